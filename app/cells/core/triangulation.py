"""Locating points in 3-D from several calibrated views: the 4-camera cross (chapter 4) and any
rig of 2+ calibrated cameras.

The cross, in the contract's frame ([Fayed 2013]'s Figure 4.3 with a pinhole at each lens)::

            Y ↑            camera 3 (0, +ay/2)
              |                  ●
    camera 2  ●--------+--------●  camera 1        X →   (Z forward, out of the page)
   (−ax/2, 0)          |         (+ax/2, 0)
                       ●
                 camera 4 (0, −ay/2)

All four look along +Z with focal length f [px]; a point (X, Y, Z) is seen by camera i at
u = cx + f (X − Xᵢ)/Z, v = cy − f (Y − Yᵢ)/Z. [Fayed 2013] writes the image plane as
x = fX/(f − Z) (eq. 4.4) and gets Z = f(1 − A/(x₂ − x₁)) (4.14); with the pinhole above the same
derivation gives Z = B/d: for cameras i, j and normalised coordinates xᵢ = (uᵢ − cx)/f,
yᵢ = −(vᵢ − cy)/f, xᵢ − xⱼ = (Xⱼ − Xᵢ)/Z and yᵢ − yⱼ = (Yⱼ − Yᵢ)/Z. The pairs (1,2) and (3,4)
give one estimate each (4.14, 4.24), the four diagonal pairs two each (4.28–4.41): ten.
"""

from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

PAIRS: tuple[tuple[int, int, str], ...] = (
    (0, 1, "x"),  # cameras 1–2, baseline ax (eq. 4.14)
    (2, 3, "y"),  # cameras 3–4, baseline ay (4.24)
    (0, 2, "x"),
    (0, 2, "y"),  # 1–3 (4.28, 4.29)
    (0, 3, "x"),
    (0, 3, "y"),  # 1–4 (4.40, 4.41)
    (1, 2, "x"),
    (1, 2, "y"),  # 2–3 (4.32, 4.33)
    (1, 3, "x"),
    (1, 3, "y"),  # 2–4 (4.36, 4.37)
)
"""The ten estimates: (camera i, camera j, axis), cameras numbered from 0."""


@dataclass(frozen=True, slots=True)
class CrossRig:
    f: float
    """Focal length [px]."""
    ax: float
    """Horizontal baseline, camera 2 to camera 1 [world units]."""
    ay: float
    """Vertical baseline, camera 4 to camera 3 [world units]."""
    cx: float = 0.0
    cy: float = 0.0

    @property
    def centres(self) -> NDArray[np.float64]:
        """Lens centres (Xᵢ, Yᵢ), shape (4, 2)."""
        return np.array(
            [[self.ax / 2, 0.0], [-self.ax / 2, 0.0], [0.0, self.ay / 2], [0.0, -self.ay / 2]]
        )

    def project(self, points: NDArray[np.float64]) -> NDArray[np.float64]:
        """(N, 3) world points → (N, 4, 2) pixels (u, v) in cameras 1–4."""
        p = np.asarray(points, dtype=np.float64)
        c = self.centres
        u = self.cx + self.f * (p[:, None, 0] - c[None, :, 0]) / p[:, None, 2]
        v = self.cy - self.f * (p[:, None, 1] - c[None, :, 1]) / p[:, None, 2]
        return np.stack([u, v], axis=-1)

    def normalised(self, obs: NDArray[np.float64]) -> NDArray[np.float64]:
        """Pixels (N, 4, 2) → (xᵢ, yᵢ) = ((u − cx)/f, −(v − cy)/f)."""
        x = (obs[..., 0] - self.cx) / self.f
        y = -(obs[..., 1] - self.cy) / self.f
        return np.stack([x, y], axis=-1)

    def baselines(self) -> NDArray[np.float64]:
        """The baseline B of each of the ten estimates (signed), shape (10,)."""
        c = self.centres
        return np.array(
            [c[j, 0 if a == "x" else 1] - c[i, 0 if a == "x" else 1] for i, j, a in PAIRS]
        )


@dataclass(frozen=True, slots=True)
class CrossResult:
    points: NDArray[np.float64]
    """(N, 3) [world units]."""
    z_estimates: NDArray[np.float64]
    """(N, 10): the pairwise depths, NaN where a pair lacks a view or has no disparity."""
    z_spread: NDArray[np.float64]
    """(N,): standard deviation of the available estimates."""
    reprojection_rms: NDArray[np.float64]
    """(N,) [px]."""
    behind: NDArray[np.bool_]
    """(N,): points left out because their rays meet behind the lens plane (mismatched
    pixels), where nothing in front of it was found."""


def _signed_depths(rig: CrossRig, obs: NDArray[np.float64]) -> NDArray[np.float64]:
    """The ten pairwise Z = B/d of each point, of either sign; ±inf or NaN where a pair has no
    disparity or lacks a view."""
    n = rig.normalised(obs)
    b = rig.baselines()
    out = np.full((obs.shape[0], len(PAIRS)), np.nan)
    for k, (i, j, axis) in enumerate(PAIRS):
        a = 0 if axis == "x" else 1
        with np.errstate(divide="ignore", invalid="ignore"):
            out[:, k] = b[k] / (n[:, i, a] - n[:, j, a])
    return out


def z_estimates(rig: CrossRig, obs: NDArray[np.float64]) -> NDArray[np.float64]:
    """The ten pairwise depth estimates Z = B/d of each point (module docstring): NaN where a
    pair has no disparity, lacks a view, or sees the point behind the lens plane."""
    return _in_front(_signed_depths(rig, obs))


def _in_front(z: NDArray[np.float64]) -> NDArray[np.float64]:
    with np.errstate(invalid="ignore"):
        return np.where(np.isfinite(z) & (z > 0), z, np.nan)


def _nanmean(a: NDArray[np.float64], axis: int) -> NDArray[np.float64]:
    """``np.nanmean`` that answers NaN for an all-NaN slice without a warning (a point with no
    usable view or estimate is NaN, not an event)."""
    ok = ~np.isnan(a)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.asarray(np.where(ok, a, 0.0).sum(axis=axis) / ok.sum(axis=axis))


def _nanstd(a: NDArray[np.float64], axis: int) -> NDArray[np.float64]:
    """``np.nanstd`` (population), NaN for an all-NaN slice without a warning."""
    mean = np.expand_dims(_nanmean(a, axis), axis)
    return np.sqrt(_nanmean((a - mean) ** 2, axis))


def _xy(rig: CrossRig, obs: NDArray[np.float64], z: NDArray[np.float64]) -> NDArray[np.float64]:
    """X and Y from Z, averaged over the views present (the analogue of 4.15–4.16)."""
    n = rig.normalised(obs)
    c = rig.centres
    x = _nanmean(n[..., 0] * z[:, None] + c[None, :, 0], axis=1)
    y = _nanmean(n[..., 1] * z[:, None] + c[None, :, 1], axis=1)
    return np.column_stack([x, y, z])


def _rms(
    rig: CrossRig, obs: NDArray[np.float64], points: NDArray[np.float64]
) -> NDArray[np.float64]:
    err = rig.project(points) - obs
    return np.sqrt(_nanmean((err**2).sum(axis=-1), axis=1))


def triangulate_cross(
    rig: CrossRig, obs: NDArray[np.float64], *, method: str = "least_squares"
) -> CrossResult:
    """Points from cross observations (N, 4, 2) [px]; NaN for a missing view.

    method
        ``mean``: the plain mean of the ten estimates (eq. 4.47, [Fayed 2013]'s least squares
        over Ẑᵢ = Z + εᵢ, 4.42–4.46). ``weighted``: inverse-variance weights — with pixel noise σ
        each estimate's variance is ≈ 2σ²Z⁴/(f²B²), so the weight is B² (a short-baseline pair
        counts a quarter of a long one; the estimates share views, so this is the minimum-
        variance combination only to first order). ``least_squares``: all eight image
        coordinates at once, f X − (uᵢ − cx) Z = f Xᵢ and f Y + (vᵢ − cy) Z = f Yᵢ, solved
        linearly, then refined by Gauss–Newton on the reprojection error (maximum likelihood
        for Gaussian pixel noise).
    """
    obs = np.asarray(obs, dtype=np.float64)
    if obs.ndim != 3 or obs.shape[1:] != (4, 2):
        raise ValueError(f"observations must have shape (N, 4, 2); got {obs.shape}")
    signed = _signed_depths(rig, obs)
    est = _in_front(signed)
    # the points none of whose pairs gave a depth in front: behind when some pair's Z = B/d was
    # negative (disparities of the wrong sign, 4.14–4.41); few, so looked at alone
    backwards = np.zeros(len(obs), np.bool_)
    none = np.isnan(est).all(axis=1)
    if none.any():
        lone = signed[none]
        with np.errstate(invalid="ignore"):
            backwards[none] = (np.isfinite(lone) & (lone < 0)).any(axis=1)
    del signed
    if method == "mean":
        z = _nanmean(est, axis=1)  # eq. 4.47
        points = _xy(rig, obs, z)
    elif method == "weighted":
        w = np.where(np.isnan(est), 0.0, rig.baselines() ** 2)
        with np.errstate(invalid="ignore", divide="ignore"):  # no estimate at all: NaN
            z = np.nansum(est * w, axis=1) / w.sum(axis=1)
        points = _xy(rig, obs, z)
    elif method == "least_squares":
        points = _least_squares(rig, obs)
        # behind the lens plane: no camera saw it, the views were mismatched (pixels swapped
        # between cameras give a point mirrored to Z < 0 that reprojects exactly); the pairwise
        # estimates drop such a depth likewise
        with np.errstate(invalid="ignore"):
            backwards = points[:, 2] <= 0
            points[~(points[:, 2] > 0)] = np.nan
    else:
        raise ValueError(f"unknown method {method!r}")
    spread = _nanstd(est, axis=1)
    return CrossResult(
        points, est, spread, _rms(rig, obs, points), np.asarray(backwards, dtype=np.bool_)
    )


def _solve_each(m: NDArray[np.float64], v: NDArray[np.float64]) -> NDArray[np.float64]:
    """Solve each of the systems m[i] x = v[i] (3×3); NaN for one that is singular. The
    normal equations of a point seen with no disparity in any view (at infinity, or the same
    pixel in every camera) have no depth column."""
    try:
        return np.asarray(np.linalg.solve(m, v[..., None])[..., 0], dtype=np.float64)
    except np.linalg.LinAlgError:  # rare: find the singular ones, solve the rest
        pass
    scale = np.abs(m).max(axis=(1, 2)) ** 3
    with np.errstate(invalid="ignore"):  # a point already NaN
        det = np.linalg.det(m)
    bad = ~(np.isfinite(det) & (np.abs(det) > 1e-12 * scale))
    x = np.linalg.solve(np.where(bad[:, None, None], np.eye(3), m), v[..., None])[..., 0]
    x[bad] = np.nan
    return np.asarray(x, dtype=np.float64)


def _least_squares(
    rig: CrossRig, obs: NDArray[np.float64], iterations: int = 5
) -> NDArray[np.float64]:
    n_pts = obs.shape[0]
    c = rig.centres
    f = rig.f
    du = obs[..., 0] - rig.cx  # (N, 4)
    dv = obs[..., 1] - rig.cy
    ok = np.isfinite(du) & np.isfinite(dv)
    # linear: rows [f, 0, −du] · P = f Xᵢ and [0, f, dv] · P = f Yᵢ
    a = np.zeros((n_pts, 8, 3))
    b = np.zeros((n_pts, 8))
    a[:, 0::2, 0] = f
    a[:, 0::2, 2] = -np.where(ok, du, 0)
    a[:, 1::2, 1] = f
    a[:, 1::2, 2] = np.where(ok, dv, 0)
    b[:, 0::2] = f * c[None, :, 0]
    b[:, 1::2] = f * c[None, :, 1]
    mask = np.repeat(ok, 2, axis=1)[..., None]
    a, b = a * mask, b * mask[..., 0]
    ata = np.einsum("nki,nkj->nij", a, a)
    atb = np.einsum("nki,nk->ni", a, b)
    p = _solve_each(ata, atb)
    for _ in range(iterations):  # Gauss–Newton on the reprojection error
        x, y, z = p[:, 0:1], p[:, 1:2], p[:, 2:3]
        ru = np.where(ok, rig.cx + f * (x - c[None, :, 0]) / z - obs[..., 0], 0)
        rv = np.where(ok, rig.cy - f * (y - c[None, :, 1]) / z - obs[..., 1], 0)
        j = np.zeros((n_pts, 8, 3))
        j[:, 0::2, 0] = f / z
        j[:, 0::2, 2] = -f * (x - c[None, :, 0]) / z**2
        j[:, 1::2, 1] = -f / z
        j[:, 1::2, 2] = f * (y - c[None, :, 1]) / z**2
        j *= mask
        r = np.empty((n_pts, 8))
        r[:, 0::2], r[:, 1::2] = ru, rv
        jtj = np.einsum("nki,nkj->nij", j, j)
        jtr = np.einsum("nki,nk->ni", j, r)
        p = p - _solve_each(jtj, jtr)
    return p


GAUSS_NEWTON_STEPS = 2
"""From the linear solution two steps reach the reprojection-error minimum to well below a
micrometre at 1–5 m with 0.3 px noise (tests/core/test_triangulation.py)."""


@dataclass(frozen=True, slots=True)
class View:
    """A calibrated camera: x_cam = R X + t (OpenCV convention), intrinsics K, distortion."""

    K: NDArray[np.float64]
    dist: NDArray[np.float64]
    R: NDArray[np.float64]
    t: NDArray[np.float64]


def lens_centres(rs: NDArray[np.float64], ts: NDArray[np.float64]) -> NDArray[np.float64]:
    """(V, 3) lens centres in the world frame, −Rᵀt (where x_cam = 0), of stacked (V, 3, 3)
    rotations and (V, 3) translations."""
    return np.asarray(-np.einsum("vji,vj->vi", rs, ts), dtype=np.float64)


COINCIDENT = 1e-9
"""Lens centres closer than this are one: a fraction of their largest distance from the
world's origin, or of one world unit when they all lie nearer than that."""


AT_LENS = 1e-3
"""A point nearer a camera that saw it than this fraction of the rig's baseline (along the
camera's axis) was not seen: it would show a disparity of 1000 f px. The linear solution of
rays that diverge (pixels of two different points) comes to rest there, at the lenses where
the rays pass closest, with a reprojection error of 10¹³ px; it is no more a point than one
behind a camera."""


def baseline(rs: NDArray[np.float64], ts: NDArray[np.float64]) -> float:
    """The largest distance between two lens centres of stacked rotations and translations
    (``RigArrays.rs``, ``.ts``). Zero (to ``COINCIDENT``) means that no point can be
    triangulated: every view's ray through a point starts at the same centre."""
    c = lens_centres(rs, ts)
    spread = float(np.linalg.norm(c[:, None] - c[None], axis=2).max())
    return 0.0 if spread <= COINCIDENT * max(1.0, float(np.abs(c).max())) else spread


def behind(
    points: NDArray[np.float64],
    rs: NDArray[np.float64],
    ts: NDArray[np.float64],
    seen: NDArray[np.bool_],
) -> NDArray[np.bool_]:
    """(N,) True where a found point (finite) lies behind, or within ``AT_LENS`` of the
    baseline in front of, a view that saw it (``seen``, (N, V)): such a point was never seen
    (the views were mismatched, or the rays only come closest at the lenses)."""
    # (N, V): z in each camera's frame; not through BLAS (`@`), whose threads would spin on
    # for a while after it and take the cores from the next call's compiled loop (the bench:
    # 100,000 points in 80 ms instead of 41)
    depth = np.einsum("nk,vk->nv", points, rs[:, 2, :]) + ts[:, 2]
    nearest = AT_LENS * baseline(rs, ts)
    found = np.isfinite(points).all(axis=1)
    with np.errstate(invalid="ignore"):
        return np.asarray(found & (seen & ~(depth > nearest)).any(axis=1), dtype=np.bool_)


@dataclass(frozen=True, slots=True)
class RigResult:
    points: NDArray[np.float64]
    """(N, 3) in the world frame; NaN where fewer than 2 views remain, or the point lies behind
    a camera that saw it."""
    reprojection_rms: NDArray[np.float64]
    """(N,) [px] over the views used."""
    used: NDArray[np.bool_]
    """(N, V): the views each point was triangulated from (outliers rejected)."""
    behind: NDArray[np.bool_]
    """(N,): points left out because they lie behind a camera that saw them (mismatched
    views)."""


def decompose_projection(
    p: NDArray[np.float64],
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """K (fx, fy > 0, K[2,2] = 1), R (det +1) and t of a 3 × 4 projection matrix P = λ K [R | t]
    (eq. 2.14 with 2.12–2.13), as multi-view data sets publish cameras.

    RQ-decompose P's left 3 × 3 block M = K̃ R; flip signs in pairs (a column of K̃ with the row
    of R) until K̃'s diagonal is positive, which leaves K̃ R unchanged; λ = K̃[2,2] > 0, K = K̃/λ,
    t = K̃⁻¹ p₄. P is taken as published, visible points at w > 0: its scale's sign is kept, so a
    det M < 0 leaves det R = −1, a mirror-handed camera (or P scaled by a negative number),
    which no lens gives: ValueError saying so. A singular M (a camera at infinity, or not a
    camera) is a ValueError too."""
    from scipy.linalg import rq

    p = np.asarray(p, dtype=np.float64)
    if p.shape != (3, 4) or not np.isfinite(p).all():
        raise ValueError(f"P must be 3 × 4 and finite; got shape {p.shape}")
    m = p[:, :3]
    scale = float(np.abs(m).max())
    if scale == 0 or abs(np.linalg.det(m / scale)) < 1e-12:
        raise ValueError("P's left 3 × 3 block is singular: not a finite projective camera")
    k, r = rq(m)
    signs = np.sign(np.diag(k))
    k, r = k * signs, signs[:, None] * r  # K̃ D, D R with D = diag(signs): the product holds
    if np.linalg.det(r) < 0:
        raise ValueError(
            "P is mirror-handed: its left 3 × 3 block has a negative determinant, so no "
            "rotation with positive focal lengths gives it (if it was scaled by a negative "
            "number, give −P)"
        )
    t = np.linalg.solve(k, p[:, 3])
    return k / k[2, 2] + 0.0, r, t  # + 0.0: no −0.0 in the answer


def _dist5(dist: NDArray[np.float64]) -> NDArray[np.float64]:
    """Distortion coefficients as k1, k2, p1, p2, k3 (missing ones zero)."""
    k = np.zeros(5)
    d = np.asarray(dist, dtype=np.float64).ravel()[:5]
    k[: len(d)] = d
    return k


def distort(xn: NDArray[np.float64], dist: NDArray[np.float64]) -> NDArray[np.float64]:
    """Normalised pinhole coordinates (..., 2) → distorted (eqs. 2.6–2.10), k = [k1, k2, p1,
    p2, k3] (2.7). Eq. 2.9 as printed drops the 2 of the y row's 2 k_t2 x y term; Bouguet's
    toolbox and OpenCV, whose calibrations we read, have it, and so do we."""
    k = _dist5(dist)
    x, y = xn[..., 0], xn[..., 1]
    r2 = x * x + y * y
    radial = 1 + r2 * (k[0] + r2 * (k[1] + r2 * k[4]))  # eq. 2.8
    xy = x * y
    xd = x * radial + 2 * k[2] * xy + k[3] * (r2 + 2 * x * x)  # eqs. 2.9–2.10
    yd = y * radial + k[2] * (r2 + 2 * y * y) + 2 * k[3] * xy
    return np.stack([xd, yd], axis=-1)


def project_views(views: list[View], points: NDArray[np.float64]) -> NDArray[np.float64]:
    """(N, 3) world points → (N, V, 2) pixels: P = R Pw + T (2.14), normalise (2.6),
    distort (2.8–2.10), then KK (2.12–2.13, skew included)."""
    points = np.asarray(points, dtype=np.float64)
    out = np.empty((len(points), len(views), 2))
    for k, v in enumerate(views):
        cam = points @ np.asarray(v.R, dtype=np.float64).T + np.asarray(v.t).ravel()
        with np.errstate(divide="ignore", invalid="ignore"):
            xd = distort(cam[:, :2] / cam[:, 2:3], v.dist)
        kk = np.asarray(v.K, dtype=np.float64)
        out[:, k, 0] = kk[0, 0] * xd[:, 0] + kk[0, 1] * xd[:, 1] + kk[0, 2]
        out[:, k, 1] = kk[1, 1] * xd[:, 1] + kk[1, 2]
    return out


def undistort(view: View, uv: NDArray[np.float64]) -> NDArray[np.float64]:
    """Pixels (N, 2) of one view → undistorted normalised coordinates (N, 2) (OpenCV)."""
    import cv2

    pts = np.ascontiguousarray(uv, dtype=np.float64).reshape(-1, 1, 2)
    return np.asarray(cv2.undistortPoints(pts, view.K, view.dist).reshape(-1, 2))


def _normalised(views: list[View], obs: NDArray[np.float64]) -> NDArray[np.float64]:
    """Pixels (N, V, 2) → undistorted normalised coordinates; NaN stays NaN."""
    out = np.empty(obs.shape)
    for k, v in enumerate(views):
        out[:, k] = undistort(v, obs[:, k])  # OpenCV passes NaN (a missing view) through
    out[~np.isfinite(obs).all(axis=-1)] = np.nan
    return out


def triangulate_views(
    views: list[View],
    obs: NDArray[np.float64],
    *,
    outlier_px: float = 3.0,
    refine: bool = True,
    steps: int = GAUSS_NEWTON_STEPS,
) -> RigResult:
    """Points from pixel observations (N, V, 2) of V ≥ 2 calibrated cameras; NaN for a missing
    view. Undistort (OpenCV), then per point: linear triangulation and Gauss–Newton on the
    reprojection error in pixels, through the distortion model; a point seen by ≥ 3 views
    with a view off by more than ``outlier_px`` goes to RANSAC over all view pairs: the pair
    whose point agrees with most other views picks the inliers, and the point is re-solved
    from them. The per-point work is one compiled loop (numba); large batches are split over
    the cores (OpenCV and the loop release the GIL)."""
    obs = np.asarray(obs, dtype=np.float64)
    n, v = obs.shape[0], len(views)
    if obs.ndim != 3 or obs.shape[1:] != (v, 2):
        raise ValueError(f"observations must have shape (N, {v}, 2); got {obs.shape}")
    rig = RigArrays.of(views)
    points = np.empty((n, 3))
    use = np.empty((n, v), np.bool_)
    rms = np.empty(n)
    if n <= SMALL_BATCH:  # no compiler to load for a handful of points: NumPy, the same maths
        _chunk_numpy(views, rig, obs, float(outlier_px), steps if refine else 0, points, use, rms)
        return _checked(points, rms, use, rig)
    workers = min(os.cpu_count() or 1, 4) if n >= 20_000 else 1
    bounds = np.linspace(0, n, workers + 1).astype(int)
    jobs = [
        (slice(a, b), views, rig, obs, float(outlier_px), steps if refine else 0, points, use, rms)
        for a, b in zip(bounds[:-1], bounds[1:], strict=True)
    ]
    if workers == 1:
        _chunk(*jobs[0])
    else:
        with ThreadPoolExecutor(workers) as pool:
            list(pool.map(lambda job: _chunk(*job), jobs))
    return _checked(points, rms, use, rig)


def _checked(
    points: NDArray[np.float64],
    rms: NDArray[np.float64],
    use: NDArray[np.bool_],
    rig: RigArrays,
) -> RigResult:
    # a point behind a camera that saw it was never seen: the views were mismatched
    back = behind(points, rig.rs, rig.ts, use)
    lost = back | ~np.isfinite(points).all(axis=1)  # or rays that never meet (parallel)
    points[lost], rms[lost], use[lost] = np.nan, np.nan, False
    return RigResult(points, rms, use, back)


@dataclass(frozen=True, slots=True)
class RigArrays:
    """The views' parameters stacked for the compiled loop (and the laser grid's geometry)."""

    rs: NDArray[np.float64]
    ts: NDArray[np.float64]
    fs: NDArray[np.float64]
    intrinsics: NDArray[np.float64]
    """(V, 5): fx, skew·fx, cx, fy, cy."""
    dist: NDArray[np.float64]
    """(V, 5): k1, k2, p1, p2, k3."""

    @classmethod
    def of(cls, views: list[View]) -> RigArrays:
        dist = np.stack([_dist5(x.dist) for x in views])
        return cls(
            np.ascontiguousarray(np.stack([np.asarray(x.R, dtype=np.float64) for x in views])),
            np.ascontiguousarray(
                np.stack([np.asarray(x.t, dtype=np.float64).ravel() for x in views])
            ),
            np.array([float(np.sqrt(x.K[0, 0] * x.K[1, 1])) for x in views]),
            np.array(
                [[x.K[0, 0], x.K[0, 1], x.K[0, 2], x.K[1, 1], x.K[1, 2]] for x in views],
                dtype=np.float64,
            ),
            dist,
        )


def _chunk(
    rows: slice,
    views: list[View],
    rig: RigArrays,
    obs: NDArray[np.float64],
    outlier_px: float,
    iterations: int,
    points: NDArray[np.float64],
    use: NDArray[np.bool_],
    rms: NDArray[np.float64],
) -> None:
    """Triangulate ``obs[rows]`` into the same rows of the outputs."""
    from app.cells.core.rig_kernel import triangulate_all  # numba: imported on first use only

    part = np.ascontiguousarray(obs[rows])
    xn = _normalised(views, part)
    out_p = np.empty((len(part), 3))
    out_u = np.empty((len(part), len(views)), np.bool_)
    out_r = np.empty(len(part))
    triangulate_all(
        rig.rs,
        rig.ts,
        rig.fs,
        np.ascontiguousarray(xn[..., 0]),
        np.ascontiguousarray(xn[..., 1]),
        np.ascontiguousarray(np.isfinite(xn).all(axis=-1)),
        outlier_px,
        iterations,
        part,
        rig.intrinsics,
        rig.dist,
        out_p,
        out_u,
        out_r,
    )
    points[rows], use[rows], rms[rows] = out_p, out_u, out_r


SMALL_BATCH = 2_000
"""Up to this many points are triangulated by ``_chunk_numpy``: a fresh process answers its
first small request without loading numba (0.6 s to import) and its compiled loop."""


def _linear(
    rig: RigArrays, xn: NDArray[np.float64], mask: NDArray[np.bool_]
) -> NDArray[np.float64]:
    """Linear triangulation of every point (N, 3) from normalised coordinates (N, V, 2) of the
    views in ``mask`` (N, V): per view (x r₃ − r₁)·X = t₁ − x t₃ and (y r₃ − r₂)·X = t₂ − y t₃,
    by the 3 × 3 normal equations; NaN where they are singular. ``rig_kernel._solve``, for
    many points at once."""
    x = np.where(mask[..., None], xn, 0.0)
    rows = x[..., None] * rig.rs[None, :, 2, None, :] - rig.rs[None, :, :2, :]  # (N, V, 2, 3)
    rhs = rig.ts[None, :, :2] - x * rig.ts[None, :, 2, None]  # (N, V, 2)
    w = mask[..., None].astype(np.float64)
    m = np.einsum("nvai,nvaj,nva->nij", rows, rows, w)
    b = np.einsum("nvai,nva,nva->ni", rows, rhs, w)
    return _solve_batch(m, b)


def _solve_batch(m: NDArray[np.float64], b: NDArray[np.float64]) -> NDArray[np.float64]:
    """X from m X = b for every (3, 3) m; NaN where m is singular."""
    det = np.linalg.det(m)
    ok = np.isfinite(det) & (np.abs(det) > 1e-300)
    out = np.full(b.shape, np.nan)
    if ok.any():
        out[ok] = np.linalg.solve(m[ok], b[ok][..., None])[..., 0]
    return out


def _gauss_newton(
    rig: RigArrays,
    pixels: NDArray[np.float64],
    mask: NDArray[np.bool_],
    p: NDArray[np.float64],
    iterations: int,
) -> NDArray[np.float64]:
    """Gauss–Newton on the reprojection error in pixels through the distortion model (eqs.
    2.8–2.13) for every point (N, 3) at once: ``rig_kernel._refine``, vectorised. A point
    whose normal equations turn singular keeps its last estimate."""
    fx, skew, u0, fy, v0 = (rig.intrinsics[:, j] for j in range(5))
    k1, k2, p1, p2, k3 = (rig.dist[:, j] for j in range(5))
    w = mask.astype(np.float64)
    for _ in range(iterations):
        cam = np.einsum("vij,nj->nvi", rig.rs, p) + rig.ts  # (N, V, 3), eq. 2.14
        z = np.where(np.abs(cam[..., 2]) > 1e-12, cam[..., 2], 1e-12)
        x, y = cam[..., 0] / z, cam[..., 1] / z
        r2 = x * x + y * y
        radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))  # eq. 2.8
        slope = 2 * (k1 + r2 * (2 * k2 + 3 * r2 * k3))
        xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
        yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
        dxx = radial + x * x * slope + 2 * p1 * y + 6 * p2 * x
        dxy = x * y * slope + 2 * p1 * x + 2 * p2 * y
        dyy = radial + y * y * slope + 6 * p1 * y + 2 * p2 * x
        # eqs. 2.12–2.13; a view not used has no residual (its pixels may be NaN)
        ru = np.where(mask, fx * xd + skew * yd + u0 - pixels[..., 0], 0.0)
        rv = np.where(mask, fy * yd + v0 - pixels[..., 1], 0.0)
        jx = (rig.rs[None, :, 0, :] - x[..., None] * rig.rs[None, :, 2, :]) / z[..., None]
        jy = (rig.rs[None, :, 1, :] - y[..., None] * rig.rs[None, :, 2, :]) / z[..., None]
        ddx = dxx[..., None] * jx + dxy[..., None] * jy
        ddy = dxy[..., None] * jx + dyy[..., None] * jy
        ju = fx[None, :, None] * ddx + skew[None, :, None] * ddy  # (N, V, 3)
        jv = fy[None, :, None] * ddy
        m = np.einsum("nvi,nvj,nv->nij", ju, ju, w) + np.einsum("nvi,nvj,nv->nij", jv, jv, w)
        b = np.einsum("nvi,nv,nv->ni", ju, ru, w) + np.einsum("nvi,nv,nv->ni", jv, rv, w)
        step = _solve_batch(m, b)
        moved = np.asarray(np.isfinite(step).all(axis=1), dtype=np.bool_)
        p = np.where(moved[:, None], p - np.nan_to_num(step), p)
    return p


def _errors(rig: RigArrays, xn: NDArray[np.float64], p: NDArray[np.float64]) -> NDArray[np.float64]:
    """(N, V) distance [≈ px] between each point's projection and each normalised observation,
    scaled by the focal length; inf behind the camera (``rig_kernel._error``)."""
    cam = np.einsum("vij,nj->nvi", rig.rs, p) + rig.ts
    with np.errstate(divide="ignore", invalid="ignore"):
        d = np.hypot(cam[..., 0] / cam[..., 2] - xn[..., 0], cam[..., 1] / cam[..., 2] - xn[..., 1])
    return np.where(cam[..., 2] > 0, d * rig.fs, np.inf)


def _chunk_numpy(
    views: list[View],
    rig: RigArrays,
    obs: NDArray[np.float64],
    outlier_px: float,
    iterations: int,
    points: NDArray[np.float64],
    use: NDArray[np.bool_],
    rms: NDArray[np.float64],
) -> None:
    """``rig_kernel.triangulate_all`` in NumPy, over all points at once: linear solution and
    Gauss–Newton on all views; points with 3+ views and one off by more than ``outlier_px``
    go to RANSAC over view pairs (the pair whose point most views agree with picks the
    inliers, the first such pair on a tie) and are solved again from the inliers; then the
    RMS reprojection error over the views used."""
    n, v = obs.shape[:2]
    xn = _normalised(views, obs)
    seen: NDArray[np.bool_] = np.asarray(np.isfinite(xn).all(axis=-1), dtype=np.bool_)
    count = seen.sum(axis=1)
    use[:] = seen
    p = _linear(rig, xn, seen)
    ok = (count >= 2) & np.isfinite(p).all(axis=1)
    p[~ok] = np.nan
    p[ok] = _gauss_newton(rig, obs[ok], seen[ok], p[ok], iterations)
    with np.errstate(invalid="ignore"):
        worst = np.where(seen, _errors(rig, xn, p), 0.0).max(axis=1)
    redo = np.nonzero(ok & (count >= 3) & ~(worst <= outlier_px))[0]
    if len(redo):
        pairs = [(a, c) for a in range(v) for c in range(a + 1, v)]
        best = np.full(len(redo), -1)
        best_mask = np.zeros((len(redo), v), dtype=np.bool_)
        for a, c in pairs:
            pair = np.zeros((len(redo), v), dtype=np.bool_)
            pair[:, [a, c]] = True
            pair &= seen[redo]
            both = pair.sum(axis=1) == 2
            trial = _linear(rig, xn[redo], pair)
            fine = both & np.isfinite(trial).all(axis=1)
            agree_mask = seen[redo] & (_errors(rig, xn[redo], trial) <= outlier_px)
            agree = np.where(fine, agree_mask.sum(axis=1), -1)
            better = agree > best
            best = np.where(better, agree, best)
            best_mask[better] = agree_mask[better]
        found = best >= 2
        rows = redo[found]
        use[rows] = best_mask[found]
        again = _linear(rig, xn[rows], use[rows])
        solved = np.isfinite(again).all(axis=1)
        again[solved] = _gauss_newton(
            rig, obs[rows[solved]], use[rows[solved]], again[solved], iterations
        )
        p[rows] = again  # NaN where the inliers' equations are singular
        ok[rows[~solved]] = False
    points[:] = p
    points[~ok] = np.nan
    off = project_views(views, p) - obs  # eqs. 2.8–2.14, as the compiled loop projects
    with np.errstate(invalid="ignore", divide="ignore"):
        total = np.where(use, (off * off).sum(axis=-1), 0.0).sum(axis=1)
        rms[:] = np.sqrt(total / use.sum(axis=1))
    rms[~ok] = np.nan


def warm_up() -> None:
    """Compile (or load from numba's cache) the per-point loop now, so that the first request
    on a calibrated rig does not wait for it."""
    k = np.array([[500.0, 0.0, 320.0], [0.0, 500.0, 240.0], [0.0, 0.0, 1.0]])
    views = [View(k, np.zeros(5), np.eye(3), np.array([-x, 0.0, 0.0])) for x in (0.0, 0.2, 0.4)]
    triangulate_views(views, project_views(views, np.array([[0.1, 0.0, 2.0]])))
