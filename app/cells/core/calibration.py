"""Camera calibration from checkerboard views ([Fayed 2013] chapter 2 §IV, chapter 3 §I).

The camera model is the pinhole with skew and the 5-term distortion k = [k1, k2, p1, p2, k3]
(eqs. 2.6–2.13, the Bouguet / OpenCV model), world → camera P = R Pw + T (2.14). Parameters are
estimated by OpenCV (Zhang's method with Levenberg–Marquardt refinement), which also gives the
standard deviation of every parameter, as the Bouguet toolbox reports them (Table 3.1).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray
from scipy.optimize import least_squares

_cv: Any = cv2  # OpenCV's stubs type these calls for UMat only

SUBPIX_CRITERIA = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 30, 0.001)


class CalibrationError(ValueError):
    """Too few usable views, views that do not determine the camera, or no common view."""


def board_points(cols: int, rows: int, square: float) -> NDArray[np.float32]:
    """The inner corners of a cols × rows checkerboard in its own plane (Z = 0) [square units]."""
    grid = np.mgrid[0:cols, 0:rows].T.reshape(-1, 2).astype(np.float32)
    points = np.zeros((cols * rows, 3), np.float32)
    points[:, :2] = grid * square
    return points


MIN_SIDE = 16
"""OpenCV's board detectors fail (an assertion, not a miss) on images smaller than this [px]."""


DETECT_SIDE = 1600
"""Boards are looked for in the image scaled to at most this long side [px], then their corners
are refined in the full image. The detectors' time grows faster than the pixel count: on a
12 MP photo with a board the classic one took 21 s, on one without 236 s."""


SB_FLAGS = cv2.CALIB_CB_NORMALIZE_IMAGE | cv2.CALIB_CB_EXHAUSTIVE
"""The sector-based detector searching hard; the classic detector is the fallback. Without
``CALIB_CB_ACCURACY``: ``cornerSubPix`` refines its corners to the same place (the OpenCV
sample's calibration agrees to 0.0001 px), and it made 20 views of 1 MP take 9.1 s on one core
instead of 2.7 (``bench/calibration.py``)."""

REFINE_SHARE = 0.35
"""``cornerSubPix``'s half-window is this share of the smallest spacing of neighbouring corners
[px], so that a window never reaches a neighbouring corner and pulls the corner onto it."""
REFINE_MIN, REFINE_MAX = 2, 11
"""Bounds of that half-window [px] (11: OpenCV's sample, for squares of 25 px and more)."""


def refine_half_window(corners: NDArray[np.float32], cols: int, rows: int) -> int:
    """``cornerSubPix``'s half-window for these corners (cols·rows, 1, 2), row by row [px]."""
    grid = corners.reshape(rows, cols, 2).astype(np.float64)
    across = np.linalg.norm(np.diff(grid, axis=1), axis=2)
    down = np.linalg.norm(np.diff(grid, axis=0), axis=2)
    spacing = min(across.min(initial=np.inf), down.min(initial=np.inf))
    if not np.isfinite(spacing):
        return REFINE_MIN
    return int(np.clip(round(REFINE_SHARE * spacing), REFINE_MIN, REFINE_MAX))


def _refined(
    grey: NDArray[np.uint8], corners: NDArray[np.float32], cols: int, rows: int
) -> NDArray[np.float32]:
    half = refine_half_window(corners, cols, rows)
    refined = cv2.cornerSubPix(grey, corners, (half, half), (-1, -1), SUBPIX_CRITERIA)
    return np.asarray(refined, dtype=np.float32)


def find_corners(grey: NDArray[np.uint8], cols: int, rows: int) -> NDArray[np.float32] | None:
    """The board's inner corners refined to sub-pixel, shape (cols·rows, 1, 2), or None.

    The sector-based detector (``SB_FLAGS``) first, the classic one when it finds nothing; either
    way refined by ``cornerSubPix`` with a window sized to the board's smallest corner spacing
    (``REFINE_SHARE``). [Fayed 2013] ch. 3 §I finds corners with Bouguet's toolbox; this is
    OpenCV's equivalent at its most accurate. A large image is searched at ``DETECT_SIDE`` and
    the corners found refined at full resolution.
    """
    if min(grey.shape[:2]) < MIN_SIDE:
        return None
    scale = max(grey.shape[:2]) / DETECT_SIDE
    if scale <= 1:
        found = _detect(grey, cols, rows)
        return None if found is None else _refined(grey, found, cols, rows)
    small = np.asarray(
        cv2.resize(grey, None, fx=1 / scale, fy=1 / scale, interpolation=cv2.INTER_AREA),
        dtype=np.uint8,
    )
    if min(small.shape[:2]) < MIN_SIDE:
        return None
    found = _detect(small, cols, rows)
    if found is None:
        return None
    sy, sx = grey.shape[0] / small.shape[0], grey.shape[1] / small.shape[1]
    # pixel centres: x_full + 0.5 = (x_small + 0.5) · scale
    full = ((found + 0.5) * np.array([sx, sy], np.float32) - 0.5).astype(np.float32)
    return _refined(grey, full, cols, rows)


def _detect(grey: NDArray[np.uint8], cols: int, rows: int) -> NDArray[np.float32] | None:
    """The corners as a detector gives them, before refinement, in ``canonical`` order."""
    ok, corners = _cv.findChessboardCornersSB(grey, (cols, rows), flags=SB_FLAGS)
    if not ok:
        flags = cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE
        ok, corners = cv2.findChessboardCorners(grey, (cols, rows), flags=flags)
    return canonical(np.asarray(corners, dtype=np.float32).reshape(-1, 1, 2)) if ok else None


def canonical(corners: NDArray[np.float32]) -> NDArray[np.float32]:
    """The corners numbered from the end nearer the image's top (the left, for a level
    diagonal). A board of cols × rows corners looks the same turned by 180°, so a detector may
    number it from either end, and the two detectors do so differently: the cameras of a pair
    must number the corners of one view alike. The rule turns only where the board's diagonal
    lies level in the image, far from a board held upright or on its side (the ends of a
    diagonal from a 9 × 6 board's first corner to its last stand 32° off level)."""
    dx, dy = corners[-1, 0] - corners[0, 0]
    reverse = dy < 0 if abs(dy) > 1e-3 * abs(dx) else dx < 0
    return corners[::-1].copy() if reverse else corners


SAME_VIEW_PX = 1.0
"""Two views whose corners lie within this RMS distance [px] of each other are one view: the
board and camera did not move between them (a repeated upload, a still camera's frames). Any
new pose moves the corners by many pixels; sensor noise and JPEG move them by hundredths."""


def same_view(a: NDArray[np.float32], b: NDArray[np.float32]) -> bool:
    """Whether two detections of one board are the same view (in either corner order: a
    detector may number the corners of a board turned 180° from the other end)."""
    a2, b2 = a.reshape(-1, 2).astype(np.float64), b.reshape(-1, 2).astype(np.float64)
    if a2.shape != b2.shape:
        return False
    rms = min(float(np.sqrt(np.mean(np.sum((a2 - c) ** 2, axis=1)))) for c in (b2, b2[::-1]))
    return rms < SAME_VIEW_PX


@dataclass(frozen=True, slots=True)
class Intrinsics:
    K: NDArray[np.float64]
    """Camera matrix [[fx, s, cx], [0, fy, cy], [0, 0, 1]] [px]."""
    dist: NDArray[np.float64]
    """[k1, k2, p1, p2, k3]."""
    rms: float
    """Reprojection RMS over all views [px]."""
    per_view_rms: NDArray[np.float64]
    """[px] per used view."""
    std: dict[str, float]
    """Standard deviations: fx, fy, cx, cy, k1, k2, p1, p2, k3."""
    rvecs: list[NDArray[np.float64]]
    tvecs: list[NDArray[np.float64]]
    image_size: tuple[int, int]
    """(width, height) [px]."""
    loo_per_view: NDArray[np.float64] | None = None
    """Each view's reprojection RMS [px] through the intrinsics fitted without it (its own
    pose fitted to it with those): how well the camera model predicts a view it did not
    learn from."""
    loo_rms: float | None = None
    """Over every corner of every view so held out [px]."""
    pixel_sigma: dict[str, float] | None = None
    """How far [px, RMS radius] the intrinsics' uncertainty moves the image of a ray through
    the image's centre and through its corner: ``centre``, ``corner``."""


STD_NAMES = ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3")

OUTLIER_FACTOR = 3.0
"""A view whose reprojection RMS exceeds this many times the views' median is flagged: a
corner mislocated, a blurred or mismatched view, which the operator should look at."""


def flagged_views(per_view_rms: NDArray[np.float64]) -> list[int]:
    """Indices of views whose RMS [px] is over ``OUTLIER_FACTOR`` × the median of all views."""
    median = float(np.median(per_view_rms)) if per_view_rms.size else 0.0
    return [i for i, v in enumerate(per_view_rms) if v > OUTLIER_FACTOR * median]


MIN_TILT_SPREAD_DEG = 5.0
"""The boards' planes must differ by at least this much [°] between some two views. Parallel
planes do not determine the focal length (Zhang 2000, §3.3: the constraints of a plane
parallel to another's are dependent), and the fit's uncertainties then mean nothing. Measured
on rendered boards through a known camera (f = 800 px, five views): all facing the camera,
f came out 39,000–300,000 px with a standard deviation of 0.01 %; planes within 1–2.5° of
each other, up to 20 % off with 0.01–0.1 %; 4–5° apart, within 2.3 standard deviations of the
truth; from 6°, within 1.4. Every 3 of the 13 views of OpenCV's sample differ by 7° or more."""

MAX_REL_STD_F = 0.05
"""The focal lengths must be known to ±5 % (one standard deviation) or better."""


def _normal_spread_deg(rvecs: list[NDArray[np.float64]]) -> float:
    """The largest angle between two views' board normals [°]."""
    normals = np.array([cv2.Rodrigues(r)[0][:, 2] for r in rvecs])
    cos = np.clip(normals @ normals.T, -1.0, 1.0)
    return float(np.degrees(np.arccos(cos.min())))


def fit_intrinsics(
    object_points: list[NDArray[np.float32]],
    image_points: list[NDArray[np.float32]],
    image_size: tuple[int, int],
) -> Intrinsics:
    """Intrinsics, distortion and per-view extrinsics with their uncertainties."""
    if len(image_points) < 3:
        raise CalibrationError(
            f"need at least 3 views where the board was found; got {len(image_points)}"
        )
    rms, k, dist, rvecs, tvecs, std_in, _, per_view = _cv.calibrateCameraExtended(
        object_points, image_points, image_size, None, None
    )
    std = {name: float(v) for name, v in zip(STD_NAMES, np.ravel(std_in)[:9], strict=True)}
    rvecs = [np.asarray(r, dtype=np.float64).ravel() for r in rvecs]
    tilt = _normal_spread_deg(rvecs)
    advice = "tilt the board by 20–40° about both of its axes, differently in each view"
    if tilt < MIN_TILT_SPREAD_DEG:
        raise CalibrationError(
            f"the board faces the same way in every view (its planes differ by {tilt:.1f}°):"
            f" they do not determine the focal length; {advice}"
        )
    fx, fy = float(k[0][0]), float(k[1][1])
    if not all(map(np.isfinite, [*std.values(), fx, fy, rms])):
        raise CalibrationError(f"the views do not determine the camera; {advice}")
    worst = max(std["fx"] / fx, std["fy"] / fy)
    if worst > MAX_REL_STD_F:
        raise CalibrationError(
            f"fx = {fx:.0f} ± {std['fx']:.0f} px, fy = {fy:.0f} ± {std['fy']:.0f} px: the views"
            f" determine the focal length only to ±{100 * worst:.0f} %, worse than"
            f" ±{100 * MAX_REL_STD_F:.0f} %; add views, and {advice}"
        )
    k = np.asarray(k, dtype=np.float64)
    dist = np.asarray(dist, dtype=np.float64).ravel()[:5]
    tvecs = [np.asarray(t, dtype=np.float64).ravel() for t in tvecs]
    loo = leave_one_out(object_points, image_points, image_size, k, dist)
    return Intrinsics(
        K=k,
        dist=dist,
        rms=float(rms),
        per_view_rms=np.asarray(per_view, dtype=np.float64).ravel(),
        std=std,
        rvecs=rvecs,
        tvecs=tvecs,
        image_size=image_size,
        loo_per_view=loo,
        loo_rms=float(np.sqrt(np.mean(loo**2))),
        pixel_sigma=pixel_sigma(object_points, image_points, k, dist, rvecs, tvecs, image_size),
    )


def _view_rms(
    obj: NDArray[np.float32],
    pts: NDArray[np.float32],
    k: NDArray[np.float64],
    dist: NDArray[np.float64],
) -> float:
    """The view's reprojection RMS [px] with its pose fitted to it through ``k``, ``dist``."""
    ok, rvec, tvec = cv2.solvePnP(obj, pts, k, dist)
    if not ok:
        return float("inf")
    rvec, tvec = cv2.solvePnPRefineLM(obj, pts, k, dist, rvec, tvec)
    proj = _cv.projectPoints(obj, rvec, tvec, k, dist)[0].reshape(-1, 2)
    return float(np.sqrt(np.mean(np.sum((proj - pts.reshape(-1, 2)) ** 2, axis=1))))


HELD_OUT_FITS = 20
"""Refits a held-out error takes at most: up to this many views each is held out alone; more
are held out in this many interleaved folds (view i in fold i mod 20), so that 500 views cost
20 refits, not 500 (each of them a calibration of all the others)."""


def folds(n: int) -> list[list[int]]:
    """The views held out together: each alone up to ``HELD_OUT_FITS``, else interleaved."""
    k = min(n, HELD_OUT_FITS)
    return [list(range(f, n, k)) for f in range(k)]


def leave_one_out(
    object_points: list[NDArray[np.float32]],
    image_points: list[NDArray[np.float32]],
    image_size: tuple[int, int],
    k: NDArray[np.float64],
    dist: NDArray[np.float64],
) -> NDArray[np.float64]:
    """Each view's reprojection RMS [px] through the intrinsics fitted to the other views
    (started from the full fit's, ``CALIB_USE_INTRINSIC_GUESS``; in ``folds``), its own pose
    fitted to it: the fit's RMS judges the model on the views it fitted, this on one it did
    not (its 6 pose parameters still fitted to its own corners, so it is a little
    optimistic)."""
    out = np.empty(len(image_points))
    for fold in folds(len(image_points)):
        kept = [i for i in range(len(image_points)) if i not in set(fold)]
        _, k_f, d_f, *_ = _cv.calibrateCamera(
            [object_points[i] for i in kept],
            [image_points[i] for i in kept],
            image_size,
            k.copy(),
            dist.copy(),
            flags=cv2.CALIB_USE_INTRINSIC_GUESS,
        )
        for i in fold:
            out[i] = _view_rms(object_points[i], image_points[i], k_f, d_f.ravel())
    return out


def pixel_sigma(
    object_points: list[NDArray[np.float32]],
    image_points: list[NDArray[np.float32]],
    k: NDArray[np.float64],
    dist: NDArray[np.float64],
    rvecs: list[NDArray[np.float64]],
    tvecs: list[NDArray[np.float64]],
    image_size: tuple[int, int],
) -> dict[str, float]:
    """How far [px, RMS radius] the intrinsics' uncertainty moves the image of the rays
    through the image's centre and its corner: the full covariance of the fit, ``σ² (JᵀJ)⁻¹``
    over the intrinsics (fx, fy, cx, cy, k1, k2, p1, p2, k3) and every view's pose, ``σ²`` the
    residuals' variance, its intrinsics block carried through each ray's projection Jacobian.
    OpenCV reports only that block's diagonal (``std``); the correlations (fx with k1, cx with
    p1) shrink or grow what a pixel feels."""
    views = len(image_points)
    n_int = 9
    rows, resid = [], []
    for v in range(views):
        proj, jac = _cv.projectPoints(object_points[v], rvecs[v], tvecs[v], k, dist)
        pts = image_points[v].reshape(-1, 2)
        resid.append((proj.reshape(-1, 2) - pts).ravel())
        # OpenCV's Jacobian columns: rvec (3), tvec (3), f (2), c (2), distortion (5)
        block = np.zeros((jac.shape[0], n_int + 6 * views))
        block[:, :n_int] = jac[:, 6 : 6 + n_int]
        block[:, n_int + 6 * v : n_int + 6 * v + 6] = jac[:, :6]
        rows.append(block)
    j = np.vstack(rows)
    r = np.concatenate(resid)
    dof = max(r.size - j.shape[1], 1)
    cov = float(r @ r) / dof * np.linalg.pinv(j.T @ j)[:n_int, :n_int]
    w, h = image_size
    out = {}
    for name, pixel in (("centre", (k[0, 2], k[1, 2])), ("corner", (0.0, 0.0))):
        norm = cv2.undistortPoints(np.array([[pixel]], np.float64), k, dist).reshape(2)
        ray = np.array([[norm[0], norm[1], 1.0]])
        _, jac = _cv.projectPoints(ray, np.zeros(3), np.zeros(3), k, dist)
        ji = jac[:, 6 : 6 + n_int]
        out[name] = float(np.sqrt(np.trace(ji @ cov @ ji.T)))
    del w, h
    return out


@dataclass(frozen=True, slots=True)
class StereoPose:
    R: NDArray[np.float64]
    """Rotation from the first camera's frame to the second's."""
    T: NDArray[np.float64]
    """Translation, x₂ = R x₁ + T [square units]."""
    rms: float
    baseline: float
    """|T| [square units]."""
    rotation_deg: float
    loo_per_pair: NDArray[np.float64] | None = None
    """Each pair's reprojection RMS [px] over both views through the R, T fitted without it,
    the board's pose fitted to both views with R, T held."""
    loo_rms: float | None = None


def stereo(
    object_points: list[NDArray[np.float32]],
    left_points: list[NDArray[np.float32]],
    right_points: list[NDArray[np.float32]],
    left: Intrinsics,
    right: Intrinsics,
) -> StereoPose:
    """The pair's relative pose from simultaneous views, intrinsics held fixed."""
    if len(left_points) < 1:
        raise CalibrationError("no view where both cameras found the board")
    rms, r, t = _stereo_fit(object_points, left_points, right_points, left, right)
    angle = float(np.degrees(np.linalg.norm(cv2.Rodrigues(r)[0])))
    loo = None
    if len(left_points) >= 3:
        loo = np.empty(len(left_points))
        for fold in folds(len(left_points)):
            loo[fold] = _held_out_pairs(object_points, left_points, right_points, left, right, fold)
    return StereoPose(
        R=r,
        T=t,
        rms=float(rms),
        baseline=float(np.linalg.norm(t)),
        rotation_deg=angle,
        loo_per_pair=loo,
        loo_rms=None if loo is None else float(np.sqrt(np.mean(loo**2))),
    )


def _stereo_fit(
    object_points: list[NDArray[np.float32]],
    left_points: list[NDArray[np.float32]],
    right_points: list[NDArray[np.float32]],
    left: Intrinsics,
    right: Intrinsics,
) -> tuple[float, NDArray[np.float64], NDArray[np.float64]]:
    """``stereoCalibrate`` with the intrinsics held: RMS [px], R and T (x₂ = R x₁ + T)."""
    rms, *_, r, t, _, _ = _cv.stereoCalibrate(
        object_points,
        left_points,
        right_points,
        left.K,
        left.dist,
        right.K,
        right.dist,
        left.image_size,
        flags=cv2.CALIB_FIX_INTRINSIC,
    )
    return float(rms), np.asarray(r, dtype=np.float64), np.asarray(t, dtype=np.float64).ravel()


def _held_out_pairs(
    object_points: list[NDArray[np.float32]],
    left_points: list[NDArray[np.float32]],
    right_points: list[NDArray[np.float32]],
    left: Intrinsics,
    right: Intrinsics,
    fold: list[int],
) -> list[float]:
    """The reprojection RMS [px] over both views of each pair in ``fold``, through the R, T
    fitted without them, each board's pose fitted to both its views at once (as
    ``stereoCalibrate`` fits the poses of the views it is given, whose RMS this sits beside)."""
    kept = [i for i in range(len(left_points)) if i not in set(fold)]
    _, r, t = _stereo_fit(
        [object_points[i] for i in kept],
        [left_points[i] for i in kept],
        [right_points[i] for i in kept],
        left,
        right,
    )
    return [
        _pair_rms(object_points[i], left_points[i], right_points[i], left, right, r, t)
        for i in fold
    ]


def _pair_rms(
    object_points: NDArray[np.float32],
    left_points: NDArray[np.float32],
    right_points: NDArray[np.float32],
    left: Intrinsics,
    right: Intrinsics,
    r: NDArray[np.float64],
    t: NDArray[np.float64],
) -> float:
    """One pair's RMS [px] over both views with R, T held, its board's pose fitted to both."""
    obj = np.asarray(object_points, dtype=np.float64)
    seen_l = np.asarray(left_points, dtype=np.float64).reshape(-1, 2)
    seen_r = np.asarray(right_points, dtype=np.float64).reshape(-1, 2)
    ok, rvec, tvec = cv2.solvePnP(object_points, left_points, left.K, left.dist)
    if not ok:
        return float("inf")

    def residuals(pose: NDArray[np.float64]) -> NDArray[np.float64]:
        rl = np.asarray(cv2.Rodrigues(pose[:3])[0], dtype=np.float64)
        pl = _cv.projectPoints(obj, pose[:3], pose[3:], left.K, left.dist)[0].reshape(-1, 2)
        rr = cv2.Rodrigues(r @ rl)[0]
        pr = _cv.projectPoints(obj, rr, r @ pose[3:] + t, right.K, right.dist)[0]
        return np.concatenate([(pl - seen_l).ravel(), (pr.reshape(-1, 2) - seen_r).ravel()])

    fit = least_squares(residuals, np.concatenate([rvec.ravel(), tvec.ravel()]), method="lm")
    return float(np.sqrt(np.mean(fit.fun**2) * 2))
