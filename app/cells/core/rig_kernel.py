"""The per-point loop of calibrated-rig triangulation (:func:`app.cells.core.triangulation.
triangulate_views`), compiled by numba. A module of its own so that numba (~100 MB a process
with its compiler and the compiled code) is loaded only by processes that triangulate."""

from __future__ import annotations

import numpy as np
from numba import njit
from numpy.typing import NDArray


@njit(cache=True, nogil=True, error_model="numpy")
def _camera(
    rs: NDArray[np.float64], ts: NDArray[np.float64], k: int, p: NDArray[np.float64]
) -> tuple[float, float, float]:
    """Point ``p`` in camera k's frame: R p + t (eq. 2.14)."""
    return (
        rs[k, 0, 0] * p[0] + rs[k, 0, 1] * p[1] + rs[k, 0, 2] * p[2] + ts[k, 0],
        rs[k, 1, 0] * p[0] + rs[k, 1, 1] * p[1] + rs[k, 1, 2] * p[2] + ts[k, 1],
        rs[k, 2, 0] * p[0] + rs[k, 2, 1] * p[1] + rs[k, 2, 2] * p[2] + ts[k, 2],
    )


@njit(cache=True, nogil=True, error_model="numpy")
def _accumulate(
    m: NDArray[np.float64], b: NDArray[np.float64], row: NDArray[np.float64], rhs: float
) -> None:
    """Add the row ``row · X = rhs`` to the normal equations (m00, m01, m02, m11, m12, m22)
    and their right-hand side."""
    m[0] += row[0] * row[0]
    m[1] += row[0] * row[1]
    m[2] += row[0] * row[2]
    m[3] += row[1] * row[1]
    m[4] += row[1] * row[2]
    m[5] += row[2] * row[2]
    b[0] += row[0] * rhs
    b[1] += row[1] * rhs
    b[2] += row[2] * rhs


@njit(cache=True, nogil=True, error_model="numpy")
def _solve(
    rs: NDArray[np.float64],
    ts: NDArray[np.float64],
    x: NDArray[np.float64],
    y: NDArray[np.float64],
    mask: NDArray[np.bool_],
    p: NDArray[np.float64],
    m: NDArray[np.float64],
    b: NDArray[np.float64],
    row: NDArray[np.float64],
) -> bool:
    """Linear triangulation of one point into ``p`` from normalised coordinates of the views in
    ``mask``: per view (x r₃ − r₁)·X = t₁ − x t₃ and (y r₃ − r₂)·X = t₂ − y t₃, by the 3 × 3
    normal equations (solved by the adjugate). False when they are singular. ``m`` (6), ``b``
    and ``row`` (3) are scratch space."""
    m[:] = 0.0
    b[:] = 0.0
    for k in range(rs.shape[0]):
        if not mask[k]:
            continue
        for axis in range(2):
            obs = x[k] if axis == 0 else y[k]
            for j in range(3):
                row[j] = obs * rs[k, 2, j] - rs[k, axis, j]
            _accumulate(m, b, row, ts[k, axis] - obs * ts[k, 2])
    return _adjugate(m, b, p)


@njit(cache=True, nogil=True, error_model="numpy")
def _adjugate(m: NDArray[np.float64], b: NDArray[np.float64], out: NDArray[np.float64]) -> bool:
    """Solve the symmetric 3 × 3 system (m00, m01, m02, m11, m12, m22) · X = b into ``out``."""
    a, bb, c, d, e, f = m[0], m[1], m[2], m[3], m[4], m[5]
    c00 = d * f - e * e
    c01 = c * e - bb * f
    c02 = bb * e - c * d
    c11 = a * f - c * c
    c12 = bb * c - a * e
    c22 = a * d - bb * bb
    det = a * c00 + bb * c01 + c * c02
    if abs(det) <= 1e-300 or not np.isfinite(det):
        return False
    out[0] = (c00 * b[0] + c01 * b[1] + c02 * b[2]) / det
    out[1] = (c01 * b[0] + c11 * b[1] + c12 * b[2]) / det
    out[2] = (c02 * b[0] + c12 * b[1] + c22 * b[2]) / det
    return True


@njit(cache=True, nogil=True, error_model="numpy")
def _refine(
    rs: NDArray[np.float64],
    ts: NDArray[np.float64],
    pixels: NDArray[np.float64],
    intrinsics: NDArray[np.float64],
    dist: NDArray[np.float64],
    mask: NDArray[np.bool_],
    p: NDArray[np.float64],
    iterations: int,
    m: NDArray[np.float64],
    b: NDArray[np.float64],
    jac: NDArray[np.float64],
    step: NDArray[np.float64],
) -> None:
    """Gauss–Newton on the reprojection error of one point in pixels, through the distortion
    model (eqs. 2.8–2.13), against the observed pixels (V, 2). Refining against OpenCV's
    undistorted coordinates instead carried its inversion's error: five fixed-point
    iterations, 0.15 px in the corners of OpenCV's own sample camera (right, k1 = −0.28), and
    noise-free pixels of that stereo pair came back up to 3e-3 of their depth off
    (tests/core/test_triangulation.py). ``m`` (6), ``b``, ``jac`` and ``step`` (3) are scratch
    space."""
    for _ in range(iterations):
        m[:] = 0.0
        b[:] = 0.0
        for k in range(rs.shape[0]):
            if not mask[k]:
                continue
            cx, cy, cz = _camera(rs, ts, k, p)
            z = cz if abs(cz) > 1e-12 else 1e-12
            x = cx / z
            y = cy / z
            k1, k2, p1, p2, k3 = dist[k, 0], dist[k, 1], dist[k, 2], dist[k, 3], dist[k, 4]
            r2 = x * x + y * y
            radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))  # eq. 2.8
            slope = 2 * (k1 + r2 * (2 * k2 + 3 * r2 * k3))  # d radial / d r², doubled
            xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
            yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
            # ∂(xd, yd)/∂(x, y)
            dxx = radial + x * x * slope + 2 * p1 * y + 6 * p2 * x
            dxy = x * y * slope + 2 * p1 * x + 2 * p2 * y  # = ∂yd/∂x
            dyy = radial + y * y * slope + 6 * p1 * y + 2 * p2 * x
            fx, skew, u0, fy, v0 = (
                intrinsics[k, 0], intrinsics[k, 1], intrinsics[k, 2], intrinsics[k, 3],
                intrinsics[k, 4],
            )  # fmt: skip
            ru = fx * xd + skew * yd + u0 - pixels[k, 0]  # eqs. 2.12–2.13
            rv = fy * yd + v0 - pixels[k, 1]
            for axis in range(2):
                for j in range(3):
                    # ∂(x, y)/∂X: (r_axis − (cam_axis/z) r₃)/z, then through the distortion
                    jx = (rs[k, 0, j] - x * rs[k, 2, j]) / z
                    jy = (rs[k, 1, j] - y * rs[k, 2, j]) / z
                    ddx = dxx * jx + dxy * jy
                    ddy = dxy * jx + dyy * jy
                    jac[j] = fx * ddx + skew * ddy if axis == 0 else fy * ddy
                _accumulate(m, b, jac, ru if axis == 0 else rv)
        if not _adjugate(m, b, step):
            return
        p -= step


@njit(cache=True, nogil=True, error_model="numpy")
def _error(
    rs: NDArray[np.float64],
    ts: NDArray[np.float64],
    f: float,
    k: int,
    x: float,
    y: float,
    p: NDArray[np.float64],
) -> float:
    """Distance [≈ px] in view k between the point's projection and the normalised observation
    (x, y), scaled by the focal length; inf behind the camera."""
    cx, cy, cz = _camera(rs, ts, k, p)
    if cz <= 0:
        return np.inf
    return float(np.hypot(cx / cz - x, cy / cz - y) * f)


@njit(cache=True, nogil=True, error_model="numpy")
def triangulate_all(
    rs: NDArray[np.float64],
    ts: NDArray[np.float64],
    fs: NDArray[np.float64],
    xs: NDArray[np.float64],
    ys: NDArray[np.float64],
    seen: NDArray[np.bool_],
    outlier_px: float,
    iterations: int,
    pixels: NDArray[np.float64],
    intrinsics: NDArray[np.float64],
    dist: NDArray[np.float64],
    points: NDArray[np.float64],
    use: NDArray[np.bool_],
    rms: NDArray[np.float64],
) -> None:
    """Every point: linear solution and Gauss–Newton on all its views; if it has 3+ views and
    one is off by more than ``outlier_px``, RANSAC over view pairs (the pair whose point most
    views agree with picks the inliers) and a new solution from the inliers. Then the RMS
    distance between its projections (eqs. 2.8–2.13, as in ``triangulation.distort``) and
    ``pixels`` (N, V, 2) over the views used; ``intrinsics`` (V, 5) = fx, skew·fx, cx, fy, cy."""
    n, v = seen.shape
    p = np.empty(3)
    trial = np.empty(3)
    mask = np.empty(v, np.bool_)
    best_mask = np.empty(v, np.bool_)
    m = np.empty(6)
    b = np.empty(3)
    s1 = np.empty(3)
    s2 = np.empty(3)
    for i in range(n):
        x = xs[i]
        y = ys[i]
        count = 0
        for k in range(v):
            use[i, k] = seen[i, k]
            count += seen[i, k]
        points[i, :] = np.nan
        rms[i] = np.nan
        if count < 2 or not _solve(rs, ts, x, y, seen[i], p, m, b, s1):
            continue
        _refine(rs, ts, pixels[i], intrinsics, dist, seen[i], p, iterations, m, b, s1, s2)
        worst = 0.0
        for k in range(v):
            if seen[i, k]:
                worst = max(worst, _error(rs, ts, fs[k], k, x[k], y[k], p))
        if count >= 3 and not worst <= outlier_px:
            best = -1
            for a in range(v):
                for c in range(a + 1, v):
                    if not (seen[i, a] and seen[i, c]):
                        continue
                    mask[:] = False
                    mask[a] = mask[c] = True
                    if not _solve(rs, ts, x, y, mask, trial, m, b, s1):
                        continue
                    agree = 0
                    for k in range(v):
                        mask[k] = seen[i, k] and (
                            _error(rs, ts, fs[k], k, x[k], y[k], trial) <= outlier_px
                        )
                        agree += mask[k]
                    if agree > best:
                        best = agree
                        best_mask[:] = mask
            if best >= 2:
                use[i, :] = best_mask
                if not _solve(rs, ts, x, y, best_mask, p, m, b, s1):
                    continue
                _refine(rs, ts, pixels[i], intrinsics, dist, best_mask, p, iterations, m, b, s1, s2)
        points[i, :] = p
        total = 0.0
        used = 0
        for k in range(v):
            if not use[i, k]:
                continue
            cx, cy, cz = _camera(rs, ts, k, p)
            xd, yd = _distort_one(cx / cz, cy / cz, dist[k])
            du = intrinsics[k, 0] * xd + intrinsics[k, 1] * yd + intrinsics[k, 2] - pixels[i, k, 0]
            dv = intrinsics[k, 3] * yd + intrinsics[k, 4] - pixels[i, k, 1]
            total += du * du + dv * dv
            used += 1
        rms[i] = np.sqrt(total / used)


@njit(cache=True, nogil=True, error_model="numpy")
def _distort_one(x: float, y: float, k: NDArray[np.float64]) -> tuple[float, float]:
    """One point through eqs. 2.8–2.10 (see :func:`distort`)."""
    r2 = x * x + y * y
    radial = 1 + r2 * (k[0] + r2 * (k[1] + r2 * k[4]))
    xy = x * y
    return (
        x * radial + 2 * k[2] * xy + k[3] * (r2 + 2 * x * x),
        y * radial + k[2] * (r2 + 2 * y * y) + 2 * k[3] * xy,
    )
