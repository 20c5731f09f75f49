"""Measure a part with the laser grid: images in, area and volume out."""

from __future__ import annotations

from collections.abc import Sequence
from typing import TypeVar

import numpy as np
from numpy.typing import NDArray
from pydantic import TypeAdapter, ValidationError

from app.cells.core import laser, laser_grid
from app.cells.core.laser_grid import Geometry
from app.cells.schemas import Finite, LaserGridOut
from app.cells.services import vision
from app.platform.http.errors import Unprocessable

Files = list[tuple[str | None, bytes]]
Sizes = Sequence[tuple[int, int] | None]
"""Per camera, the [width, height] its K was calibrated for, or None when not known."""
T = TypeVar("T")


_PIXELS = TypeAdapter(list[tuple[Finite, Finite] | None])
_PLANE = TypeAdapter(tuple[Finite, Finite, Finite, Finite])
_PAN_TILT = TypeAdapter(list[tuple[Finite, Finite] | None])


def pan_tilt_field(raw: list[str]) -> list[list[float] | None] | None:
    """The ``pan_tilt_deg`` form field (JSON, per camera [pan, tilt] in degrees or null)."""
    angles = _field(raw, "pan_tilt_deg", _PAN_TILT)
    return None if angles is None else [None if a is None else list(a) for a in angles]


def _field(raw: list[str], name: str, adapter: TypeAdapter[T]) -> T | None:
    """A JSON form field checked by the schemas' own types; None when not sent."""
    if not raw:
        return None
    try:
        return adapter.validate_json(raw[0])
    except ValidationError as exc:
        error = exc.errors()[0]
        where = "".join(f"[{p}]" for p in error["loc"])
        raise Unprocessable(f"{name}{where}: {error['msg']}") from None


def _decode(
    k: int, data: bytes, sizes: Sizes, max_pixels: int, colour: laser.Colour
) -> NDArray[np.uint8]:
    """Camera k's image, the laser's channel first (``laser.as_red``), refused when it is not
    of the size its K was calibrated for: K in pixels of another size puts every ray
    elsewhere (twice the pixels, twice the focal length and principal point), and the figures
    come out confidently wrong."""
    image = vision.decode(data, max_pixels=max_pixels)
    size = sizes[k] if k < len(sizes) else None
    h, w = image.shape[:2]
    if size is not None and (w, h) != tuple(size):
        raise Unprocessable(
            f"camera {k + 1}'s image is {w}×{h} px, but the camera was calibrated for "
            f"{size[0]}×{size[1]}: send images of that size (or calibrate at this one)",
            code="wrong_image_size",
        )
    return laser.as_red(image, colour)


def locate_dot(
    geo: Geometry,
    files: Files,
    max_pixels: int,
    sizes: Sizes = (),
    colour: laser.Colour = "red",
) -> laser.Dot:
    """The laser dot from one dot-mode image per camera, in camera order (``/laser/dot``, and
    the grid's origin)."""
    n_cams = len(geo.f)
    if len(files) != n_cams:
        raise Unprocessable(
            f"send one image per camera, in camera order: {n_cams}, got {len(files)}"
        )
    spots = [
        laser.find_spots(_decode(k, data, sizes, max_pixels, colour))
        for k, (_, data) in enumerate(files)
    ]
    try:
        dot = laser.locate(spots, geo.triangulate)
    except ValueError as exc:
        raise Unprocessable(str(exc), code="dot_not_found") from None
    if not np.isfinite(dot.point).all():
        raise Unprocessable("the dot's views do not triangulate to a point", code="dot_not_found")
    return dot


def origin_from(
    geo: Geometry,
    dot_files: Files,
    origin: list[str],
    n_cams: int,
    max_pixels: int,
    sizes: Sizes = (),
    colour: laser.Colour = "red",
) -> tuple[np.ndarray | None, list[str]]:
    """The laser dot's 3-D point, from dot-mode images or from its pixels in each view."""
    if dot_files:
        return locate_dot(geo, dot_files, max_pixels, sizes, colour).point, []
    pixels = _field(origin, "origin", _PIXELS)
    if pixels is None:
        return None, [
            "no laser dot (dot_files or origin): labels start anywhere, and a grid aligned "
            "with the rig's baselines may be matched a whole number of cells off"
        ]
    if len(pixels) != n_cams:
        raise Unprocessable(f"origin must be a list of {n_cams}: [u, v] or null per camera")
    obs = np.full((1, n_cams, 2), np.nan)
    for k, uv in enumerate(pixels):
        if uv is not None:
            obs[0, k] = uv
    if np.isfinite(obs[0]).all(axis=1).sum() < 2:
        raise Unprocessable("origin: the dot must be given in at least 2 cameras")
    point, _ = geo.triangulate(obs)
    if not np.isfinite(point).all():
        raise Unprocessable("origin: the dot's pixels do not triangulate to a point")
    return point[0], []


def measure(
    geo: Geometry,
    files: Files,
    *,
    dot_files: Files,
    origin: list[str],
    base_plane: list[str],
    max_pixels: int,
    sizes: Sizes = (),
    colour: laser.Colour = "red",
) -> LaserGridOut:
    n_cams = len(geo.f)
    if len(files) != n_cams:
        raise Unprocessable(
            f"send one grid image per camera, in camera order: {n_cams}, got {len(files)}"
        )
    plane_raw = _field(base_plane, "base_plane", _PLANE)
    plane = None if plane_raw is None else np.array(plane_raw)
    if plane is not None and np.linalg.norm(plane[:3]) == 0:
        raise Unprocessable("base_plane needs a non-zero normal (a, b, c)")
    point, warnings = origin_from(geo, dot_files, origin, n_cams, max_pixels, sizes, colour)
    nodes = [
        laser_grid.detect(_decode(k, data, sizes, max_pixels, colour))
        for k, (_, data) in enumerate(files)
    ]
    blind = [k + 1 for k, n in enumerate(nodes) if len(n.uv) == 0]
    if len(blind) > n_cams - 2:
        raise Unprocessable(
            f"no laser grid found in camera(s) {', '.join(map(str, blind))}", code="grid_not_found"
        )
    matches = laser_grid.match(nodes, geo, origin=point)
    if matches.tied >= laser_grid.TIED_WARNING:
        # a grid square to the baselines matches whole cells off where fewer than all cameras
        # see it: better no figures than wrong ones
        raise Unprocessable(matches.warnings[0], code="grid_ambiguous")
    grid = laser_grid.label(nodes, matches, geo, origin=point)
    if len(grid.points) < 4:
        raise Unprocessable("too few grid nodes matched across the views", code="grid_not_found")
    try:
        m = laser_grid.measure(grid, nodes, geo, base_plane=plane)
    except ValueError as exc:
        raise Unprocessable(str(exc), code="no_base_plane") from None
    return LaserGridOut(
        points=grid.points.tolist(),
        labels=grid.labels.tolist(),
        surfaces=grid.surface.tolist(),
        reprojection_rms_px=grid.rms.tolist(),
        surface_area=m.surface_area,
        side_area=m.side_area,
        footprint_area=m.footprint_area,
        volume=m.volume,
        base_plane=m.base_plane.tolist(),
        height_max=m.height_max,
        nodes_per_view=[len(n.uv) for n in nodes],
        boundary_traced=m.boundary_traced,
        boundary_guessed=m.boundary_guessed,
        warnings=warnings + grid.warnings,
    )
