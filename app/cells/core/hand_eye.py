"""Hand-eye calibration: where a camera is on (or beside) a robot, from views of a board.

For each view ``i`` the robot reports its flange's pose in its base, ``F_i`` (4×4, base ←
flange), and the camera sees the board at ``C_i`` (camera ← board, from the corners with the
camera's intrinsics). With the camera on the flange (eye in hand) the unknown is ``X`` =
flange ← camera and the board stays in the base: ``F_i X C_i`` is the same for every view.
With the camera fixed and the board on the flange (eye to hand) the unknown is ``X`` = base ←
camera and ``F_i⁻¹ X C_i`` (flange ← board) stays the same. Either way, for two views ``i, j``

.. math:: A X = X B,\\qquad A = G_j^{-1} G_i,\\quad B = C_j C_i^{-1}

with ``G = F`` (eye in hand) or ``G = F⁻¹`` (eye to hand). The closed form is Park and
Martin's ("Robot sensor calibration: solving AX = XB on the Euclidean group", IEEE Trans.
Robotics and Automation 10(5), 1994): with ``α``, ``β`` the rotation vectors of ``A``, ``B``,
``M = Σ β αᵀ`` and ``R_X = (MᵀM)^{-½} Mᵀ``; then ``t_X`` by least squares from
``(R_A − I) t_X = R_X t_B − t_A``. It starts a nonlinear least squares over every corner of
every view (the board's fixed pose a second unknown), which weighs the views by what the
camera saw rather than by rotations. Not in the dissertation; OpenCV 5's Python wheel no longer
ships ``calibrateHandEye``.

Lengths are in the unit of the robot's translations (metres); the board's square is given in
it too.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray
from scipy.optimize import least_squares

_cv: Any = cv2

MIN_AXIS_SPREAD_DEG = 5.0
"""The robot's rotations between views must turn about axes at least this far apart [°]:
rotations about one axis leave the camera's position along it unobservable (Tsai and Lenz
1989, Park and Martin 1994: at least two motions with non-parallel axes)."""

MIN_TURN_DEG = 2.0
"""A motion that turns less than this [°] says nothing of the axis."""

ORTHONORMAL_TOL = 1e-3
"""How far ``RᵀR`` may be from the identity, and ``det R`` from 1."""

MAX_TRANSLATION = 10.0
"""A flange further than this from the base [m] is a pose in millimetres by mistake."""


class HandEyeError(ValueError):
    """The poses or views cannot determine the camera: what is wrong, in words."""


def rigid(rotation: NDArray[np.float64], translation: NDArray[np.float64]) -> NDArray[np.float64]:
    """The 4×4 homogeneous transform of a rotation (3×3) and a translation (3,)."""
    out = np.eye(4)
    out[:3, :3] = rotation
    out[:3, 3] = translation
    return out


def inverse(t: NDArray[np.float64]) -> NDArray[np.float64]:
    """The inverse of a rigid 4×4 transform."""
    r = t[:3, :3]
    return rigid(r.T, -r.T @ t[:3, 3])


def check_pose(rotation: NDArray[np.float64], translation: NDArray[np.float64]) -> str | None:
    """Why a flange pose cannot be one (not orthonormal, a reflection, translations in
    millimetres), or None."""
    r = np.asarray(rotation, dtype=np.float64)
    t = np.asarray(translation, dtype=np.float64)
    if r.shape != (3, 3) or t.shape != (3,) or not (np.isfinite(r).all() and np.isfinite(t).all()):
        return "rotation must be 3×3 and translation 3 finite numbers"
    off = float(np.abs(r.T @ r - np.eye(3)).max())
    if off > ORTHONORMAL_TOL:
        return f"the rotation is not orthonormal (RᵀR is {off:.3g} from the identity)"
    if np.linalg.det(r) < 0:
        return "the rotation is a reflection (its determinant is −1)"
    distance = float(np.linalg.norm(t))
    if distance > MAX_TRANSLATION:
        return (
            f"the flange is {distance:.1f} m from the base: translations are in metres "
            "(millimetres by mistake?)"
        )
    return None


def _log(r: NDArray[np.float64]) -> NDArray[np.float64]:
    return np.asarray(cv2.Rodrigues(r)[0], dtype=np.float64).ravel()


def _motions(
    g: list[NDArray[np.float64]], c: list[NDArray[np.float64]]
) -> list[tuple[NDArray[np.float64], NDArray[np.float64]]]:
    """``(A, B)`` for every pair of views (all pairs: none is favoured)."""
    out = []
    for i in range(len(g)):
        for j in range(i + 1, len(g)):
            out.append((inverse(g[j]) @ g[i], c[j] @ inverse(c[i])))
    return out


def axis_spread_deg(motions: list[tuple[NDArray[np.float64], NDArray[np.float64]]]) -> float:
    """The largest angle [°] between the axes (as lines) of the robot's motions that turn by
    at least ``MIN_TURN_DEG``; 0 when fewer than two do."""
    axes = []
    for a, _ in motions:
        v = _log(a[:3, :3])
        if np.degrees(np.linalg.norm(v)) >= MIN_TURN_DEG:
            axes.append(v / np.linalg.norm(v))
    if len(axes) < 2:
        return 0.0
    u = np.array(axes)
    cos = np.clip(np.abs(u @ u.T), 0.0, 1.0)
    return float(np.degrees(np.arccos(cos.min())))


def _angle(r: NDArray[np.float64]) -> float:
    """A rotation's angle [rad]."""
    return math.acos(max(-1.0, min(1.0, (float(np.trace(r)) - 1.0) / 2.0)))


def consistent(
    flange: list[NDArray[np.float64]],
    candidates: list[list[NDArray[np.float64]]],
    *,
    eye_in_hand: bool,
) -> list[int]:
    """Which of each view's candidate board poses (camera ← board, 4×4) numbers the board as
    the first view does. A checkerboard turned by 180° looks the same, and a detector numbers
    its corners from either end: the camera's pose of it is then turned by 180° about its
    normal, and calibration does not care, but hand-eye does. ``A X = X B`` keeps angles: the
    robot's rotation between the first view and view ``i`` turns by as much as the board does
    in the camera, so each view takes the candidate whose turn from the first view's matches
    the robot's best."""
    if not candidates:
        return []
    g = [f if eye_in_hand else inverse(f) for f in flange]
    chosen = [0]
    for i in range(1, len(candidates)):
        turn = _angle((inverse(g[i]) @ g[0])[:3, :3])
        miss = [abs(_angle((c @ inverse(candidates[0][0]))[:3, :3]) - turn) for c in candidates[i]]
        chosen.append(int(np.argmin(miss)))
    return chosen


def park_martin(
    motions: list[tuple[NDArray[np.float64], NDArray[np.float64]]],
) -> NDArray[np.float64]:
    """``X`` from ``A X = X B`` in closed form (Park and Martin 1994, module docstring)."""
    m = np.zeros((3, 3))
    for a, b in motions:
        m += np.outer(_log(b[:3, :3]), _log(a[:3, :3]))
    # (MᵀM)^{-1/2} Mᵀ by the SVD M = U S Vᵀ: V S⁻¹ Vᵀ V S Uᵀ = V Uᵀ (the nearest rotation)
    u, _, vt = np.linalg.svd(m)
    r = vt.T @ u.T
    if np.linalg.det(r) < 0:
        r = vt.T @ np.diag([1.0, 1.0, -1.0]) @ u.T
    lhs = np.vstack([a[:3, :3] - np.eye(3) for a, _ in motions])
    rhs = np.concatenate([r @ b[:3, 3] - a[:3, 3] for a, b in motions])
    t = np.linalg.lstsq(lhs, rhs, rcond=None)[0]
    return rigid(r, t)


@dataclass(frozen=True, slots=True)
class HandEye:
    X: NDArray[np.float64]
    """eye_in_hand: flange ← camera; eye_to_hand: base ← camera (4×4)."""
    Y: NDArray[np.float64]
    """The board's fixed pose: eye_in_hand, base ← board; eye_to_hand, flange ← board."""
    rms_px: float
    per_view_px: NDArray[np.float64]
    per_view_mm: NDArray[np.float64]
    """How far each view's board lies from where the chain puts it [mm]."""
    per_view_deg: NDArray[np.float64]
    rms_mm: float
    rms_deg: float
    axis_spread_deg: float
    closed_form: NDArray[np.float64]
    """Park and Martin's ``X``, before the refinement."""


def _vec(t: NDArray[np.float64]) -> NDArray[np.float64]:
    return np.concatenate([_log(t[:3, :3]), t[:3, 3]])


def _mat(v: NDArray[np.float64]) -> NDArray[np.float64]:
    return rigid(np.asarray(cv2.Rodrigues(v[:3])[0], dtype=np.float64), v[3:])


def _chain(
    g: NDArray[np.float64], x: NDArray[np.float64], y: NDArray[np.float64]
) -> NDArray[np.float64]:
    """camera ← board as the chain puts it: ``X⁻¹ G⁻¹ Y``."""
    return inverse(x) @ inverse(g) @ y


def solve(
    flange: list[NDArray[np.float64]],
    board_in_camera: list[NDArray[np.float64]],
    object_points: list[NDArray[np.float32]],
    image_points: list[NDArray[np.float32]],
    k: NDArray[np.float64],
    dist: NDArray[np.float64],
    *,
    eye_in_hand: bool,
) -> HandEye:
    """``X`` and the board's pose from ≥ 3 views: each view's flange pose ``F_i`` (base ←
    flange, 4×4), the board's pose in the camera ``C_i`` (4×4), the corners it saw on the
    board (Nᵢ, 3) and in the image (Nᵢ, 2) [px] (a ChArUco board's views see different
    corners), with the camera's ``k`` and ``dist``.

    Raises ``HandEyeError`` when the motions turn about one axis only."""
    n = len(flange)
    if n < 3 or len(board_in_camera) != n or len(image_points) != n:
        raise HandEyeError(f"need at least 3 views with a pose and the board found; got {n}")
    # G: base ← flange (eye in hand) or flange ← base (eye to hand), so that G⁻¹-chains agree
    g = [f if eye_in_hand else inverse(f) for f in flange]
    motions = _motions(g, board_in_camera)
    spread = axis_spread_deg(motions)
    if spread < MIN_AXIS_SPREAD_DEG:
        raise HandEyeError(
            f"the robot's rotations between views turn about one axis (their axes lie within "
            f"{spread:.1f}° of each other): the camera's position along it is not observable; "
            "turn the flange about two or more axes, by 15–45°"
        )
    x0 = park_martin(motions)
    # the board's pose in the base (eye in hand) or on the flange (eye to hand), from each view
    # by the chain; the rotations' mean projected back onto SO(3)
    ys = [gi @ x0 @ ci for gi, ci in zip(g, board_in_camera, strict=True)]
    u, _, vt = np.linalg.svd(sum(y[:3, :3] for y in ys))
    y0 = rigid(u @ vt, np.mean([y[:3, 3] for y in ys], axis=0))

    objs = [np.asarray(o, dtype=np.float64).reshape(-1, 3) for o in object_points]
    seen = [np.asarray(p, dtype=np.float64).reshape(-1, 2) for p in image_points]

    def residuals(v: NDArray[np.float64]) -> NDArray[np.float64]:
        x, y = _mat(v[:6]), _mat(v[6:])
        out = []
        for gi, obj, pts in zip(g, objs, seen, strict=True):
            cb = _chain(gi, x, y)
            proj = _cv.projectPoints(obj, _log(cb[:3, :3]), cb[:3, 3], k, dist)[0]
            out.append((proj.reshape(-1, 2) - pts).ravel())
        return np.concatenate(out)

    fit = least_squares(residuals, np.concatenate([_vec(x0), _vec(y0)]), method="lm")
    x, y = _mat(fit.x[:6]), _mat(fit.x[6:])
    ends = np.cumsum([2 * len(o) for o in objs])[:-1]
    per_px = np.array([np.sqrt(np.mean(e**2) * 2) for e in np.split(fit.fun, ends)])
    mm, deg = [], []
    for gi, ci in zip(g, board_in_camera, strict=True):
        d = inverse(ci) @ _chain(gi, x, y)
        mm.append(1000.0 * float(np.linalg.norm(d[:3, 3])))
        deg.append(math.degrees(float(np.linalg.norm(_log(d[:3, :3])))))
    mm_a, deg_a = np.array(mm), np.array(deg)
    return HandEye(
        X=x,
        Y=y,
        rms_px=float(np.sqrt(np.mean(fit.fun**2) * 2)),
        per_view_px=per_px,
        per_view_mm=mm_a,
        per_view_deg=deg_a,
        rms_mm=float(np.sqrt(np.mean(mm_a**2))),
        rms_deg=float(np.sqrt(np.mean(deg_a**2))),
        axis_spread_deg=spread,
        closed_form=x0,
    )


@dataclass(frozen=True, slots=True)
class Reading:
    """One way of numbering a view's corners: the board's pose in the camera it gives (4×4),
    the corners on the board (N, 3) and in the image (N, 2) [px]."""

    pose: NDArray[np.float64]
    object_points: NDArray[np.float32]
    image_points: NDArray[np.float32]


MAX_RENUMBERINGS = 3
"""Times the views' numbering is read again from the fitted chain before it is taken."""

OUTLIER_FACTOR = 3.0
"""A view whose corners lie this many times the views' median RMS from where the chain puts
them (and over ``OUTLIER_FLOOR_PX``) is left out and the rest solved again: its corners were
misnumbered by the detector, or its pose mistyped."""
OUTLIER_FLOOR_PX = 1.0


def solve_numbered(
    flange: list[NDArray[np.float64]],
    readings: list[list[Reading]],
    k: NDArray[np.float64],
    dist: NDArray[np.float64],
    *,
    eye_in_hand: bool,
) -> tuple[HandEye, list[int], list[int]]:
    """``solve`` over the views' readings numbered alike (``_numbered``), leaving out views
    that disagree with the rest (``OUTLIER_FACTOR``) while 3 or more remain. Returns the
    solution, the views it kept and those it left out (indices into ``readings``)."""
    kept = list(range(len(readings)))
    dropped: list[int] = []
    while True:
        result = _numbered(
            [flange[i] for i in kept], [readings[i] for i in kept], k, dist, eye_in_hand
        )
        limit = max(OUTLIER_FACTOR * float(np.median(result.per_view_px)), OUTLIER_FLOOR_PX)
        worst = int(np.argmax(result.per_view_px))
        if result.per_view_px[worst] <= limit or len(kept) <= 3:
            return result, kept, dropped
        dropped.append(kept.pop(worst))


def _numbered(
    flange: list[NDArray[np.float64]],
    readings: list[list[Reading]],
    k: NDArray[np.float64],
    dist: NDArray[np.float64],
    eye_in_hand: bool,
) -> HandEye:
    """``solve`` with each view's reading chosen first as ``consistent`` chooses, then, from
    the fitted chain, the reading nearest where the chain puts its board, until no choice
    changes."""
    chosen = consistent(flange, [[r.pose for r in rs] for rs in readings], eye_in_hand=eye_in_hand)
    g = [f if eye_in_hand else inverse(f) for f in flange]
    for _ in range(MAX_RENUMBERINGS + 1):
        picked = [rs[c] for rs, c in zip(readings, chosen, strict=True)]
        result = solve(
            flange,
            [r.pose for r in picked],
            [r.object_points for r in picked],
            [r.image_points for r in picked],
            k,
            dist,
            eye_in_hand=eye_in_hand,
        )
        nearest = [
            int(
                np.argmin(
                    [_angle((inverse(r.pose) @ _chain(gi, result.X, result.Y))[:3, :3]) for r in rs]
                )
            )
            for gi, rs in zip(g, readings, strict=True)
        ]
        if nearest == chosen:
            break
        chosen = nearest
    return result
