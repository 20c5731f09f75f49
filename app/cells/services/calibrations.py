"""Calibrating cameras and stereo pairs from uploaded checkerboard images."""

from __future__ import annotations

import uuid
from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass
from datetime import datetime
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray
from sqlalchemy import select
from sqlalchemy.orm import Session

from app.cells.core import calibration, charuco
from app.cells.models import Calibration
from app.platform.frames.jpeg import JpegError, decode_image
from app.platform.http.errors import Unprocessable
from app.platform.lookup import get_or_404


@dataclass(frozen=True, slots=True)
class Board:
    cols: int
    """Checkerboard: inner corners across; ChArUco: squares across."""
    rows: int
    square: float
    kind: str = "checkerboard"
    """checkerboard, or charuco (markers in the white squares: partly visible boards count)."""
    dictionary: str = "DICT_5X5_100"
    marker: float | None = None
    """ChArUco: the markers' side, in the square's unit."""

    def charuco(self) -> Any:
        """OpenCV's ChArUco board; 422 naming what is wrong with it."""
        try:
            return charuco.board(
                self.cols, self.rows, self.square, self.marker or 0.0, self.dictionary
            )
        except ValueError as exc:
            raise Unprocessable(str(exc), code="bad_board") from None

    def described(self) -> dict[str, Any]:
        """What the calibration keeps of the board."""
        out: dict[str, Any] = {"pattern": [self.cols, self.rows], "square_size": self.square}
        if self.kind == "charuco":
            out |= {"board": "charuco", "dictionary": self.dictionary, "marker_size": self.marker}
        return out


def _found(grey: NDArray[np.uint8], board: Board, made: Any) -> charuco.Found | None:
    """One view's corners with their ids and board points, of either kind of board."""
    if board.kind == "charuco":
        return charuco.find(grey, made)
    corners = calibration.find_corners(grey, board.cols, board.rows)
    if corners is None:
        return None
    obj = calibration.board_points(board.cols, board.rows, board.square)
    return charuco.Found(np.arange(len(obj), dtype=np.int32), obj, corners)


def _same(a: charuco.Found, b: charuco.Found) -> bool:
    return np.array_equal(a.ids, b.ids) and calibration.same_view(a.image_points, b.image_points)


def detect_boards(
    files: list[tuple[str | None, bytes]], board: Board, max_pixels: int
) -> tuple[list[charuco.Found | None], list[dict[str, str]], tuple[int, int] | None]:
    """The board's corners in each image (None where it is not used), the images not used with
    the reason, and the image size calibrated for.

    That size is the one most of the views with a board have (on a tie, the first such view's):
    one photo from another camera among a series does not reject the series, wherever it comes
    in the upload. A view the same as an earlier one (``calibration.same_view``) counts once:
    repeated, it added no information but made the fit look surer and, with one pose only,
    gave a focal length 76 % off with an RMS of 0.16 px."""
    labels = [name or f"file {i + 1}" for i, (name, _) in enumerate(files)]
    reasons: dict[int, str] = {}
    corners: dict[int, charuco.Found] = {}
    made = board.charuco() if board.kind == "charuco" else None
    what = (
        f"no ChArUco board of {board.cols}×{board.rows} squares ({board.dictionary}) with "
        f"{charuco.MIN_CORNERS} corners or more found"
        if board.kind == "charuco"
        else f"no {board.cols}×{board.rows} checkerboard found"
    )
    sizes: dict[int, tuple[int, int]] = {}
    for i, (_, data) in enumerate(files):
        try:
            rgb = decode_image(data, max_pixels=max_pixels)
        except JpegError as exc:
            reasons[i] = str(exc)
            continue
        grey = cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY)
        del rgb
        sizes[i] = (grey.shape[1], grey.shape[0])
        if min(sizes[i]) < calibration.MIN_SIDE:
            reasons[i] = f"{sizes[i][0]}×{sizes[i][1]} is too small"
            continue
        found = _found(np.asarray(grey, np.uint8), board, made)
        if found is None:
            reasons[i] = what
        else:
            corners[i] = found
    size: tuple[int, int] | None = None
    if corners:
        counts = Counter(sizes[i] for i in corners)  # insertion order breaks ties: the first
        size = max(counts, key=lambda s: counts[s])
    elif sizes:
        size = next(iter(sizes.values()))
    kept: list[int] = []
    for i in sorted(corners):
        if sizes[i] != size:
            reasons[i] = f"size {sizes[i]} differs from {size}, the size of most views"
        elif (twin := next((j for j in kept if _same(corners[j], corners[i])), None)) is not None:
            reasons[i] = (
                f"the same view as {labels[twin]}: a view counts once (move the board or"
                " the camera between views)"
            )
        else:
            kept.append(i)
    found_list = [corners[i] if i in kept else None for i in range(len(files))]
    rejected = [{"file": labels[i], "reason": reasons[i]} for i in sorted(reasons)]
    return found_list, rejected, size


def _intrinsics_out(c: calibration.Intrinsics, used: list[str]) -> dict[str, Any]:
    loo = c.loo_per_view if c.loo_per_view is not None else c.per_view_rms
    flagged = set(calibration.flagged_views(c.per_view_rms)) | set(calibration.flagged_views(loo))
    return {
        "K": c.K.tolist(),
        "dist": c.dist.tolist(),
        "rms_px": c.rms,
        "loo_rms_px": c.loo_rms,
        "per_view_rms_px": c.per_view_rms.tolist(),
        "per_view_loo_px": loo.tolist(),
        "pixel_sigma_px": c.pixel_sigma,
        "views_flagged": [used[i] for i in sorted(flagged)],
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
    name: str | None = None,
) -> Calibration:
    """A camera's intrinsics from its views of the board, stored (kind ``single``)."""
    found, rejected, size = detect_boards(files, board, max_pixels)
    names = [n or f"file {i + 1}" for i, (n, _) in enumerate(files)]
    used = [names[i] for i, c in enumerate(found) if c is not None]
    views = [c for c in found if c is not None]
    if size is None or len(views) < 3:
        raise Unprocessable(
            f"{len(views)} of {len(files)} images are usable views of the board; at least 3"
            " are needed (views_rejected says why the others are not)",
            views_rejected=rejected,
        )
    try:
        result = calibration.fit_intrinsics(
            [v.object_points for v in views], [v.image_points for v in views], size
        )
    except calibration.CalibrationError as exc:
        raise Unprocessable(str(exc), views_rejected=rejected) from None
    row = Calibration(
        id=str(uuid.uuid4()),
        created_at=now,
        kind="single",
        result={
            "name": name,
            **_intrinsics_out(result, used),
            "views_rejected": rejected,
            **board.described(),
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
    name: str | None = None,
) -> Calibration:
    """Each camera on its own views, then their relative pose from the simultaneous pairs."""
    if len(left) != len(right):
        raise Unprocessable(f"{len(left)} left but {len(right)} right images: pair them in order")
    lf, lrej, lsize = detect_boards(left, board, max_pixels)
    rf, rrej, rsize = detect_boards(right, board, max_pixels)
    lpts = [c for c in lf if c is not None]
    rpts = [c for c in rf if c is not None]
    if lsize is None or rsize is None or len(lpts) < 3 or len(rpts) < 3:
        raise Unprocessable(
            f"{len(lpts)} left and {len(rpts)} right images are usable views of the board; at"
            " least 3 of each are needed (views_rejected says why the others are not)",
            views_rejected=lrej + rrej,
        )
    pairs = [
        shared
        for a, b in zip(lf, rf, strict=True)
        if a is not None and b is not None and (shared := charuco.common(a, b)) is not None
    ]
    cals = []
    for side, pts, size in (("left", lpts, lsize), ("right", rpts, rsize)):
        try:
            cals.append(
                calibration.fit_intrinsics(
                    [v.object_points for v in pts], [v.image_points for v in pts], size
                )
            )
        except calibration.CalibrationError as exc:
            raise Unprocessable(f"{side} camera: {exc}", views_rejected=lrej + rrej) from None
    lcal, rcal = cals
    if not pairs:
        raise Unprocessable(
            "no pair in which both cameras found the board: their relative pose needs views"
            " taken together",
            views_rejected=lrej + rrej,
        )
    pose = calibration.stereo(
        [a.object_points for a, _ in pairs],
        [a.image_points for a, _ in pairs],
        [b.image_points for _, b in pairs],
        lcal,
        rcal,
    )
    lnames = [n or f"left {i + 1}" for i, (n, _) in enumerate(left)]
    rnames = [n or f"right {i + 1}" for i, (n, _) in enumerate(right)]
    row = Calibration(
        id=str(uuid.uuid4()),
        created_at=now,
        kind="stereo",
        result={
            "name": name,
            "left": _intrinsics_out(lcal, [lnames[i] for i, c in enumerate(lf) if c is not None]),
            "right": _intrinsics_out(rcal, [rnames[i] for i, c in enumerate(rf) if c is not None]),
            "R": pose.R.tolist(),
            "T": pose.T.tolist(),
            "baseline": pose.baseline,
            "rotation_deg": pose.rotation_deg,
            "rms_px": pose.rms,
            "loo_rms_px": pose.loo_rms,
            "per_pair_loo_px": None if pose.loo_per_pair is None else pose.loo_per_pair.tolist(),
            "pairs_used": len(pairs),
            "views_rejected": lrej + rrej,
            **board.described(),
        },
    )
    session.add(row)
    session.flush()
    return row


def listed(session: Session, *, kind: str | None, limit: int, offset: int) -> Sequence[Calibration]:
    """Calibrations newest first (only of ``kind``, single or stereo, when given)."""
    q = select(Calibration)
    if kind is not None:
        q = q.where(Calibration.kind == kind)
    q = q.order_by(Calibration.created_at.desc(), Calibration.id)
    return session.scalars(q.limit(limit).offset(offset)).all()


def get(session: Session, calibration_id: str) -> Calibration:
    return get_or_404(session, Calibration, calibration_id, "calibration")


def stereo_cameras(session: Session, calibration_id: str) -> list[dict[str, Any]]:
    """The two cameras of a stereo calibration as a calibrated rig's: the left one is the world
    frame, the right one at the pair's R and T (OpenCV's: x_right = R x_left + T)."""
    row = session.get(Calibration, calibration_id)
    if row is None:
        raise Unprocessable(f"no calibration {calibration_id!r}", code="no_such_calibration")
    if row.kind != "stereo":
        raise Unprocessable(
            f"calibration {calibration_id!r} is of one camera; a rig needs a stereo pair "
            "(POST /calibrations/stereo), or cameras given with their R and t",
            code="not_a_stereo_calibration",
        )
    r = row.result
    identity = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]
    left, right = r["left"], r["right"]
    return [
        {
            "K": left["K"],
            "dist": left["dist"],
            "R": identity,
            "t": [0.0, 0.0, 0.0],
            "image_size": left.get("image_size"),
        },
        {
            "K": right["K"],
            "dist": right["dist"],
            "R": r["R"],
            "t": r["T"],
            "image_size": right.get("image_size"),
        },
    ]
