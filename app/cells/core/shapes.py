"""Matching located corner points to a library of regular parts ("compared to a library of all
possible regular geometries", chapter 4, Applications): rectangular box, triangular prism,
cylinder. Each fit gives the shape's dimensions, pose and the RMS distance of the points from
it; the shapes are ranked by that residual.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.optimize import least_squares, minimize
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation


@dataclass(frozen=True, slots=True)
class Fit:
    shape: str
    dimensions: dict[str, float]
    centre: NDArray[np.float64]
    axes: NDArray[np.float64]
    """Rows: the shape's local x, y, z axes in world coordinates."""
    rms: float
    """RMS distance of the points from the fitted model's features [world units]."""
    hidden: int = 0
    """The model's corners that no point lies near (``_hidden``): corners the cameras did not
    see, or that the shape does not have."""


def _hidden(points: NDArray[np.float64], corners: NDArray[np.float64], rms: float) -> int:
    """Corners farther than 4 × the fit's RMS (at least 2 % of the shape's size) from every
    point."""
    size = float(np.ptp(corners, axis=0).max())
    tol = max(4 * rms, 0.02 * size)
    d = np.linalg.norm(corners[:, None, :] - points[None, :, :], axis=-1).min(axis=1)
    return int((d > tol).sum())


def _frame(p: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    centre = p.mean(axis=0)
    _, _, vt = np.linalg.svd(p - centre, full_matrices=False)  # not U: n × n
    if np.linalg.det(vt) < 0:
        vt[2] *= -1
    return centre, vt


def _nearest_rms(points: NDArray[np.float64], model: NDArray[np.float64]) -> float:
    d = np.linalg.norm(points[:, None, :] - model[None, :, :], axis=-1)
    return float(np.sqrt(np.mean(d.min(axis=1) ** 2)))


def _edge_directions(
    points: NDArray[np.float64], *, k: int = 6, limit: int = 60
) -> NDArray[np.float64]:
    """Unit directions from each point to its ``k`` nearest others, shortest first, one of each
    (within 3°, either sign), at most ``limit``: a box's edges join a corner to its nearest
    corners."""
    k = min(k, len(points) - 1)
    dist, near = cKDTree(points).query(points, k=k + 1)  # the first is the point itself
    rows = np.repeat(np.arange(len(points)), k)
    vec = points[near[:, 1:].ravel()] - points[rows]
    length = dist[:, 1:].ravel()
    order = np.argsort(length, kind="stable")
    keep = order[length[order] > 1e-12]
    units = vec[keep] / length[keep, None]
    chosen: list[NDArray[np.float64]] = []
    for u in units:
        if all(abs(float(u @ c)) < math.cos(math.radians(3)) for c in chosen):
            chosen.append(u)
            if len(chosen) == limit:
                break
    return np.array(chosen).reshape(-1, 3)


def _box_frames(points: NDArray[np.float64]) -> NDArray[np.float64]:
    """Candidate box orientations (rows: the box's axes): every two edge directions within 10°
    of square to each other, made orthonormal; and the principal axes."""
    units = _edge_directions(points)
    i, j = np.triu_indices(len(units), 1)
    square = np.abs(np.einsum("ij,ij->i", units[i], units[j])) < math.sin(math.radians(10))
    a, b = units[i[square]], units[j[square]]
    b = b - np.einsum("ij,ij->i", a, b)[:, None] * a
    b /= np.linalg.norm(b, axis=1, keepdims=True)
    frames = np.stack([a, b, np.cross(a, b)], axis=1)
    _, pca = _frame(points)
    return np.concatenate([frames, pca[None]])


def _box_in(
    points: NDArray[np.float64], frame: NDArray[np.float64]
) -> tuple[NDArray[np.float64], NDArray[np.float64], float]:
    """The box of orientation ``frame`` around the points: its centre (in the frame), half
    extents, and the RMS distance from each point to its nearest corner."""
    local = points @ frame.T
    lo, hi = local.min(axis=0), local.max(axis=0)
    mid, half = (lo + hi) / 2, (hi - lo) / 2
    corners = mid + SIGNS * half
    return mid, half, _nearest_rms(local, corners)


SIGNS = np.array(list(itertools.product((-1.0, 1.0), repeat=3)))
"""The 8 corners of a box as signs of its half extents."""


def fit_box(points: NDArray[np.float64]) -> Fit:
    """Corners of a rectangular box, some of them possibly hidden: the orientation whose box
    around the points has its corners nearest to them, among those two edges between the
    points make (a box's axes are not its principal axes when two of its sides are equal, or
    when a corner is missing), refined by least squares over pose and size."""
    best = min((_box_in(points, f) + (f,) for f in _box_frames(points)), key=lambda fit: fit[2])
    mid, half, _, frame = best
    # refine: each point stays with its nearest corner; pose and half extents move
    local = points @ frame.T
    corner = np.argmin(
        np.linalg.norm(local[:, None, :] - (mid + SIGNS * half)[None], axis=-1), axis=1
    )
    signs = SIGNS[corner]

    def axes_of(x: NDArray[np.float64]) -> NDArray[np.float64]:
        return np.asarray(Rotation.from_rotvec(x[:3]).as_matrix() @ frame, dtype=np.float64)

    def residual(x: NDArray[np.float64]) -> NDArray[np.float64]:
        return np.asarray((points - (x[3:6] + signs * x[6:9]) @ axes_of(x)).ravel())

    x0 = np.concatenate([np.zeros(3), mid, half])
    x = least_squares(residual, x0).x

    def box_of(x: NDArray[np.float64]) -> tuple[NDArray[np.float64], ...]:
        axes, half = axes_of(x), np.abs(x[6:9])
        centre = x[3:6] @ axes
        return axes, half, centre, (SIGNS * half) @ axes + centre

    # points that are no box's corners can pull the refined box beyond them: keep the closer
    axes, half, centre, corners = min(
        (box_of(x), box_of(x0)), key=lambda box: _nearest_rms(points, box[3])
    )
    dims = sorted((2 * half).tolist(), reverse=True)
    rms = _nearest_rms(points, corners)
    return Fit(
        "box",
        {"length": dims[0], "width": dims[1], "height": dims[2]},
        centre,
        axes,
        rms,
        _hidden(points, corners, rms),
    )


def fit_prism(points: NDArray[np.float64]) -> Fit:
    """Corners of a triangular prism: the axis is the direction along which the points split
    into two triangles, tried among the principal axes and the directions between the points
    (a lateral edge is one); residual to the 6 corners of the fitted prism."""
    centre, axes = _frame(points)
    best: Fit | None = None
    for ax in [*axes, *_edge_directions(points)]:
        t = (points - centre) @ ax
        ends = t > np.median(t)
        if ends.sum() < 1 or (~ends).sum() < 1:
            continue
        length = float(t[ends].mean() - t[~ends].mean())
        section = (points - centre) - np.outer(t, ax)
        # the triangle: the cross-section points of both ends together, clustered into 3
        pts2 = section
        tri = _three_clusters(pts2)
        model = np.concatenate([tri + ax * t[~ends].mean(), tri + ax * t[ends].mean()]) + centre
        sides = [float(np.linalg.norm(tri[i] - tri[(i + 1) % 3])) for i in range(3)]
        rms = _nearest_rms(points, model)
        u = tri[1] - tri[0]
        u /= np.linalg.norm(u) or 1.0
        fit = Fit(
            "prism",
            {"length": abs(length), "side_a": sides[0], "side_b": sides[1], "side_c": sides[2]},
            centre,
            np.array([u, np.cross(ax, u), ax]),
            rms,
            _hidden(points, model, rms),
        )
        if best is None or fit.rms < best.rms:
            best = fit
    if best is None:
        raise ValueError("the points do not separate into two ends")
    return best


def _three_clusters(p: NDArray[np.float64]) -> NDArray[np.float64]:
    """Three cluster centres by farthest-point seeding and a few Lloyd steps."""
    seeds = [p[0]]
    for _ in range(2):
        d = np.min([np.linalg.norm(p - s, axis=1) for s in seeds], axis=0)
        seeds.append(p[int(np.argmax(d))])
    c = np.array(seeds)
    for _ in range(10):
        lab = np.argmin(np.linalg.norm(p[:, None] - c[None], axis=-1), axis=1)
        c = np.array([p[lab == i].mean(axis=0) if (lab == i).any() else c[i] for i in range(3)])
    return c


MIN_RIM_POINTS = 5
"""Any 3 points, and a rectangle's 4 corners, lie on a circle: a cylinder needs at least this
many points on each rim before it counts as a fit."""


def _cylinder_along(
    points: NDArray[np.float64], centre: NDArray[np.float64], ax: NDArray[np.float64]
) -> Fit | None:
    """The cylinder of axis direction ``ax``: the circle through the points' projections on
    the plane square to it (least squares on |q − c|² = r²); None without ``MIN_RIM_POINTS``
    at each end."""
    t = (points - centre) @ ax
    upper = t > np.median(t)
    if min(upper.sum(), (~upper).sum()) < MIN_RIM_POINTS:
        return None
    u = np.cross(ax, np.eye(3)[int(np.argmin(np.abs(ax)))])
    u /= np.linalg.norm(u)
    v = np.cross(ax, u)
    section = points - centre
    q = np.column_stack([section @ u, section @ v])
    a = np.column_stack([2 * q, np.ones(len(q))])
    sol, *_ = np.linalg.lstsq(a, (q**2).sum(axis=1), rcond=None)
    c2 = sol[:2]
    r = float(np.sqrt(max(sol[2] + c2 @ c2, 0.0)))
    radial = np.linalg.norm(q - c2, axis=1)
    return Fit(
        "cylinder",
        {"radius": r, "height": float(np.ptp(t))},
        centre + c2[0] * u + c2[1] * v + ax * (t.max() + t.min()) / 2,
        np.array([u, v, ax]),
        float(np.sqrt(np.mean((radial - r) ** 2))),
    )


def _direction(angles: NDArray[np.float64]) -> NDArray[np.float64]:
    theta, phi = angles
    return np.array(
        [math.sin(theta) * math.cos(phi), math.sin(theta) * math.sin(phi), math.cos(theta)]
    )


AXIS_CANDIDATES = 256
"""Directions over a hemisphere tried as a cylinder's axis (~9° apart), besides the principal
axes, before the best is refined."""


def fit_cylinder(points: NDArray[np.float64]) -> Fit | None:
    """Points on a cylinder's two rims: the axis is the direction whose cross-section is most
    circular; residual is the spread of the radial distance. None when no axis has at least
    ``MIN_RIM_POINTS`` points at each end.

    The axis is searched over the hemisphere, not only among the principal axes: when the
    height is about √2 × the radius the points' spread is the same in every direction and
    the principal axes are any three (the height came out 50–60 % long)."""
    centre, axes = _frame(points)
    k = np.arange(AXIS_CANDIDATES) + 0.5
    theta = np.arccos(1 - k / AXIS_CANDIDATES)  # Fibonacci points over the upper hemisphere
    phi = math.pi * (1 + 5**0.5) * k
    candidates = [*axes, *(_direction(np.array(a)) for a in zip(theta, phi, strict=True))]
    fits = [f for f in (_cylinder_along(points, centre, ax) for ax in candidates) if f is not None]
    if not fits:
        return None
    best = min(fits, key=lambda f: f.rms)
    z = best.axes[2]
    start = np.array([math.acos(float(np.clip(z[2], -1, 1))), math.atan2(z[1], z[0])])

    def spread(angles: NDArray[np.float64]) -> float:
        fit = _cylinder_along(points, centre, _direction(angles))
        return math.inf if fit is None else fit.rms

    refined = _cylinder_along(
        points, centre, _direction(minimize(spread, start, method="Nelder-Mead").x)
    )
    return refined if refined is not None and refined.rms <= best.rms else best


GOOD_FIT = 0.05
"""A fit whose RMS is within this fraction of the points' extent explains them."""


AS_CLOSE = 2.0
"""A fit within this factor of the closest fit's RMS (plus ``NOISE_FLOOR``) fits as closely."""
NOISE_FLOOR = 0.005
"""Below this fraction of the points' extent, residuals are noise whatever their ratio."""


def _rank(fit: Fit, size: float, closest: float) -> tuple[int, int, float]:
    """Fits that explain the points (RMS within ``GOOD_FIT`` of the points' extent ``size``)
    first; among them, those that fit about as closely as the closest fit (RMS ``closest``),
    and among those the one that accounts for the most of its own corners. The six corners of
    a right-angled prism are six of a box's eight: the box fits them as closely (two corners
    unseen), and the prism, which has no corner unseen, is the answer; a box seen with one
    corner hidden is still a box (no prism fits it). A box missing two corners at the ends of
    a diagonal is a box: a prism fits those six only to some per cent of the size (7–10 mm on
    a 160–190 mm box whose own fit is the 0.2 mm noise), and it must not win for its corners."""
    if fit.rms > GOOD_FIT * size:
        return (2, 0, fit.rms)
    if fit.rms > AS_CLOSE * closest + NOISE_FLOOR * size:
        return (1, 0, fit.rms)
    return (0, fit.hidden, fit.rms)


def match(points: ArrayLike) -> list[Fit]:
    """Every library shape fitted to the points, best first (``_rank``)."""
    p = np.asarray(points, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 3 or len(p) < 6:
        raise ValueError(f"need at least 6 points of shape (n, 3); got {p.shape}")
    if not np.isfinite(p).all():
        raise ValueError("points must be finite")
    fits = [fit_box(p), fit_prism(p)]
    cylinder = fit_cylinder(p)
    if cylinder is not None:
        fits.append(cylinder)
    size = float(np.ptp(p, axis=0).max())
    closest = min(f.rms for f in fits)
    return sorted(fits, key=lambda f: _rank(f, size, closest))
