"""Matching located corner points to a library of regular parts ("compared to a library of all
possible regular geometries", chapter 4, Applications): rectangular box, triangular prism,
cylinder. Each fit gives the shape's dimensions, pose and the RMS distance of the points from
it; the shapes are ranked by that residual.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray


@dataclass(frozen=True, slots=True)
class Fit:
    shape: str
    dimensions: dict[str, float]
    centre: NDArray[np.float64]
    axes: NDArray[np.float64]
    """Rows: the shape's local x, y, z axes in world coordinates."""
    rms: float
    """RMS distance of the points from the fitted model's features [world units]."""


def _frame(p: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    centre = p.mean(axis=0)
    _, _, vt = np.linalg.svd(p - centre)
    if np.linalg.det(vt) < 0:
        vt[2] *= -1
    return centre, vt


def _nearest_rms(points: NDArray[np.float64], model: NDArray[np.float64]) -> float:
    d = np.linalg.norm(points[:, None, :] - model[None, :, :], axis=-1)
    return float(np.sqrt(np.mean(d.min(axis=1) ** 2)))


def fit_box(points: NDArray[np.float64]) -> Fit:
    """Corners of a rectangular box: principal axes, extents, residual to the 8 corners."""
    centre, axes = _frame(points)
    local = (points - centre) @ axes.T
    half = np.abs(local).max(axis=0)
    lo, hi = local.min(axis=0), local.max(axis=0)
    mid = (lo + hi) / 2
    half = (hi - lo) / 2
    corners = np.array(list(itertools.product(*[(-h, h) for h in half]))) + mid
    world = corners @ axes + centre
    dims = sorted((2 * half).tolist(), reverse=True)
    return Fit(
        "box",
        {"length": dims[0], "width": dims[1], "height": dims[2]},
        centre + mid @ axes,
        axes,
        _nearest_rms(points, world),
    )


def fit_prism(points: NDArray[np.float64]) -> Fit:
    """Corners of a triangular prism: the axis is the principal direction along which the points
    split into two triangles; residual to the 6 corners of the fitted prism."""
    centre, axes = _frame(points)
    best: Fit | None = None
    for k in range(3):  # try each principal axis as the prism's axis
        ax = axes[k]
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
        fit = Fit(
            "prism",
            {"length": abs(length), "side_a": sides[0], "side_b": sides[1], "side_c": sides[2]},
            centre,
            axes,
            _nearest_rms(points, model),
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


def fit_cylinder(points: NDArray[np.float64]) -> Fit | None:
    """Points on a cylinder's two rims: the axis is the principal direction whose cross-section
    is most circular; residual is the spread of the radial distance. None when no axis has at
    least ``MIN_RIM_POINTS`` points at each end."""
    centre, axes = _frame(points)
    best: Fit | None = None
    for k in range(3):
        ax = axes[k]
        t = (points - centre) @ ax
        upper = t > np.median(t)
        if min(upper.sum(), (~upper).sum()) < MIN_RIM_POINTS:
            continue
        section = (points - centre) - np.outer(t, ax)
        # circle centre in the section plane: least squares on |q − c|² = r²
        u, v = axes[(k + 1) % 3], axes[(k + 2) % 3]
        q = np.column_stack([section @ u, section @ v])
        a = np.column_stack([2 * q, np.ones(len(q))])
        sol, *_ = np.linalg.lstsq(a, (q**2).sum(axis=1), rcond=None)
        c2 = sol[:2]
        r = float(np.sqrt(max(sol[2] + c2 @ c2, 0.0)))
        radial = np.linalg.norm(q - c2, axis=1)
        fit = Fit(
            "cylinder",
            {"radius": r, "height": float(np.ptp(t))},
            centre + c2[0] * u + c2[1] * v,
            np.array([u, v, ax]),
            float(np.sqrt(np.mean((radial - r) ** 2))),
        )
        if best is None or fit.rms < best.rms:
            best = fit
    return best


def match(points: ArrayLike) -> list[Fit]:
    """Every library shape fitted to the points, best (smallest residual) first."""
    p = np.asarray(points, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 3 or len(p) < 6:
        raise ValueError(f"need at least 6 points of shape (n, 3); got {p.shape}")
    if not np.isfinite(p).all():
        raise ValueError("points must be finite")
    fits = [fit_box(p), fit_prism(p)]
    cylinder = fit_cylinder(p)
    if cylinder is not None:
        fits.append(cylinder)
    return sorted(fits, key=lambda f: f.rms)
