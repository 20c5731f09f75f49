"""Ingest one frame: check and decode the JPEG, compute its statistics, store frame and verdict."""

from __future__ import annotations

import uuid
from dataclasses import dataclass
from datetime import datetime

from sqlalchemy.orm import Session

from app.core.jpeg import SOI, JpegError, JpegHeader, TooManyPixelsError, decode_rgb
from app.core.stats import ChannelStats, Roi, channel_stats
from app.db.base import utcnow
from app.db.models import Frame, Verdict
from app.db.rows import insert_rows
from app.errors import Unprocessable, UnsupportedMediaType
from app.services.camera_info import CameraInfo
from app.services.storage import FrameStore
from app.services.verdicts import conclude


@dataclass(frozen=True, slots=True)
class Decoded:
    header: JpegHeader
    stats: ChannelStats


def analyse(data: bytes, *, roi: Roi | None, max_pixels: int) -> Decoded:
    """Validate and decode the JPEG and compute the channel statistics inside ``roi``.

    Raises UnsupportedMediaType (not a JPEG) or Unprocessable (truncated, undecodable,
    over the pixel limit, ROI outside the frame). Touches no database.
    """
    if not data:
        raise Unprocessable("empty body: expected a JPEG", code="empty")
    if not data.startswith(SOI):
        raise UnsupportedMediaType(
            "the body is not a JPEG (no FF D8 start marker)", code="not_jpeg"
        )
    try:
        header, image = decode_rgb(data, max_pixels=max_pixels)
    except TooManyPixelsError as exc:
        raise Unprocessable(str(exc), code="too_many_pixels") from None
    except JpegError as exc:
        raise Unprocessable(str(exc), code="corrupt_jpeg") from None
    try:
        stats = channel_stats(image, roi)
    except ValueError as exc:
        raise Unprocessable(f"the camera's {exc}", code="roi_outside_frame") from None
    return Decoded(header, stats)


@dataclass(frozen=True, slots=True)
class Prepared:
    """A frame checked, decoded, measured and written to the store; not yet in the database."""

    camera: CameraInfo
    frame: Frame
    stats: ChannelStats


def prepare(
    frames: FrameStore | None,
    *,
    camera: CameraInfo,
    data: bytes,
    captured_at: datetime | None,
    max_pixels: int,
) -> Prepared:
    """Everything about a frame that needs no database, run in a worker thread.

    The file is written here, before any transaction, so a committed row always has its file.
    A transaction that then fails leaves at most an unreferenced file, which the retention sweep
    removes; it is never deleted here, because an identical frame may share it.
    """
    decoded = analyse(data, roi=camera.roi, max_pixels=max_pixels)
    sha256 = FrameStore.digest(data)
    stored_path = frames.put(data, sha256)[0] if frames is not None else None
    now = utcnow()
    frame = Frame(
        id=str(uuid.uuid4()),
        camera_id=camera.id,
        captured_at=captured_at or now,
        received_at=now,
        width=decoded.header.width,
        height=decoded.header.height,
        size_bytes=len(data),
        sha256=sha256,
        stored_path=stored_path,
    )
    return Prepared(camera, frame, decoded.stats)


def record(session: Session, prepared: Prepared) -> tuple[Frame, Verdict]:
    """The database part: conclude the verdict and insert the frame and verdict rows.

    Runs on the group-commit writer (``app.services.writer``), inside the batch's transaction.
    """
    verdict = conclude(session, prepared.camera, prepared.frame, prepared.stats)
    insert_rows(session, prepared.frame, verdict)
    return prepared.frame, verdict
