"""Calibrating cameras and stereo pairs from uploaded checkerboard images."""

from __future__ import annotations

import uuid
from dataclasses import dataclass
from datetime import datetime
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray
from sqlalchemy.orm import Session

from app.core import calibration
from app.core.jpeg import JpegError, decode_image
from app.db.models import Calibration
from app.errors import NotFound, Unprocessable


@dataclass(frozen=True, slots=True)
class Board:
    cols: int
    rows: int
    square: float


def _detect(
    files: list[tuple[str | None, bytes]], board: Board, max_pixels: int
) -> tuple[list[NDArray[np.float32] | None], list[dict[str, str]], tuple[int, int] | None]:
    found: list[NDArray[np.float32] | None] = []
    rejected: list[dict[str, str]] = []
    size: tuple[int, int] | None = None
    for i, (name, data) in enumerate(files):
        label = name or f"file {i + 1}"
        try:
            rgb = decode_image(data, max_pixels=max_pixels)
        except JpegError as exc:
            rejected.append({"file": label, "reason": str(exc)})
            found.append(None)
            continue
        grey = cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY)
        here = (grey.shape[1], grey.shape[0])
        if min(here) < calibration.MIN_SIDE:
            rejected.append({"file": label, "reason": f"{here[0]}×{here[1]} is too small"})
            found.append(None)
            continue
        if size is not None and here != size:
            rejected.append({"file": label, "reason": f"size {here} differs from {size}"})
            found.append(None)
            continue
        size = size or here
        corners = calibration.find_corners(np.asarray(grey, np.uint8), board.cols, board.rows)
        if corners is None:
            rejected.append(
                {"file": label, "reason": f"no {board.cols}×{board.rows} checkerboard found"}
            )
        found.append(corners)
    return found, rejected, size


def _intrinsics_out(c: calibration.Intrinsics, used: list[str]) -> dict[str, Any]:
    return {
        "K": c.K.tolist(),
        "dist": c.dist.tolist(),
        "rms_px": c.rms,
        "per_view_rms_px": c.per_view_rms.tolist(),
        "std": c.std,
        "views_used": used,
        "image_size": list(c.image_size),
    }


def calibrate_camera(
    session: Session,
    files: list[tuple[str | None, bytes]],
    board: Board,
    *,
    max_pixels: int,
    now: datetime,
) -> Calibration:
    found, rejected, size = _detect(files, board, max_pixels)
    names = [n or f"file {i + 1}" for i, (n, _) in enumerate(files)]
    used = [names[i] for i, c in enumerate(found) if c is not None]
    points = [c for c in found if c is not None]
    if size is None or len(points) < 3:
        raise Unprocessable(
            f"the board was found in {len(points)} of {len(files)} images; at least 3 are needed",
            views_rejected=rejected,
        )
    obj = calibration.board_points(board.cols, board.rows, board.square)
    result = calibration.calibrate([obj] * len(points), points, size)
    row = Calibration(
        id=str(uuid.uuid4()),
        created_at=now,
        kind="single",
        result={
            **_intrinsics_out(result, used),
            "views_rejected": rejected,
            "pattern": [board.cols, board.rows],
            "square_size": board.square,
        },
    )
    session.add(row)
    session.flush()
    return row


def calibrate_pair(
    session: Session,
    left: list[tuple[str | None, bytes]],
    right: list[tuple[str | None, bytes]],
    board: Board,
    *,
    max_pixels: int,
    now: datetime,
) -> Calibration:
    """Each camera on its own views, then their relative pose from the simultaneous pairs."""
    if len(left) != len(right):
        raise Unprocessable(f"{len(left)} left but {len(right)} right images: pair them in order")
    lf, lrej, lsize = _detect(left, board, max_pixels)
    rf, rrej, rsize = _detect(right, board, max_pixels)
    obj = calibration.board_points(board.cols, board.rows, board.square)
    lpts = [c for c in lf if c is not None]
    rpts = [c for c in rf if c is not None]
    if lsize is None or rsize is None or len(lpts) < 3 or len(rpts) < 3:
        raise Unprocessable(
            f"the board was found in {len(lpts)} left and {len(rpts)} right images; "
            "at least 3 of each are needed",
            views_rejected=lrej + rrej,
        )
    lcal = calibration.calibrate([obj] * len(lpts), lpts, lsize)
    rcal = calibration.calibrate([obj] * len(rpts), rpts, rsize)
    pairs = [(a, b) for a, b in zip(lf, rf, strict=True) if a is not None and b is not None]
    pose = calibration.stereo(
        [obj] * len(pairs), [a for a, _ in pairs], [b for _, b in pairs], lcal, rcal
    )
    lnames = [n or f"left {i + 1}" for i, (n, _) in enumerate(left)]
    rnames = [n or f"right {i + 1}" for i, (n, _) in enumerate(right)]
    row = Calibration(
        id=str(uuid.uuid4()),
        created_at=now,
        kind="stereo",
        result={
            "left": _intrinsics_out(lcal, [lnames[i] for i, c in enumerate(lf) if c is not None]),
            "right": _intrinsics_out(rcal, [rnames[i] for i, c in enumerate(rf) if c is not None]),
            "R": pose.R.tolist(),
            "T": pose.T.tolist(),
            "baseline": pose.baseline,
            "rotation_deg": pose.rotation_deg,
            "rms_px": pose.rms,
            "pairs_used": len(pairs),
            "views_rejected": lrej + rrej,
            "pattern": [board.cols, board.rows],
            "square_size": board.square,
        },
    )
    session.add(row)
    session.flush()
    return row


def get(session: Session, calibration_id: str) -> Calibration:
    row = session.get(Calibration, calibration_id)
    if row is None:
        raise NotFound(f"no calibration {calibration_id!r}")
    return row
