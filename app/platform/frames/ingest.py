"""Ingest one frame: check and decode the JPEG, compute its statistics, store frame and verdict."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from datetime import datetime
from functools import partial

import numpy as np
from numpy.typing import NDArray
from sqlalchemy import select
from sqlalchemy.orm import Session, selectinload

from app.platform.db.ids import time_ordered_id
from app.platform.db.models import Frame, Verdict
from app.platform.db.rows import insert_rows
from app.platform.frames.camera_info import CameraInfo, Region, parse_region
from app.platform.frames.jpeg import (
    SOI,
    JpegError,
    TooManyPixelsError,
    decode_rgb,
    read_header,
)
from app.platform.frames.kinds import KINDS, Decoded, Pixels, Prepared
from app.platform.frames.quality import (
    obstruction_reason,
    unusable_reason,
)
from app.platform.frames.stats import (
    Polygon,
    Roi,
    bounding_box,
    channel_stats,
    crop,
    polygon_pixels,
)
from app.platform.frames.storage import FrameStore, digest
from app.platform.http.errors import Unprocessable, UnsupportedMediaType, VantageError
from app.platform.timing import Timing


def scale_roi(roi: Roi, width: int, height: int, reduction: int) -> Roi:
    """The ROI of the full frame, checked against it, in the pixels of the reduced image."""
    x, y, w, h = roi
    if x + w > width or y + h > height:
        raise ValueError(f"ROI {list(roi)} does not lie inside the {width}×{height} frame")
    r = reduction
    return (x // r, y // r, max(1, w // r), max(1, h // r))


def scale_polygon(polygon: Polygon, width: int, height: int, reduction: int) -> Polygon:
    """The polygon of the full frame, checked against it, in the pixels of the reduced image."""
    if any(x >= width or y >= height for x, y in polygon):
        raise ValueError(
            f"ROI polygon {[list(p) for p in polygon]} does not lie inside the "
            f"{width}×{height} frame"
        )
    return tuple((x // reduction, y // reduction) for x, y in polygon)


def check_fits(region: Region, width: int, height: int) -> None:
    """Raise ValueError when ``region`` (as stored) does not lie inside a ``width`` ×
    ``height`` frame: the check every upload's region gets."""
    roi, polygon = parse_region(region)
    if polygon is not None:
        scale_polygon(polygon, width, height, 1)
    elif roi is not None:
        scale_roi(roi, width, height, 1)


def region_of(
    image: NDArray[np.uint8], camera: CameraInfo, width: int, height: int, reduction: int
) -> tuple[NDArray[np.uint8], Roi | None]:
    """The camera's region of the (reduced) image, and its bounding box: a rectangle's crop,
    or a polygon's pixels as a column image."""
    if camera.polygon is not None:
        polygon = scale_polygon(camera.polygon, width, height, reduction)
        return polygon_pixels(image, polygon), bounding_box(polygon)
    roi = camera.roi and scale_roi(camera.roi, width, height, reduction)
    return crop(image, roi), roi


def analyse(data: bytes, *, camera: CameraInfo, max_pixels: int) -> Decoded:
    """Validate and decode the JPEG; channel statistics inside the ROI; quality; features.

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
        header = read_header(data)
        kind = KINDS[camera.kind]
        reduction = kind.reduction(header)
        header, image = decode_rgb(data, max_pixels=max_pixels, reduce=reduction)
    except TooManyPixelsError as exc:
        raise Unprocessable(str(exc), code="too_many_pixels") from None
    except JpegError as exc:
        raise Unprocessable(str(exc), code="corrupt_jpeg") from None
    try:
        region, roi = region_of(image, camera, header.width, header.height, reduction)
    except ValueError as exc:
        raise Unprocessable(f"the camera's {exc}", code="roi_outside_frame") from None
    stats = channel_stats(region)
    limits = kind.limits
    quality = unusable_reason(stats, limits)
    if quality is None and roi is not None:
        # only in a region declared as sky: a camera without one measures its whole view,
        # street and trees included (the Milan webcam's whole frames are up to 21 % foliage)
        quality = obstruction_reason(region, limits)
    features = None
    if kind.features is not None:
        features = kind.features(Pixels(camera, image, region, roi, stats))
    return Decoded(header, stats, quality, features, reduction)


def prepare(
    frames: FrameStore | None,
    *,
    camera: CameraInfo,
    data: bytes,
    captured_at: datetime | None,
    received_at: datetime,
    max_pixels: int,
    idempotency_key: str | None = None,
    backfill: bool = False,
) -> Prepared:
    """Everything about a frame that needs no database, run in a worker thread.

    The bytes are stored here, before any transaction, so a committed row always has them. A
    transaction that then fails leaves bytes no row refers to, which retention removes (with
    their pack, or as an orphan file); they are never deleted here, because in a store that
    names frames by their SHA-256 an identical frame may share them.
    """
    decoded = analyse(data, camera=camera, max_pixels=max_pixels)
    sha256 = digest(data)
    stored_path = frames.put(data, sha256, received_at) if frames is not None else None
    frame = Frame(
        id=time_ordered_id(),
        camera_id=camera.id,
        captured_at=captured_at or received_at,
        received_at=received_at,
        width=decoded.header.width,
        height=decoded.header.height,
        size_bytes=len(data),
        sha256=sha256,
        stored_path=stored_path,
        idempotency_key=idempotency_key,
    )
    may_repeat = idempotency_key is not None or captured_at is not None
    return Prepared(camera, frame, decoded, may_repeat, backfill)


def recording(
    frames: FrameStore | None,
    camera: CameraInfo,
    data: bytes,
    *,
    captured_at: datetime | None,
    max_pixels: int,
    timing: Timing,
    idempotency_key: str | None = None,
    backfill: bool = False,
) -> Callable[[Session], Recorded]:
    """``prepare`` the frame (received now) and give back the writer's job that records it:
    what ``GroupCommitWriter.submit_after`` runs for a posted frame and for a pulled one."""
    prepared = prepare(
        frames,
        camera=camera,
        data=data,
        captured_at=captured_at,
        received_at=timing.now(),
        max_pixels=max_pixels,
        idempotency_key=idempotency_key,
        backfill=backfill,
    )
    return partial(record, prepared=prepared, timing=timing)


def decode_all(
    files: Sequence[tuple[str | None, bytes]], camera: CameraInfo, *, max_pixels: int
) -> list[Decoded]:
    """Decode every uploaded image; refuse (422) naming each one that is unusable."""
    decoded, problems = [], []
    for i, (name, data) in enumerate(files):
        label = name or f"file {i + 1}"
        try:
            d = analyse(data, camera=camera, max_pixels=max_pixels)
        except VantageError as exc:
            problems.append(f"{label}: {exc.detail}")
            continue
        if d.quality is not None:
            problems.append(f"{label}: {d.quality}")
        decoded.append(d)
    if problems:
        raise Unprocessable("unusable images: " + "; ".join(problems), problems=problems)
    return decoded


def modes_of(decoded: Sequence[Decoded]) -> NDArray[np.float64]:
    return np.array([d.stats.modes for d in decoded], dtype=np.float64).reshape(-1, 3)


@dataclass(frozen=True, slots=True)
class Recorded:
    frame: Frame
    verdict: Verdict
    replay: bool
    """The frame was already stored (a retried upload): these are the original rows."""


def find_original(session: Session, frame: Frame) -> tuple[Frame, Verdict] | None:
    """The stored frame a retry repeats: same camera and Idempotency-Key, or same camera, bytes
    and capture time."""
    q = select(Frame.id).where(Frame.camera_id == frame.camera_id)
    if frame.idempotency_key is not None:
        q = q.where(Frame.idempotency_key == frame.idempotency_key)
    else:
        q = q.where(Frame.sha256 == frame.sha256, Frame.captured_at == frame.captured_at)
    found = session.scalar(q.limit(1))
    if found is None:
        return None
    original = session.scalars(
        select(Frame).where(Frame.id == found).options(selectinload(Frame.verdict))
    ).one()
    return original, original.verdict


def check_same_frame(original: Frame, frame: Frame) -> None:
    """Refuse (422) an Idempotency-Key used before for other bytes: answering with the original
    frame told a camera whose key counter restarted (a reboot) that its new frame was stored,
    and the frame was lost. The key names one request's content (the IETF draft on the header
    answers its reuse with another payload with 422)."""
    if original.idempotency_key is not None and original.sha256 != frame.sha256:
        raise Unprocessable(
            f"Idempotency-Key {original.idempotency_key!r} was used for another frame "
            f"(frame {original.id}, taken at {original.captured_at.isoformat()}): "
            "send a new frame with a new key",
            code="idempotency_key_reused",
        )


def conclude(session: Session, prepared: Prepared, timing: Timing) -> Verdict:
    """The verdict on a prepared frame, by its camera's kind (``kinds.KindHandler.conclude``)."""
    verdict = KINDS[prepared.camera.kind].conclude(session, prepared, timing)
    verdict.roi = prepared.camera.region
    verdict.usable = prepared.decoded.quality is None
    return verdict


def record(
    session: Session, prepared: Prepared, timing: Timing, *, retry: bool = False
) -> Recorded:
    """The database part: conclude the verdict and insert the frame and verdict rows, unless
    this is a retry of a stored frame, whose original rows are returned instead.

    Runs on the group-commit writer (``writer``), inside the batch's transaction.
    """
    # the lookup costs a query per frame: only uploads that could be retries make it (a
    # duplicate of any other is refused by the unique constraint, and the writer then runs
    # this job again with ``may_repeat`` forced on)
    original = find_original(session, prepared.frame) if prepared.may_repeat or retry else None
    if original is not None:
        check_same_frame(original[0], prepared.frame)
        return Recorded(*original, replay=True)
    verdict = conclude(session, prepared, timing)
    insert_rows(session, prepared.frame, verdict)
    return Recorded(prepared.frame, verdict, replay=False)
