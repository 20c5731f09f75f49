"""Ingest one frame: check and decode the JPEG, compute its statistics, store frame and verdict."""

from __future__ import annotations

import uuid
from dataclasses import dataclass
from datetime import datetime

from sqlalchemy.orm import Session

from app.core.jpeg import SOI, JpegError, JpegHeader, TooManyPixelsError, decode_rgb
from app.core.stats import ChannelStats, Roi, channel_stats
from app.db.base import utcnow
from app.db.models import Camera, Frame, Verdict
from app.errors import NotFound, Unprocessable, UnsupportedMediaType
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


def store(
    session: Session,
    frames: FrameStore | None,
    *,
    camera_id: str,
    data: bytes,
    decoded: Decoded,
    captured_at: datetime | None,
) -> tuple[Frame, Verdict]:
    """Write the frame and its verdict in the request's transaction, and the bytes to the store.

    The file is written after the rows are flushed, so a refused row leaves no file behind.
    """
    camera = session.get(Camera, camera_id)
    if camera is None:
        raise NotFound(f"no camera {camera_id!r}")
    now = utcnow()
    sha256 = FrameStore.digest(data)
    frame = Frame(
        id=str(uuid.uuid4()),
        camera_id=camera.id,
        captured_at=captured_at or now,
        received_at=now,
        width=decoded.header.width,
        height=decoded.header.height,
        size_bytes=len(data),
        sha256=sha256,
    )
    session.add(frame)
    verdict = conclude(session, camera, frame, decoded.stats)
    session.add(verdict)
    if frames is not None:
        frame.stored_path = FrameStore.relative_path(sha256)
    session.flush()
    if frames is not None:
        frames.put(data, sha256)
    return frame, verdict


def ingest(
    session: Session,
    frames: FrameStore | None,
    *,
    camera_id: str,
    roi: Roi | None,
    data: bytes,
    captured_at: datetime | None,
    max_pixels: int,
) -> tuple[Frame, Verdict]:
    """Decode first (no transaction open), then store."""
    decoded = analyse(data, roi=roi, max_pixels=max_pixels)
    return store(
        session, frames, camera_id=camera_id, data=data, decoded=decoded, captured_at=captured_at
    )
