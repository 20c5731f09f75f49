"""City-wide interpolation of the cameras' air-quality levels, and the category bands.

Distances are in metres in a local equirectangular projection around the cameras' centre
(error < 0.1 % across a city). Every method works in a local neighbourhood (the k nearest
cameras of each grid cell), so memory and time grow with cameras × cells × k, never cameras²:
- ``idw``: inverse-distance weighting, power 2 (SciPy's k-d tree for the neighbours);
- ``kriging``: ordinary kriging with an exponential variogram fitted to the empirical
  semivariogram; one (k+1)×(k+1) system per cell, solved in a batch; the kriging variance is
  the uncertainty layer;
- ``rbf``: thin-plate-spline radial basis functions (SciPy's ``RBFInterpolator`` with
  ``neighbors``).
Cells farther than ``max_distance`` from every camera are left empty: no evidence, no paint.
Bands are filled contours between the category boundaries (contourpy), checked with shapely.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray
from scipy.interpolate import RBFInterpolator
from scipy.optimize import curve_fit
from scipy.spatial import cKDTree

Method = Literal["idw", "kriging", "rbf"]
EARTH_RADIUS = 6_371_008.8
"""Mean Earth radius [m]."""
BAND_EDGES = (0.5, 2.5, 4.5, 6.5, 8.5, 10.5)
BANDS = (
    ("Very Poor", 1, 2),
    ("Poor", 3, 4),
    ("Fair", 5, 6),
    ("Good", 7, 8),
    ("Very Good", 9, 10),
)


class IsoplethError(ValueError):
    """The input cannot make a field (all cameras at one point, a bad bounding box, NaN)."""


@dataclass(frozen=True, slots=True)
class Projection:
    lon0: float
    lat0: float

    def forward(self, lon: NDArray[np.float64], lat: NDArray[np.float64]) -> NDArray[np.float64]:
        """(lon, lat) [°] → (x, y) [m]."""
        x = np.radians(lon - self.lon0) * EARTH_RADIUS * math.cos(math.radians(self.lat0))
        y = np.radians(lat - self.lat0) * EARTH_RADIUS
        return np.column_stack([x, y])

    def inverse(self, xy: NDArray[np.float64]) -> NDArray[np.float64]:
        """(x, y) [m] → (lon, lat) [°]."""
        lon = self.lon0 + np.degrees(xy[:, 0] / (EARTH_RADIUS * math.cos(math.radians(self.lat0))))
        lat = self.lat0 + np.degrees(xy[:, 1] / EARTH_RADIUS)
        return np.column_stack([lon, lat])


@dataclass(frozen=True, slots=True)
class Field:
    lon: NDArray[np.float64]
    """Grid longitudes, shape (nx,) [°]."""
    lat: NDArray[np.float64]
    """Grid latitudes, shape (ny,) [°]."""
    value: NDArray[np.float64]
    """Interpolated level, shape (ny, nx); NaN where masked."""
    uncertainty: NDArray[np.float64]
    """Kriging standard deviation [level], or the distance to the nearest camera [m]."""
    uncertainty_kind: Literal["kriging_sd", "nearest_camera_m"]


def _check(lon: NDArray[np.float64], lat: NDArray[np.float64], values: NDArray[np.float64]) -> None:
    if not (len(lon) == len(lat) == len(values)):
        raise IsoplethError("lon, lat and values must have the same length")
    if not (np.isfinite(lon).all() and np.isfinite(lat).all() and np.isfinite(values).all()):
        raise IsoplethError("camera coordinates and levels must be finite (no NaN)")
    if (np.abs(lat) > 90).any() or (np.abs(lon) > 180).any():
        raise IsoplethError("coordinates out of range")
    if len(lon) >= 1 and np.ptp(lon) == 0 and np.ptp(lat) == 0 and len(lon) > 1:
        raise IsoplethError("all cameras are at one point: there is no field to interpolate")


SAME_PLACE_M = 1.0
"""Cameras closer than this [m] (two on one mast) are one station with their mean level."""


def _stations(
    xy: NDArray[np.float64], values: NDArray[np.float64], variances: NDArray[np.float64]
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """One position per place: cameras within ``SAME_PLACE_M`` of each other (on a grid of that
    size) merged, at their mean position with their mean level, whose error variance is that
    of a mean, Σσᵢ²/n². A place counts once whatever number of cameras it has, and a radial
    basis needs distinct points."""
    cell = np.floor(xy / SAME_PLACE_M)
    _, group = np.unique(cell, axis=0, return_inverse=True)
    group = group.ravel()
    n = np.bincount(group)
    if len(n) == len(values):
        return xy, values, variances
    merged = np.stack([np.bincount(group, xy[:, 0]), np.bincount(group, xy[:, 1])], axis=1)
    return (
        merged / n[:, None],
        np.bincount(group, values) / n,
        np.bincount(group, variances) / n.astype(np.float64) ** 2,
    )


def _rbf(
    xy: NDArray[np.float64], values: NDArray[np.float64], grid: NDArray[np.float64], k: int
) -> NDArray[np.float64]:
    """Thin-plate spline in each cell's k-neighbourhood. Its linear term needs three cameras
    not on one line in every neighbourhood."""
    if len(values) < 3:
        raise IsoplethError("rbf needs cameras at 3 places or more; idw works with fewer")
    scale = float(np.ptp(xy, axis=0).max())  # condition the kernel: work in units of the extent
    try:
        z = RBFInterpolator(
            xy / scale, values, kernel="thin_plate_spline", neighbors=k, smoothing=1e-6
        )(grid / scale)
    except np.linalg.LinAlgError:
        raise IsoplethError(
            "rbf cannot fit cameras that lie on one line; idw or kriging can"
        ) from None
    return np.asarray(z, dtype=np.float64)


def check_bbox(bbox: tuple[float, ...]) -> None:
    """(min lon, min lat, max lon, max lat): four finite numbers, min < max, on the globe."""
    if len(bbox) != 4 or not all(map(math.isfinite, bbox)):
        raise IsoplethError("bbox must be four finite numbers: minlon,minlat,maxlon,maxlat")
    x0, y0, x1, y1 = bbox
    if x0 >= x1 or y0 >= y1:
        raise IsoplethError(f"bbox needs min < max in both longitude and latitude; got {bbox}")
    if x0 < -180 or x1 > 180 or y0 < -90 or y1 > 90:
        raise IsoplethError(f"bbox must lie within longitude ±180° and latitude ±90°; got {bbox}")


def default_bbox(
    lon: NDArray[np.float64], lat: NDArray[np.float64]
) -> tuple[float, float, float, float]:
    """The cameras' extent plus 10 % (at least 0.01°) on every side, within the globe."""
    mx = max(0.1 * float(np.ptp(lon)), 0.01)
    my = max(0.1 * float(np.ptp(lat)), 0.01)
    return (
        max(float(lon.min()) - mx, -180.0),
        max(float(lat.min()) - my, -90.0),
        min(float(lon.max()) + mx, 180.0),
        min(float(lat.max()) + my, 90.0),
    )


def _idw(
    xy: NDArray[np.float64], v: NDArray[np.float64], grid: NDArray[np.float64], k: int
) -> NDArray[np.float64]:
    dist, idx = cKDTree(xy).query(grid, k=k)
    dist, idx = dist.reshape(len(grid), -1), idx.reshape(len(grid), -1)
    w = 1.0 / np.maximum(dist, 1e-6) ** 2
    return np.asarray((w * v[idx]).sum(axis=1) / w.sum(axis=1), dtype=np.float64)


def _exp_variogram(
    h: NDArray[np.float64], nugget: float, sill: float, rng: float
) -> NDArray[np.float64]:
    return np.asarray(nugget + sill * (1.0 - np.exp(-h / rng)), dtype=np.float64)


def fit_variogram(
    xy: NDArray[np.float64], v: NDArray[np.float64], *, max_pairs: int = 200_000, seed: int = 0
) -> tuple[float, float, float]:
    """Exponential variogram (nugget, partial sill, range [m]) fitted to the empirical
    semivariogram of (a random sample of) camera pairs, in 15 distance bins."""
    n = len(v)
    rng = np.random.default_rng(seed)
    if n * (n - 1) // 2 <= max_pairs:
        i, j = np.triu_indices(n, 1)
    else:
        i = rng.integers(0, n, max_pairs)
        j = rng.integers(0, n, max_pairs)
        keep = i != j
        i, j = i[keep], j[keep]
    h = np.hypot(*(xy[i] - xy[j]).T)
    g = 0.5 * (v[i] - v[j]) ** 2
    var = float(np.var(v)) or 1e-6
    edges = np.quantile(h, np.linspace(0, 1, 16))
    centres, gammas = [], []
    for a, b in zip(edges[:-1], edges[1:], strict=True):
        m = (h >= a) & (h <= b)
        if m.sum() >= 3:
            centres.append(h[m].mean())
            gammas.append(g[m].mean())
    hmax = float(h.max()) or 1.0
    try:
        params, _ = curve_fit(
            _exp_variogram,
            np.array(centres),
            np.array(gammas),
            p0=(0.1 * var, var, hmax / 3),
            bounds=([0, 1e-9, hmax / 1000], [10 * var, 10 * var, 10 * hmax]),
            maxfev=5000,
        )
        return float(params[0]), float(params[1]), float(params[2])
    except (RuntimeError, ValueError):
        return 0.0, var, hmax / 3


KRIGING_CHUNK = 4096
"""Grid cells solved together: bounds the batch's memory (cells × (k+1)² floats, a few MB)."""


def _kriging(
    xy: NDArray[np.float64],
    v: NDArray[np.float64],
    grid: NDArray[np.float64],
    k: int,
    variances: NDArray[np.float64],
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Ordinary kriging, local: the k nearest cameras of each cell, cells solved in batches.

    Each camera's level carries its own error variance σᵢ² [level²] (its reading's range):
    kriging with measurement error puts −σᵢ² on the system's diagonal in place of γ(0) = 0
    (the covariance C(0) + σᵢ² in semivariogram form; Cressie, *Statistics for Spatial Data*,
    1993, §3.2.1), so a camera sure of its reading weighs more than one that is not, the map
    need not pass through an unsure reading, and the standard deviation is that of the air,
    not of a camera's error."""
    nugget, sill, rng = fit_variogram(xy, v)
    _, idx_all = cKDTree(xy).query(grid, k=k)
    idx_all = idx_all.reshape(len(grid), -1)
    value = np.empty(len(grid))
    sd = np.empty(len(grid))
    for start in range(0, len(grid), KRIGING_CHUNK):
        cells = grid[start : start + KRIGING_CHUNK]
        idx = idx_all[start : start + KRIGING_CHUNK]
        pts = xy[idx]  # (G, k, 2)
        h = np.linalg.norm(pts[:, :, None, :] - pts[:, None, :, :], axis=-1)
        g = len(cells)
        a = np.ones((g, k + 1, k + 1))
        a[:, :k, :k] = _exp_variogram(h, nugget, sill, rng)
        a[:, np.arange(k), np.arange(k)] = -variances[idx]  # γ(0) = 0, less its error
        a[:, k, k] = 0.0
        # cameras a few metres apart make the system near-singular: a tiny ridge keeps it
        # solvable (those within SAME_PLACE_M are already one station)
        a[:, np.arange(k), np.arange(k)] += 1e-9 * (sill + nugget)
        b = np.ones((g, k + 1))
        b[:, :k] = _exp_variogram(
            np.linalg.norm(pts - cells[:, None, :], axis=-1), nugget, sill, rng
        )
        w = np.linalg.solve(a, b[..., None])[..., 0]
        value[start : start + g] = (w[:, :k] * v[idx]).sum(axis=1)
        sd[start : start + g] = np.sqrt(np.maximum((w * b).sum(axis=1), 0.0))  # σ² = Σ wᵢγᵢ₀ + μ
    return value, sd


def interpolate(
    lon: NDArray[np.float64],
    lat: NDArray[np.float64],
    values: NDArray[np.float64],
    *,
    bbox: tuple[float, float, float, float],
    method: Method = "idw",
    resolution: int = 128,
    max_distance: float = 5_000.0,
    neighbours: int = 16,
    errors: NDArray[np.float64] | None = None,
) -> Field:
    """Interpolate camera levels onto a ``resolution`` × ``resolution`` lon/lat grid.

    Parameters
    ----------
    lon, lat : camera positions [°]; values : their levels (1–10).
    bbox : (min lon, min lat, max lon, max lat) [°].
    max_distance : cells farther than this from every camera are NaN [m].
    neighbours : cameras per cell for every method.
    errors : each camera's standard error [level] (0 when None): kriging weighs by them.
    """
    lon, lat, values = (np.asarray(a, dtype=np.float64) for a in (lon, lat, values))
    _check(lon, lat, values)
    check_bbox(bbox)
    sd = np.zeros(len(values)) if errors is None else np.asarray(errors, dtype=np.float64)
    x0, y0, x1, y1 = bbox
    if not 2 <= resolution <= 1024:
        raise IsoplethError("resolution must be 2–1024")
    proj = Projection(float(np.mean(lon)), float(np.mean(lat)))
    xy, values, variances = _stations(proj.forward(lon, lat), values, sd**2)
    glon = np.linspace(x0, x1, resolution)
    glat = np.linspace(y0, y1, resolution)
    mlon, mlat = np.meshgrid(glon, glat)
    grid = proj.forward(mlon.ravel(), mlat.ravel())
    nearest, _ = cKDTree(xy).query(grid, k=1)
    k = min(neighbours, len(values))
    kind: Literal["kriging_sd", "nearest_camera_m"] = "nearest_camera_m"
    uncertainty = nearest
    if len(values) == 1:
        z = np.full(len(grid), values[0])
    elif method == "idw":
        z = _idw(xy, values, grid, k)
    elif method == "kriging":
        if len(values) < 3:
            raise IsoplethError("kriging needs cameras at 3 places or more; idw works with fewer")
        z, uncertainty = _kriging(xy, values, grid, k, variances)
        kind = "kriging_sd"
    elif method == "rbf":
        z = _rbf(xy, values, grid, k)
    else:
        raise IsoplethError(f"unknown method {method!r}")
    z = np.clip(z, 1.0, 10.0)
    z[nearest > max_distance] = np.nan
    shape = (resolution, resolution)
    return Field(glon, glat, z.reshape(shape), np.asarray(uncertainty).reshape(shape), kind)


MAX_CELL_FRACTION = 0.5
"""A grid cell is at most this fraction of the mask distance wide: a coarser cell paints (or
masks) a camera's whole neighbourhood in one block."""
MAX_CELLS = 512
"""Cells per side of one island's grid at most."""


@dataclass(frozen=True, slots=True)
class Island:
    """A group of cameras close enough that the map between them is painted, and its field."""

    cameras: NDArray[np.int64]
    """Indices of its cameras in the input."""
    bbox: tuple[float, float, float, float]
    field: Field
    method: str
    """The method that made it (``idw`` where kriging had too few places)."""


def islands(
    lon: NDArray[np.float64], lat: NDArray[np.float64], link_m: float
) -> list[NDArray[np.int64]]:
    """Cameras grouped by single linkage: two cameras closer than ``link_m`` [m] share an
    island (SciPy's k-d tree pairs and connected components); groups in order of their first
    camera. With ``link_m`` twice the mask distance, no painted cell lies between islands."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    lon, lat = np.asarray(lon, dtype=np.float64), np.asarray(lat, dtype=np.float64)
    n = len(lon)
    # a projection per camera would do better across continents; around the mean, the
    # distortion of links a few km long between cameras of one region is well under 1 %
    xy = _globe(lon, lat)
    chord = 2 * EARTH_RADIUS * math.sin(min(link_m / (2 * EARTH_RADIUS), math.pi / 2))
    pairs = cKDTree(xy).query_pairs(chord, output_type="ndarray")
    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    _, label = connected_components(graph, directed=False)
    order = {lab: i for i, lab in enumerate(dict.fromkeys(label.tolist()))}
    return [np.flatnonzero(label == lab) for lab in sorted(order, key=order.__getitem__)]


def _globe(lon: NDArray[np.float64], lat: NDArray[np.float64]) -> NDArray[np.float64]:
    """Points on the sphere [m] (earth-centred): straight chords, exact at any distance."""
    lo, la = np.radians(lon), np.radians(lat)
    return EARTH_RADIUS * np.column_stack(
        [np.cos(la) * np.cos(lo), np.cos(la) * np.sin(lo), np.sin(la)]
    )


def _places(lon: NDArray[np.float64], lat: NDArray[np.float64]) -> int:
    """Distinct places among cameras (``_stations``)."""
    proj = Projection(float(np.mean(lon)), float(np.mean(lat)))
    xy = proj.forward(lon, lat)
    return len(_stations(xy, np.zeros(len(xy)), np.zeros(len(xy)))[1])


def cells_for(bbox: tuple[float, float, float, float], resolution: int, max_cell_m: float) -> int:
    """Cells per side over ``bbox``: ``resolution``, or more (up to ``MAX_CELLS``) so that a
    cell is at most ``max_cell_m`` wide and tall [m]."""
    x0, y0, x1, y1 = bbox
    mid = math.radians((y0 + y1) / 2)
    w = math.radians(x1 - x0) * EARTH_RADIUS * math.cos(mid)
    h = math.radians(y1 - y0) * EARTH_RADIUS
    need = math.ceil(max(w, h) / max_cell_m) + 1
    return int(min(max(resolution, need), MAX_CELLS))


def intersect(
    a: tuple[float, float, float, float], b: tuple[float, float, float, float]
) -> tuple[float, float, float, float] | None:
    """The overlap of two bboxes, None when they do not overlap."""
    x0, y0 = max(a[0], b[0]), max(a[1], b[1])
    x1, y1 = min(a[2], b[2]), min(a[3], b[3])
    return (x0, y0, x1, y1) if x0 < x1 and y0 < y1 else None


def interpolate_islands(
    lon: NDArray[np.float64],
    lat: NDArray[np.float64],
    values: NDArray[np.float64],
    *,
    bbox: tuple[float, float, float, float] | None = None,
    method: Method = "idw",
    resolution: int = 128,
    max_distance: float = 5_000.0,
    neighbours: int = 16,
    errors: NDArray[np.float64] | None = None,
) -> list[Island]:
    """The map as islands: cameras grouped by ``islands`` (linked within 2 × ``max_distance``),
    each interpolated (``interpolate``) over its own bbox — its cameras' extent plus a margin
    (``default_bbox``), clipped to ``bbox`` when given; one island over all of ``bbox`` when the
    cameras make one — on a grid whose cells are at most ``MAX_CELL_FRACTION`` of the mask
    distance wide (so two cities far apart are two fine maps, not one coarse one where every
    cell is farther than the mask distance from a camera). An island with fewer than 3 places
    is interpolated by ``idw`` when kriging or rbf is asked for (both need 3). Islands outside
    ``bbox`` are left out."""
    lon, lat, values = (np.asarray(a, dtype=np.float64) for a in (lon, lat, values))
    _check(lon, lat, values)
    if bbox is not None:
        check_bbox(bbox)
    groups = islands(lon, lat, 2 * max_distance)
    out = []
    for idx in groups:
        if bbox is not None and len(groups) == 1:
            box: tuple[float, float, float, float] | None = bbox
        else:
            box = default_bbox(lon[idx], lat[idx])
            if bbox is not None:
                box = intersect(box, bbox)
        if box is None:
            continue
        n = cells_for(box, resolution, MAX_CELL_FRACTION * max_distance)
        how = method
        if method in ("kriging", "rbf") and _places(lon[idx], lat[idx]) < 3:
            how = "idw"
        f = interpolate(
            lon[idx],
            lat[idx],
            values[idx],
            bbox=box,
            method=how,
            resolution=n,
            max_distance=max_distance,
            neighbours=neighbours,
            errors=None if errors is None else np.asarray(errors, dtype=np.float64)[idx],
        )
        out.append(Island(idx, box, f, how))
    return out


def cell_size_m(f: Field) -> tuple[float, float]:
    """A grid cell's width and height [m] at the grid's middle latitude."""
    lat_mid = math.radians(float(f.lat[len(f.lat) // 2]))
    dx = math.radians(float(f.lon[1] - f.lon[0])) * EARTH_RADIUS * math.cos(lat_mid)
    dy = math.radians(float(f.lat[1] - f.lat[0])) * EARTH_RADIUS
    return dx, dy


def band_at(f: Field, lon: NDArray[np.float64], lat: NDArray[np.float64]) -> list[str | None]:
    """The category the bands give each point: the field linearly interpolated there (as the
    contours are), None outside the painted cells. Where the grid is coarser than the cameras'
    spacing, a camera can lie in another category's band than its own reading."""
    from scipy.interpolate import RegularGridInterpolator

    z = RegularGridInterpolator(
        (f.lat, f.lon), f.value, method="linear", bounds_error=False, fill_value=np.nan
    )(np.column_stack([lat, lon]))
    out: list[str | None] = []
    for v in z:
        if not np.isfinite(v):
            out.append(None)
            continue
        k = int(np.searchsorted(BAND_EDGES, v, side="right")) - 1
        out.append(BANDS[min(max(k, 0), len(BANDS) - 1)][0])
    return out


def _filled(f: Field, z: NDArray[np.float64], edges: Sequence[float]) -> list[tuple[int, Any]]:
    """Filled contours of ``z`` between consecutive ``edges``: (index of the band, its shapely
    Polygon or MultiPolygon) for each band present, valid, exteriors counter-clockwise (RFC
    7946 right-hand rule)."""
    import contourpy
    from shapely import MultiPolygon, Polygon, make_valid, simplify, unary_union
    from shapely.geometry.polygon import orient

    if np.isnan(z).all():
        return []
    # Cameras reading alike interpolate to their reading give or take float noise: kriging
    # made 8.5 ± 2e-15 of three cameras at 8.5, and the Good and Very Good bands of that
    # noise overlapped (by 0.4 % of the smaller). Values are taken to 1e-9 first.
    z = np.round(z, 9)
    # A band holds lower <= z < upper, as ``band_at``, the PNG and ``airquality.rounded``
    # (halves up: 8.5 is Very Good) have it; contourpy fills lower < z <= upper, and one
    # camera at 8.5 was a Good band. Its levels are the edges' next doubles below, which no
    # value taken to 1e-9 equals.
    below = np.nextafter(np.asarray(edges, dtype=np.float64), -np.inf).tolist()
    gen = contourpy.contour_generator(
        f.lon, f.lat, np.ma.masked_invalid(z), fill_type=contourpy.FillType.OuterOffset,
        name="serial",
    )  # fmt: skip
    out = []
    for i, (a, b) in enumerate(zip(below[:-1], below[1:], strict=True)):
        filled: Any = gen.filled(a, b)
        points, offsets = filled[0], filled[1]
        polygons = []
        for pts, offs in zip(points, offsets, strict=True):
            rings = [pts[offs[i] : offs[i + 1]] for i in range(len(offs) - 1)]
            if len(rings[0]) < 4:
                continue
            polygons.append(Polygon(rings[0], [r for r in rings[1:] if len(r) >= 4]))
        if not polygons:
            continue
        geom = make_valid(unary_union(polygons))
        # without the vertices lying on a straight line between their neighbours (tolerance
        # 0: the same area, point for point): contourpy gives one at every cell along the
        # grid's edges and straight runs, and one camera's map of a single band (128 cells)
        # was 509 vertices, 20 kB, for a rectangle
        parts = [
            simplify(g, 0.0)
            for g in getattr(geom, "geoms", [geom])
            if isinstance(g, Polygon) and not g.is_empty
        ]
        if not parts:
            continue
        out.append(
            (
                i,
                MultiPolygon([orient(p, 1.0) for p in parts])
                if len(parts) > 1
                else orient(parts[0], 1.0),
            )
        )
    return out


def bands(f: Field) -> list[dict[str, Any]]:
    """GeoJSON features, one per category present: filled contours between the category
    boundaries, valid (shapely), exteriors counter-clockwise (RFC 7946 right-hand rule)."""
    from shapely.geometry import mapping

    features = []
    for i, shape in _filled(f, f.value, BAND_EDGES):
        name, lo, hi = BANDS[i]
        features.append(
            {
                "type": "Feature",
                "geometry": mapping(shape),
                "properties": {"category": name, "level_min": lo, "level_max": hi},
            }
        )
    return features


UNCERTAINTY_EDGES: dict[str, tuple[float, ...]] = {
    "kriging_sd": (0.0, 0.25, 0.5, 1.0, 1.5, 2.0, 3.0),
    "nearest_camera_m": (0.0, 250.0, 500.0, 1_000.0, 2_000.0, 5_000.0, 10_000.0, 20_000.0),
}
"""Where the uncertainty layer's bands change: kriging's standard deviation [level], or the
distance to the nearest camera [m]; the last band is open above."""
UNCERTAINTY_UNITS = {"kriging_sd": "level", "nearest_camera_m": "m"}


def uncertainty_edges(f: Field) -> tuple[float, ...]:
    """The edges of ``f``'s uncertainty bands, the last one closing over its largest value."""
    edges = UNCERTAINTY_EDGES[f.uncertainty_kind]
    u = uncertainty_of(f)
    top = edges[-1] if np.isnan(u).all() else max(float(np.nanmax(u)), edges[-1])
    return (*edges, top * 1.001 + 1.0)


def uncertainty_of(f: Field) -> NDArray[np.float64]:
    """The uncertainty where the map is painted (NaN where it is not: no evidence there, so
    no claim of how uncertain it is)."""
    return np.where(np.isnan(f.value), np.nan, f.uncertainty)


def uncertainty_bands(f: Field) -> list[dict[str, Any]]:
    """The uncertainty layer as GeoJSON features: filled contours of kriging's standard
    deviation, or of the distance to the nearest camera, between ``UNCERTAINTY_EDGES``, over
    the painted cells; valid and counter-clockwise as ``bands``. Properties: ``kind``,
    ``unit``, ``uncertainty_min`` and ``uncertainty_max`` (null for the open last band)."""
    from shapely.geometry import mapping

    edges = uncertainty_edges(f)
    features = []
    for i, shape in _filled(f, uncertainty_of(f), edges):
        features.append(
            {
                "type": "Feature",
                "geometry": mapping(shape),
                "properties": {
                    "kind": f.uncertainty_kind,
                    "unit": UNCERTAINTY_UNITS[f.uncertainty_kind],
                    "uncertainty_min": edges[i],
                    "uncertainty_max": edges[i + 1] if i + 2 < len(edges) else None,
                },
            }
        )
    return features


def merged(per_island: Sequence[list[dict[str, Any]]]) -> list[dict[str, Any]]:
    """GeoJSON features of several islands as one per band: features with equal properties
    joined into one (Multi)Polygon (shapely), in the order each band first appears."""
    from shapely import MultiPolygon, Polygon, unary_union
    from shapely.geometry import mapping, shape
    from shapely.geometry.polygon import orient

    groups: dict[str, tuple[dict[str, Any], list[Any]]] = {}
    for features in per_island:
        for f in features:
            key = repr(sorted(f["properties"].items()))
            groups.setdefault(key, (f["properties"], []))[1].append(shape(f["geometry"]))
    out = []
    for props, shapes in groups.values():
        geom = shapes[0] if len(shapes) == 1 else unary_union(shapes)
        parts = [g for g in getattr(geom, "geoms", [geom]) if isinstance(g, Polygon)]
        joined = (
            MultiPolygon([orient(p, 1.0) for p in parts])
            if len(parts) > 1
            else orient(parts[0], 1.0)
        )
        out.append({"type": "Feature", "geometry": mapping(joined), "properties": props})
    return out
