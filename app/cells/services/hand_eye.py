"""Hand-eye calibration from uploaded views of a board and the robot's poses
(``core.hand_eye``): where the camera is in the robot's base (eye to hand) or on its flange
(eye in hand)."""

from __future__ import annotations

import json
import uuid
from datetime import datetime
from typing import Any, Literal

import cv2
import numpy as np
from numpy.typing import NDArray
from sqlalchemy.orm import Session

from app.cells.core import charuco, hand_eye
from app.cells.models import Calibration
from app.cells.services.calibrations import Board, detect_boards
from app.platform.http.errors import Unprocessable

Setup = Literal["eye_to_hand", "eye_in_hand"]

MAX_SQUARE_M = 0.5
"""A board's square larger than this [m] is one given in millimetres by mistake."""


def parse_pose(text: str, index: int) -> NDArray[np.float64]:
    """A flange pose (base ← flange, 4×4) from its JSON: ``{"rotation": 3×3, "translation":
    [x, y, z]}`` or ``{"rvec", "tvec"}``, translations in metres; 422 naming the pose."""
    where = f"poses[{index}]"
    try:
        given = json.loads(text)
    except ValueError:
        raise Unprocessable(f"{where}: not JSON", code="bad_pose") from None
    if not isinstance(given, dict):
        raise Unprocessable(f"{where}: expected an object", code="bad_pose")
    try:
        if "rotation" in given:
            r = np.array(given["rotation"], dtype=np.float64)
            t = np.array(given["translation"], dtype=np.float64)
        elif "rvec" in given:
            rvec = np.array(given["rvec"], dtype=np.float64)
            t = np.array(given["tvec"], dtype=np.float64)
            if rvec.shape != (3,) or not np.isfinite(rvec).all():
                raise ValueError
            r = np.asarray(cv2.Rodrigues(rvec)[0], dtype=np.float64)
        else:
            raise Unprocessable(
                f"{where}: give rotation and translation, or rvec and tvec", code="bad_pose"
            )
    except (KeyError, TypeError, ValueError):
        raise Unprocessable(
            f"{where}: rotation must be 3×3 numbers (rvec 3) and translation (tvec) 3",
            code="bad_pose",
        ) from None
    why = hand_eye.check_pose(r, t)
    if why is not None:
        raise Unprocessable(f"{where}: {why}", code="bad_pose")
    return hand_eye.rigid(r, t)


def _intrinsics(session: Session, calibration_id: str) -> tuple[Any, Any, list[int]]:
    row = session.get(Calibration, calibration_id)
    if row is None:
        raise Unprocessable(f"no calibration {calibration_id!r}", code="no_such_calibration")
    cam = row.result if row.kind == "single" else row.result.get("left")
    if row.kind not in ("single", "stereo") or cam is None:
        raise Unprocessable(
            f"calibration {calibration_id!r} is a {row.kind} calibration: give a camera's "
            "(POST /calibrations)",
            code="no_such_calibration",
        )
    k = np.array(cam["K"], dtype=np.float64)
    dist = np.array(cam["dist"], dtype=np.float64)
    return k, dist, list(cam.get("image_size") or [])


def _poses(
    view: charuco.Found, k: NDArray[np.float64], dist: NDArray[np.float64]
) -> list[NDArray[np.float64]]:
    """The board's poses in the camera (4×4) its corners allow: a plane seen from afar or
    nearly face on has two that reproject almost alike (IPPE gives both), and hand-eye lets the
    robot's motion choose (``hand_eye.solve_numbered``)."""
    _, rvecs, tvecs, _ = cv2.solvePnPGeneric(
        view.object_points, view.image_points, k, dist, flags=cv2.SOLVEPNP_IPPE
    )
    return [
        hand_eye.rigid(
            np.asarray(cv2.Rodrigues(rv)[0], dtype=np.float64),
            np.asarray(tv, dtype=np.float64).ravel(),
        )
        for rv, tv in zip(rvecs, tvecs, strict=True)
    ]


def _readings(view: charuco.Found, board: Board) -> list[charuco.Found]:
    """The ways a view's corners may be numbered: a ChArUco board's one (by its ids), a
    checkerboard's two (from either end: it looks the same turned by 180°)."""
    if board.kind == "charuco":
        return [view]
    turned = charuco.Found(view.ids, view.object_points, view.image_points[::-1].copy())
    return [view, turned]


def _posed(
    found: list[charuco.Found | None],
    flange: list[NDArray[np.float64]],
    k: NDArray[np.float64],
    dist: NDArray[np.float64],
    board: Board,
    names: list[str],
    rejected: list[dict[str, str]],
) -> tuple[list[str], list[Any], list[list[hand_eye.Reading]]]:
    """The views with the board found and its pose solved: names, flange poses, and each
    view's readings: every numbering (``_readings``) with every pose it allows (``_poses``);
    a view without one joins ``rejected``."""
    used, f_used, readings = [], [], []
    for i, view in enumerate(found):
        if view is None:
            continue
        ways = [
            hand_eye.Reading(pose, w.object_points, w.image_points)
            for w in _readings(view, board)
            for pose in _poses(w, k, dist)
        ]
        if not ways:
            rejected.append({"file": names[i], "reason": "the board's pose could not be solved"})
            continue
        used.append(names[i])
        f_used.append(flange[i])
        readings.append(ways)
    return used, f_used, readings


def _described(
    result: hand_eye.HandEye,
    setup: Setup,
    calibration_id: str,
    used: list[str],
    rejected: list[dict[str, str]],
    board: Board,
) -> dict[str, Any]:
    """What a hand-eye calibration keeps and answers."""
    frame = "camera_to_flange" if setup == "eye_in_hand" else "camera_to_base"
    board_key = "board_in_base" if setup == "eye_in_hand" else "board_on_flange"
    return {
        "setup": setup,
        "calibration_id": calibration_id,
        frame: result.X.tolist(),
        board_key: result.Y.tolist(),
        "closed_form": result.closed_form.tolist(),
        "rms_px": result.rms_px,
        "rms_mm": result.rms_mm,
        "rms_deg": result.rms_deg,
        "axis_spread_deg": result.axis_spread_deg,
        "per_view": [
            {"file": name, "rms_px": float(px), "mm": float(mm), "deg": float(deg)}
            for name, px, mm, deg in zip(
                used, result.per_view_px, result.per_view_mm, result.per_view_deg, strict=True
            )
        ],
        "views_used": used,
        "views_rejected": rejected,
        **board.described(),
    }


def calibrate(
    session: Session,
    *,
    calibration_id: str,
    files: list[tuple[str | None, bytes]],
    poses: list[str],
    setup: Setup,
    board: Board,
    max_pixels: int,
    now: datetime,
    name: str | None = None,
) -> Calibration:
    """Solve the hand-eye calibration and store it (kind ``hand_eye``). Every pose is checked
    before an image is decoded; views without the board are left out with their pose."""
    if len(poses) != len(files):
        fewer = "fewer" if len(poses) < len(files) else "more"
        raise Unprocessable(
            f"{len(poses)} poses for {len(files)} files ({fewer} poses than files): give one "
            "pose per file, in the same order",
            code="bad_pose",
        )
    if board.square > MAX_SQUARE_M:
        raise Unprocessable(
            f"square_size {board.square} m: the board's square is in metres, as the poses' "
            "translations are",
            code="bad_pose",
        )
    flange = [parse_pose(text, i) for i, text in enumerate(poses)]
    k, dist, size = _intrinsics(session, calibration_id)
    found, rejected, got_size = detect_boards(files, board, max_pixels)
    if size and got_size is not None and list(got_size) != size:
        raise Unprocessable(
            f"the views are {got_size[0]}×{got_size[1]}, the calibration's camera "
            f"{size[0]}×{size[1]}: calibrate this camera first",
            views_rejected=rejected,
        )
    names = [n or f"file {i + 1}" for i, (n, _) in enumerate(files)]
    used, f_used, readings = _posed(found, flange, k, dist, board, names, rejected)
    if len(readings) < 3:
        raise Unprocessable(
            f"{len(readings)} of {len(files)} images are usable views of the board; at least 3 "
            "are needed (views_rejected says why the others are not)",
            views_rejected=rejected,
        )
    try:
        result, kept, dropped = hand_eye.solve_numbered(
            f_used, readings, k, dist, eye_in_hand=setup == "eye_in_hand"
        )
    except hand_eye.HandEyeError as exc:
        raise Unprocessable(str(exc), code="not_observable", views_rejected=rejected) from None
    rejected += [
        {
            "file": used[i],
            "reason": "its board lies far from where the robot's other poses put it (corners "
            "misnumbered, or its pose mistyped): left out",
        }
        for i in dropped
    ]
    used = [used[i] for i in kept]
    row = Calibration(
        id=str(uuid.uuid4()),
        created_at=now,
        kind="hand_eye",
        result={"name": name, **_described(result, setup, calibration_id, used, rejected, board)},
    )
    session.add(row)
    session.flush()
    return row
