"""Locating points in 3-D from several calibrated views: the 4-camera cross (chapter 4) and any
rig of 2+ calibrated cameras.

The cross, in the contract's frame (the dissertation's Figure 4.3 with a pinhole at each lens)::

            Y ↑            camera 3 (0, +ay/2)
              |                  ●
    camera 2  ●--------+--------●  camera 1        X →   (Z forward, out of the page)
   (−ax/2, 0)          |         (+ax/2, 0)
                       ●
                 camera 4 (0, −ay/2)

All four look along +Z with focal length f [px]; a point (X, Y, Z) is seen by camera i at
u = cx + f (X − Xᵢ)/Z, v = cy − f (Y − Yᵢ)/Z. The dissertation writes the image plane as
x = fX/(f − Z) (eq. 4.4) and gets Z = f(1 − A/(x₂ − x₁)) (4.14); with the pinhole above the same
derivation gives Z = B/d: for cameras i, j and normalised coordinates xᵢ = (uᵢ − cx)/f,
yᵢ = −(vᵢ − cy)/f, xᵢ − xⱼ = (Xⱼ − Xᵢ)/Z and yᵢ − yⱼ = (Yⱼ − Yᵢ)/Z. The pairs (1,2) and (3,4)
give one estimate each (4.14, 4.24), the four diagonal pairs two each (4.28–4.41): ten.
"""

from __future__ import annotations

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


def z_estimates(rig: CrossRig, obs: NDArray[np.float64]) -> NDArray[np.float64]:
    """The ten pairwise depth estimates Z = B/d of each point (module docstring)."""
    n = rig.normalised(obs)
    b = rig.baselines()
    out = np.full((obs.shape[0], len(PAIRS)), np.nan)
    for k, (i, j, axis) in enumerate(PAIRS):
        a = 0 if axis == "x" else 1
        d = n[:, i, a] - n[:, j, a]
        with np.errstate(divide="ignore", invalid="ignore"):
            z = b[k] / d  # Z = B/d: a zero disparity (or a missing view) gives no estimate
        out[:, k] = np.where(np.isfinite(z) & (z > 0), z, np.nan)
    return out


def _xy(rig: CrossRig, obs: NDArray[np.float64], z: NDArray[np.float64]) -> NDArray[np.float64]:
    """X and Y from Z, averaged over the views present (the analogue of 4.15–4.16)."""
    n = rig.normalised(obs)
    c = rig.centres
    x = np.nanmean(n[..., 0] * z[:, None] + c[None, :, 0], axis=1)
    y = np.nanmean(n[..., 1] * z[:, None] + c[None, :, 1], axis=1)
    return np.column_stack([x, y, z])


def _rms(
    rig: CrossRig, obs: NDArray[np.float64], points: NDArray[np.float64]
) -> NDArray[np.float64]:
    err = rig.project(points) - obs
    return np.asarray(np.sqrt(np.nanmean((err**2).sum(axis=-1), axis=1)), dtype=np.float64)


def triangulate_cross(
    rig: CrossRig, obs: NDArray[np.float64], *, method: str = "least_squares"
) -> CrossResult:
    """Points from cross observations (N, 4, 2) [px]; NaN for a missing view.

    method
        ``mean``: the plain mean of the ten estimates (eq. 4.47, the dissertation's least squares
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
    est = z_estimates(rig, obs)
    if method == "mean":
        z = np.nanmean(est, axis=1)  # eq. 4.47
        points = _xy(rig, obs, z)
    elif method == "weighted":
        w = np.where(np.isnan(est), 0.0, rig.baselines() ** 2)
        z = np.nansum(est * w, axis=1) / w.sum(axis=1)
        points = _xy(rig, obs, z)
    elif method == "least_squares":
        points = _least_squares(rig, obs)
    else:
        raise ValueError(f"unknown method {method!r}")
    spread = np.nanstd(est, axis=1)
    return CrossResult(points, est, spread, _rms(rig, obs, points))


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
    p = np.linalg.solve(ata, atb[..., None])[..., 0]
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
        p = p - np.linalg.solve(jtj, jtr[..., None])[..., 0]
    return p


@dataclass(frozen=True, slots=True)
class View:
    """A calibrated camera: x_cam = R X + t (OpenCV convention), intrinsics K, distortion."""

    K: NDArray[np.float64]
    dist: NDArray[np.float64]
    R: NDArray[np.float64]
    t: NDArray[np.float64]


@dataclass(frozen=True, slots=True)
class RigResult:
    points: NDArray[np.float64]
    """(N, 3) in the world frame; NaN where fewer than 2 views remain."""
    reprojection_rms: NDArray[np.float64]
    """(N,) [px] over the views used."""
    used: NDArray[np.bool_]
    """(N, V): the views each point was triangulated from (outliers rejected)."""


def project_views(views: list[View], points: NDArray[np.float64]) -> NDArray[np.float64]:
    """(N, 3) world points → (N, V, 2) pixels, distortion included."""
    import cv2

    out = np.empty((len(points), len(views), 2))
    for k, v in enumerate(views):
        rvec = cv2.Rodrigues(v.R)[0]
        pix, _ = cv2.projectPoints(points.reshape(-1, 1, 3), rvec, v.t, v.K, v.dist)
        out[:, k] = pix.reshape(-1, 2)
    return out


def _normalised(views: list[View], obs: NDArray[np.float64]) -> NDArray[np.float64]:
    """Pixels (N, V, 2) → undistorted normalised coordinates; NaN stays NaN."""
    import cv2

    out = np.full(obs.shape, np.nan)
    for k, v in enumerate(views):
        ok = np.isfinite(obs[:, k]).all(axis=1)
        if ok.any():
            pts = obs[ok, k].reshape(-1, 1, 2).astype(np.float64)
            out[ok, k] = cv2.undistortPoints(pts, v.K, v.dist).reshape(-1, 2)
    return out


def _linear(
    rs: NDArray[np.float64],
    ts: NDArray[np.float64],
    xn: NDArray[np.float64],
    use: NDArray[np.bool_],
) -> NDArray[np.float64]:
    """Linear triangulation from normalised coordinates: per view (x r₃ − r₁)·X = t₁ − x t₃ and
    (y r₃ − r₂)·X = t₂ − y t₃, all points at once by their 3 × 3 normal equations."""
    x = np.where(use, xn[..., 0], 0.0)
    y = np.where(use, xn[..., 1], 0.0)
    w = use.astype(np.float64)
    ax_ = (x[..., None] * rs[None, :, 2] - rs[None, :, 0]) * w[..., None]  # (N, V, 3)
    ay_ = (y[..., None] * rs[None, :, 2] - rs[None, :, 1]) * w[..., None]
    bx = (ts[None, :, 0] - x * ts[None, :, 2]) * w
    by = (ts[None, :, 1] - y * ts[None, :, 2]) * w
    ata = np.einsum("nvi,nvj->nij", ax_, ax_) + np.einsum("nvi,nvj->nij", ay_, ay_)
    atb = np.einsum("nvi,nv->ni", ax_, bx) + np.einsum("nvi,nv->ni", ay_, by)
    ata += np.eye(3) * 1e-12
    return np.asarray(np.linalg.solve(ata, atb[..., None])[..., 0], dtype=np.float64)


def _refine(
    rs: NDArray[np.float64],
    ts: NDArray[np.float64],
    fs: NDArray[np.float64],
    xn: NDArray[np.float64],
    use: NDArray[np.bool_],
    p: NDArray[np.float64],
    iterations: int = 3,
) -> NDArray[np.float64]:
    """Gauss–Newton on the normalised reprojection error, each view weighted by its focal
    length (so the error is in pixels, distortion aside)."""
    w = use.astype(np.float64) * fs[None, :]
    for _ in range(iterations):
        cam = np.einsum("vij,nj->nvi", rs, p) + ts[None]  # (N, V, 3)
        z = cam[..., 2]
        z = np.where(np.abs(z) < 1e-12, 1e-12, z)
        rx = (cam[..., 0] / z - np.where(use, xn[..., 0], 0)) * w
        ry = (cam[..., 1] / z - np.where(use, xn[..., 1], 0)) * w
        # d(cam_x/z)/dX = (r₁ − (cam_x/z) r₃)/z
        jx = (rs[None, :, 0] - (cam[..., 0] / z)[..., None] * rs[None, :, 2]) / z[..., None]
        jy = (rs[None, :, 1] - (cam[..., 1] / z)[..., None] * rs[None, :, 2]) / z[..., None]
        jx *= w[..., None]
        jy *= w[..., None]
        jtj = np.einsum("nvi,nvj->nij", jx, jx) + np.einsum("nvi,nvj->nij", jy, jy)
        jtr = np.einsum("nvi,nv->ni", jx, rx) + np.einsum("nvi,nv->ni", jy, ry)
        jtj += np.eye(3) * 1e-12
        p = p - np.linalg.solve(jtj, jtr[..., None])[..., 0]
    return p


def triangulate_views(
    views: list[View], obs: NDArray[np.float64], *, outlier_px: float = 3.0, refine: bool = True
) -> RigResult:
    """Points from pixel observations (N, V, 2) of V ≥ 2 calibrated cameras; NaN for a missing
    view. Undistort, triangulate linearly, refine by Gauss–Newton; for points seen by ≥ 3 views,
    the view pair whose point agrees with most other views (within ``outlier_px``) picks the
    inliers (RANSAC over all pairs), and the point is re-solved from them."""
    obs = np.asarray(obs, dtype=np.float64)
    n, v = obs.shape[0], len(views)
    if obs.ndim != 3 or obs.shape[1:] != (v, 2):
        raise ValueError(f"observations must have shape (N, {v}, 2); got {obs.shape}")
    rs = np.stack([np.asarray(x.R, dtype=np.float64) for x in views])
    ts = np.stack([np.asarray(x.t, dtype=np.float64).ravel() for x in views])
    fs = np.array([float(np.sqrt(x.K[0, 0] * x.K[1, 1])) for x in views])
    xn = _normalised(views, obs)
    seen: NDArray[np.bool_] = np.asarray(np.isfinite(xn).all(axis=-1), dtype=bool)
    use: NDArray[np.bool_] = seen.copy()
    multi = seen.sum(axis=1) >= 3
    if multi.any():
        best = np.full(n, -1)
        best_use = seen.copy()
        for i in range(v):
            for j in range(i + 1, v):
                pair = np.zeros_like(seen)
                pair[:, i] = pair[:, j] = True
                pair &= seen
                ok = pair.sum(axis=1) == 2
                p = _linear(rs, ts, xn, pair)
                cam = np.einsum("vij,nj->nvi", rs, p) + ts[None]
                err = (
                    np.hypot(
                        cam[..., 0] / cam[..., 2] - xn[..., 0],
                        cam[..., 1] / cam[..., 2] - xn[..., 1],
                    )
                    * fs[None]
                )
                inl = seen & (err <= outlier_px) & (cam[..., 2] > 0)
                count = np.where(ok, inl.sum(axis=1), -1)
                better = multi & (count > best)
                best = np.where(better, count, best)
                best_use[better] = inl[better]
        use = np.asarray(np.where(multi[:, None], best_use & seen, seen), dtype=bool)
        use[multi & (use.sum(axis=1) < 2)] = seen[multi & (use.sum(axis=1) < 2)]
    enough = use.sum(axis=1) >= 2
    p = np.full((n, 3), np.nan)
    if enough.any():
        q = _linear(rs, ts, xn[enough], use[enough])
        if refine:
            q = _refine(rs, ts, fs, xn[enough], use[enough], q)
        p[enough] = q
    proj = project_views(views, np.nan_to_num(p))
    err2 = np.where(use, ((proj - obs) ** 2).sum(axis=-1), np.nan)
    with np.errstate(invalid="ignore"):
        rms = np.sqrt(np.nanmean(err2, axis=1))
    rms[~enough] = np.nan
    return RigResult(p, rms, use)
