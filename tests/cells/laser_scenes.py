"""Ray-traced renders of the laser grid (and dot) on a part resting on a table, seen by the
4-camera cross, with exact ground truth: made by the tests themselves.

The laser sits at the centre of the cross (the rig origin) and looks along +Z, like the cameras.
Its grid is the set of rays whose angular coordinates (a, b) = (X/Z, Y/Z), rotated by
``grid_rotation``, fall on a multiple of ``pitch``; the dot is the ray (0, 0). A point is lit
when the laser reaches it (no shadow) and seen when it is the first surface along the camera's
ray, so occlusion and shadows are both exact.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from app.cells.core.triangulation import CrossRig

RIG = CrossRig(f=1000.0, ax=0.3, ay=0.2, cx=320.0, cy=240.0)


@dataclass(frozen=True)
class Part:
    shape: str
    """``box`` (length, width, height) or ``cylinder`` (radius, height), resting on the table."""
    dims: tuple[float, ...]
    centre: tuple[float, float] = (0.0, 0.0)
    """Offset on the table [m], in its own frame."""
    yaw: float = 0.0
    """Rotation about the table's normal [rad]."""

    @property
    def volume(self) -> float:
        if self.shape == "box":
            return self.dims[0] * self.dims[1] * self.dims[2]
        return math.pi * self.dims[0] ** 2 * self.dims[1]

    @property
    def top_area(self) -> float:
        if self.shape == "box":
            return self.dims[0] * self.dims[1]
        return math.pi * self.dims[0] ** 2

    @property
    def side_area(self) -> float:
        if self.shape == "box":
            return 2 * (self.dims[0] + self.dims[1]) * self.dims[2]
        return 2 * math.pi * self.dims[0] * self.dims[1]


@dataclass(frozen=True)
class Scene:
    part: Part
    table_distance: float = 1.0
    table_tilt: float = 0.0
    """Rotation of the table about the X axis [rad]."""
    pitch: float = 0.012
    """Angular spacing of the grid lines [rad]."""
    grid_rotation: float = 0.0
    lines: int = 25
    """Grid lines each side of the centre."""

    def table_frame(self) -> tuple[np.ndarray, np.ndarray]:
        """(origin, rows e1, e2, e3): e3 is the table's normal, towards the rig."""
        c, s = math.cos(self.table_tilt), math.sin(self.table_tilt)
        axes = np.array([[1.0, 0.0, 0.0], [0.0, c, s], [0.0, s, -c]])
        return np.array([0.0, 0.0, self.table_distance]), axes

    def base_plane(self) -> np.ndarray:
        """[a, b, c, d] with a X + b Y + c Z + d = 0, (a, b, c) the unit normal towards the rig."""
        origin, axes = self.table_frame()
        return np.append(axes[2], -axes[2] @ origin)


def _intersect(scene: Scene, o: np.ndarray, d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """First hit along rays o + t d (t > 0): (t, surface) with 0 table, 1 part, −1 nothing."""
    origin, axes = scene.table_frame()
    ol = (o - origin) @ axes.T
    dl = d @ axes.T
    with np.errstate(divide="ignore", invalid="ignore"):
        t_table = np.where(dl[:, 2] != 0, -ol[:, 2] / dl[:, 2], np.inf)
    t_table = np.where(t_table > 1e-9, t_table, np.inf)
    p = scene.part
    cz, sz = math.cos(p.yaw), math.sin(p.yaw)
    yaw = np.array([[cz, sz, 0.0], [-sz, cz, 0.0], [0.0, 0.0, 1.0]])
    ob = (ol - np.array([p.centre[0], p.centre[1], 0.0])) @ yaw.T
    db = dl @ yaw.T
    t_part = np.full(len(o), np.inf)
    with np.errstate(divide="ignore", invalid="ignore"):
        if p.shape == "box":
            lo = np.array([-p.dims[0] / 2, -p.dims[1] / 2, 0.0])
            hi = np.array([p.dims[0] / 2, p.dims[1] / 2, p.dims[2]])
            t1 = (lo - ob) / db
            t2 = (hi - ob) / db
            near = np.nanmax(np.minimum(t1, t2), axis=1)
            far = np.nanmin(np.maximum(t1, t2), axis=1)
            hit = (near <= far) & (far > 1e-9)
            t_part = np.where(hit, np.where(near > 1e-9, near, far), np.inf)
        else:
            r, h = p.dims
            a = db[:, 0] ** 2 + db[:, 1] ** 2
            b = 2 * (ob[:, 0] * db[:, 0] + ob[:, 1] * db[:, 1])
            c = ob[:, 0] ** 2 + ob[:, 1] ** 2 - r * r
            disc = b * b - 4 * a * c
            ts = (-b - np.sqrt(np.maximum(disc, 0))) / (2 * a)
            z = ob[:, 2] + ts * db[:, 2]
            side = (disc >= 0) & (ts > 1e-9) & (z >= 0) & (z <= h)
            t_cap = (h - ob[:, 2]) / db[:, 2]
            xy = ob[:, :2] + t_cap[:, None] * db[:, :2]
            cap = (t_cap > 1e-9) & ((xy**2).sum(axis=1) <= r * r)
            t_part = np.minimum(np.where(side, ts, np.inf), np.where(cap, t_cap, np.inf))
    t = np.minimum(t_table, t_part)
    surface = np.where(np.isinf(t), -1, np.where(t_part < t_table, 1, 0))
    return t, surface


def _laser(scene: Scene, points: np.ndarray, mode: str) -> np.ndarray:
    """Laser intensity 0–1 at world points (shadows included)."""
    dist = np.linalg.norm(points, axis=1)
    t, _ = _intersect(scene, np.zeros_like(points), points / dist[:, None])
    lit = t >= dist - 1e-7
    a = points[:, 0] / points[:, 2]
    b = points[:, 1] / points[:, 2]
    c, s = math.cos(scene.grid_rotation), math.sin(scene.grid_rotation)
    ar, br = c * a + s * b, -s * a + c * b
    width = 0.0011  # the line's σ [rad]: about 1.1 px at f = 1000
    if mode == "dot":
        level = np.exp(-0.5 * (ar**2 + br**2) / 0.0015**2)
    else:
        q = scene.pitch
        da = ar - q * np.round(ar / q)
        db = br - q * np.round(br / q)
        inside = (np.abs(ar) <= scene.lines * q + 2 * width) & (
            np.abs(br) <= scene.lines * q + 2 * width
        )
        la = np.exp(-0.5 * (da / width) ** 2) * (np.abs(br) <= scene.lines * q)
        lb = np.exp(-0.5 * (db / width) ** 2) * (np.abs(ar) <= scene.lines * q)
        level = (1 - (1 - la) * (1 - lb)) * inside
    return np.where(lit, level, 0.0)


def render(
    scene: Scene, *, mode: str = "grid", rig: CrossRig = RIG, seed: int = 0, size=(640, 480)
) -> list[np.ndarray]:
    """One RGB uint8 image per camera of the cross."""
    w, h = size
    v, u = np.mgrid[0:h, 0:w].astype(np.float64)
    rng = np.random.default_rng(seed)
    images = []
    for xc, yc in rig.centres:
        d = np.stack(
            [(u - rig.cx) / rig.f, -(v - rig.cy) / rig.f, np.ones_like(u)], axis=-1
        ).reshape(-1, 3)
        o = np.tile([xc, yc, 0.0], (len(d), 1))
        t, surface = _intersect(scene, o, d)
        pts = o + np.where(np.isfinite(t), t, 0)[:, None] * d
        level = np.where(surface >= 0, _laser(scene, pts, mode), 0.0)
        albedo = np.where(
            surface[:, None] == 1,
            np.array([0.45, 0.38, 0.30]),
            np.where(surface[:, None] == 0, np.array([0.55, 0.55, 0.52]), 0.1),
        )
        shade = 170.0 * albedo * (0.9 + 0.1 * np.sin(pts[:, :1] * 40) * np.cos(pts[:, 1:2] * 31))
        image = shade + level[:, None] * np.array([210.0, 25.0, 20.0])
        image = cv2.GaussianBlur(image.reshape(h, w, 3), (0, 0), 0.7)
        image = image + rng.normal(0.0, 2.0, image.shape)
        images.append(np.clip(np.rint(image), 0, 255).astype(np.uint8))
    return images


def photographed(rgb: np.ndarray, gain: float = 1.0, quality: int = 0) -> np.ndarray:
    """A render as a camera delivers it: exposure scaled by ``gain`` (every channel clipped at
    255, as a sensor saturates), then JPEG at ``quality`` (0: lossless), decoded again."""
    out = np.clip(rgb.astype(np.float64) * gain, 0, 255).astype(np.uint8)
    if not quality:
        return out
    ok, buf = cv2.imencode(".jpg", out[:, :, ::-1], [cv2.IMWRITE_JPEG_QUALITY, quality])
    assert ok
    return np.asarray(cv2.imdecode(buf, cv2.IMREAD_COLOR)[:, :, ::-1])
