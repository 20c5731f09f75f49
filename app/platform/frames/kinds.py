"""What a camera kind's domain does with a frame, handed to the platform by ``app.main``.

The platform ingests every frame alike (decode, channel statistics inside the region,
quality gate, store) and leaves what a frame means to the domain that owns the camera's kind:
solar judges a panel, air grades the sky, cells keep the statistics of a rig's view. A domain
registers one ``KindHandler`` per kind at start (``register``); the platform never imports a
domain.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray
from pydantic import BaseModel
from sqlalchemy.orm import Session

from app.platform.db.models import Camera, CameraKind, Frame, Verdict
from app.platform.frames.camera_info import CameraInfo
from app.platform.frames.jpeg import JpegHeader
from app.platform.frames.quality import DEFAULT_LIMITS, QualityLimits
from app.platform.frames.stats import ChannelStats, Roi
from app.platform.schemas import FrameOut
from app.platform.timing import Timing


@dataclass(frozen=True, slots=True)
class Decoded:
    header: JpegHeader
    stats: ChannelStats
    """Channel statistics inside the camera's ROI (of the image decoded at ``reduction``)."""
    quality: str | None
    """Why the frame cannot be judged (night, glare, blank, occluded), or None."""
    features: NDArray[np.float64] | None
    """The kind's own features of the frame (``KindHandler.features``), or None."""
    reduction: int
    """The frame was decoded at 1/reduction of its size (libjpeg DCT scaling)."""


@dataclass(frozen=True, slots=True)
class Prepared:
    """A frame checked, decoded, measured and written to the store; not yet in the database."""

    camera: CameraInfo
    frame: Frame
    decoded: Decoded
    may_repeat: bool = False
    """The upload could repeat a stored one (it has an Idempotency-Key or its own captured_at);
    otherwise the unique constraint alone guards against duplicates."""
    backfill: bool = False
    """An archive's frame imported by an admin: history, graded and smoothed in its own time,
    raising nothing live (no alert)."""


@dataclass(frozen=True, slots=True)
class Pixels:
    """A decoded frame as a kind's feature extractor sees it."""

    camera: CameraInfo
    image: NDArray[np.uint8]
    """The whole frame, H×W×3 RGB (at 1/``reduction`` of its size)."""
    region: NDArray[np.uint8]
    """The camera's region of it: a rectangle's crop, or a polygon's pixels as a column."""
    roi: Roi | None
    """The region's bounding box in ``image``'s pixels, or None (the whole frame)."""
    stats: ChannelStats


Classifier = Callable[[Session, Prepared, Timing], Verdict]
"""The verdict on a prepared frame: runs on the group-commit writer, inside the batch's
transaction (it may read its reference and update state rows) and returns an unsaved row.
Anything CPU-heavy belongs in ``KindHandler.features``, which runs in parallel before."""


def _full_size(header: JpegHeader) -> int:
    return 1


STATISTICS_PIXELS = 12_000_000
"""What channel statistics need at most [px]: a frame larger is decoded reduced to this."""


def reduced_to_statistics(header: JpegHeader) -> int:
    """The smallest DCT reduction (1, 2, 4, 8) that brings the frame to ``STATISTICS_PIXELS``
    or fewer: a 48 MP phone photo is decoded at 12 MP (1/4 of the memory and the time) for
    statistics that a 2×2 block average does not change (its modes are histogram peaks)."""
    for r in (1, 2, 4):
        if header.pixels <= STATISTICS_PIXELS * r * r:
            return r
    return 8


def _as_stored(session: Session, camera: Camera, info: CameraInfo) -> CameraInfo:
    return info


def _no_check(session: Session, link: str) -> None:
    return None


def _no_link(session: Session, link: str) -> bool:
    return False


def _none_kept(session: Session) -> Iterable[str]:
    return ()


@dataclass(frozen=True, slots=True)
class KindHandler:
    """One camera kind's part of the ingest path."""

    conclude: Classifier
    verdict_out: Callable[[Verdict], BaseModel]
    """The verdict row as the frame endpoints answer it (a member of ``schemas.VerdictOut``)."""
    limits: QualityLimits = DEFAULT_LIMITS
    """The quality gate's limits for this kind's pictures."""
    reduction: Callable[[JpegHeader], int] = _full_size
    """The DCT reduction (1, 2, 4 or 8) a frame of this kind is decoded at."""
    features: Callable[[Pixels], NDArray[np.float64] | None] | None = None
    """Per-frame features the classifier needs, computed in the preparing threads."""
    describe: Callable[[Session, Camera, CameraInfo], CameraInfo] = _as_stored
    """The camera's snapshot with what the kind knows of it (``CameraInfo.has_reference``)."""
    check_camera: Callable[[Session, str], None] = _no_check
    """Refuse (4xx) a camera of this kind linked to a record (``Camera.panel_id``) that does not
    exist or is out of service; run as a camera is registered or changed, before its flush."""
    link_exists: Callable[[Session, str], bool] = _no_link
    """Whether the record a camera of this kind may link to exists (a filter's 404)."""
    verdict_table: type[Verdict] | None = None
    """The kind's own verdict table (joined to ``verdicts``), whose rows go first when a
    frame's rows go."""
    kept_frames: Callable[[Session], Iterable[str]] = _none_kept
    """Ids of frames the kind still needs whatever their age (a baseline's or a calibration's
    training frames, an alert's frame): retention keeps them."""


@dataclass(slots=True)
class Kinds:
    """The handlers of the camera kinds, one each."""

    handlers: dict[CameraKind, KindHandler] = field(default_factory=dict)

    def __getitem__(self, kind: CameraKind) -> KindHandler:
        try:
            return self.handlers[kind]
        except KeyError:
            raise LookupError(f"no handler registered for {kind.value} cameras") from None


KINDS = Kinds()
"""The process's handlers, filled by ``app.main.register_kinds`` before any frame is taken."""


def register(kind: CameraKind, handler: KindHandler) -> None:
    """Hand the platform what the domain owning ``kind`` does with its frames."""
    KINDS.handlers[kind] = handler


def verdict_common(verdict: Verdict) -> dict[str, object]:
    """The fields every kind's verdict answers with (``schemas.VerdictBase``)."""
    return {
        "modes": verdict.modes,
        "means": verdict.means,
        "reason": verdict.reason,
        "roi": verdict.roi,
    }


def frame_out(frame: Frame, verdict: Verdict) -> FrameOut:
    """A frame and its verdict as the frame endpoints answer them."""
    return FrameOut(
        frame_id=frame.id,
        camera_id=frame.camera_id,
        captured_at=frame.captured_at,
        received_at=frame.received_at,
        width=frame.width,
        height=frame.height,
        sha256=frame.sha256,
        stored=frame.stored_path is not None,
        verdict=KINDS[verdict.kind].verdict_out(verdict),
    )
