"""Sky cameras' part of the ingest path (``KindHandler``), handed to the platform by
``app.main``: the sky's quality limits, its features, and its verdict's shape."""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np
from numpy.typing import NDArray
from sqlalchemy import select
from sqlalchemy.orm import Session

from app.air.core import airquality
from app.air.models import AirAlert, AirCalibration, SkyVerdict
from app.air.services import grading
from app.air.services.readings import estimate_out
from app.platform.db.models import Verdict
from app.platform.frames.kinds import KindHandler, Pixels, verdict_common
from app.platform.frames.quality import SKY_LIMITS
from app.platform.frames.stats import Roi
from app.platform.schemas import SkyVerdictOut


def band_below(image: NDArray[np.uint8], roi: Roi | None) -> NDArray[np.uint8] | None:
    """The strip under the sky region (``airquality.SKYLINE_HEIGHT`` of the frame's height):
    the distant skyline, whose contrast fades in haze, then nearer buildings. None when the
    sky region reaches the bottom."""
    h = image.shape[0]
    top = roi[1] + roi[3] if roi else h
    strip = image[top : min(h, top + max(1, round(h * airquality.SKYLINE_HEIGHT)))]
    return strip if strip.shape[0] >= 2 else None


def _features(pixels: Pixels) -> NDArray[np.float64]:
    below = band_below(pixels.image, pixels.roi)
    return airquality.sky_features(pixels.region, below, pixels.stats.histograms)


NOT_SURE = "Not sure: the sky in this frame is unlike what the camera was calibrated on"


def verdict_message(verdict: SkyVerdict) -> str | None:
    """A frame's message (ch. 6: the screen below the camera): its category, "likely" when the
    regression's probability of it is below ``public.SURE``; not sure only outside what was
    calibrated (no category then)."""
    if verdict.category is None:
        return NOT_SURE if verdict.uncertain else None
    likely = "likely " if verdict.uncertain else ""
    return f"Today's Air Quality is {likely}{verdict.category}"


def verdict_out(verdict: Verdict) -> SkyVerdictOut:
    """A sky verdict row as the frame endpoints answer it."""
    assert isinstance(verdict, SkyVerdict)
    return SkyVerdictOut(
        level=verdict.level,
        category=verdict.category,
        message=verdict_message(verdict),
        calibration_id=verdict.calibration_id,
        uncertain=bool(verdict.uncertain),
        probability=verdict.probability,
        span=verdict.span,
        estimate=estimate_out(verdict),
        **verdict_common(verdict),
    )


def _kept_frames(session: Session) -> Iterator[str]:
    """The frames air calibrations were made from, and those alerts point at."""
    for ids in session.scalars(select(AirCalibration.frame_ids)):
        yield from ids or []
    yield from session.scalars(select(AirAlert.frame_id))


HANDLER = KindHandler(
    conclude=grading.classify_frame,
    verdict_out=verdict_out,
    limits=SKY_LIMITS,
    features=_features,
    verdict_table=SkyVerdict,
    kept_frames=_kept_frames,
)
