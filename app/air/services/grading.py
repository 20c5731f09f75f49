"""Grading sky frames: a frame's level by the calibration that grades its camera, the camera's
smoothed level, and grading a camera's history again."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from datetime import datetime, timedelta
from typing import Any

import numpy as np
from numpy.typing import NDArray
from sqlalchemy import (
    Select,
    and_,
    select,
    update,
)
from sqlalchemy.orm import Session

from app.air.core import airquality
from app.air.models import SkyVerdict
from app.air.services.alerts import alert_row, in_episode, public_level_changed
from app.air.services.calibration import Grading, as_core, as_regression, grading
from app.air.services.cameras import TRUSTED, sky_camera, trusted, with_verdicts
from app.platform.db.models import Camera, Frame
from app.platform.frames.camera_info import (
    CameraInfo,
    describe_region,
)
from app.platform.frames.ingest import analyse
from app.platform.frames.kinds import Decoded, Prepared
from app.platform.frames.storage import FrameStore
from app.platform.frames.verdicts import stats_columns
from app.platform.http.errors import (
    VantageError,
)
from app.platform.timing import Timing


def _levels_of(camera_id: str) -> Select[str, datetime, int | None, bool, float | None]:
    """A camera's readings as smoothing reads them: id, capture time, level, doubt and
    smoothed level."""
    return (
        select(
            Frame.id,
            Frame.captured_at,
            SkyVerdict.level,
            SkyVerdict.uncertain,
            SkyVerdict.smoothed_level,
        )
        .join(SkyVerdict, SkyVerdict.frame_id == Frame.id)
        .where(Frame.camera_id == camera_id)
    )


def classify_frame(session: Session, prepared: Prepared, timing: Timing) -> SkyVerdict:
    """Grade a sky frame, smooth the camera's level, and raise an alert when it turns Poor
    (or clear the camera's last one when it is back to ``CLEAR_LEVEL``)."""
    camera, frame, decoded = prepared.camera, prepared.frame, prepared.decoded
    verdict = SkyVerdict(
        frame_id=frame.id,
        camera_id=camera.id,
        level=None,
        category=None,
        **stats_columns(decoded.stats),
    )
    if decoded.features is not None:
        verdict.details = {"features": decoded.features.tolist()}
    grade_verdict(verdict, camera, decoded, grading(session, camera.id))
    _lock_camera(session, camera.id)
    # the camera's readings of the 12 hours before this frame and the 12 after: those up to
    # its capture smooth it (a frame uploaded late, a backlog, is smoothed with the hours
    # before it was taken, not with the readings taken since); those after it, smoothed
    # before it arrived, are smoothed again with it
    # (an ungraded reading has a smoothed level too: the camera's, from the readings before)
    readings = _levels_of(camera.id)
    graded = readings.where(TRUSTED)
    hours = timedelta(hours=airquality.NOWCAST_HOURS)
    around = session.execute(
        readings.where(
            Frame.captured_at > frame.captured_at - hours,
            Frame.captured_at < frame.captured_at + hours,
        ).order_by(Frame.captured_at.desc(), Frame.received_at.desc())
    ).all()
    counted = [r for r in around if trusted(r.level, r.uncertain)]
    times = [r.captured_at for r in counted]
    levels = [float(r.level) for r in counted]
    later = []
    if verdict.level is not None and not verdict.uncertain:  # trusted
        later = [r for r in around if r.captured_at >= frame.captured_at]
        times.append(frame.captured_at)
        levels.append(float(verdict.level))
    smoothed, *again = airquality.nowcasts(
        times, levels, [frame.captured_at, *(r.captured_at for r in later)]
    )
    verdict.smoothed_level = smoothed
    changed = [
        {"frame_id": r.id, "smoothed_level": s}
        for r, s in zip(later, again, strict=True)
        if (s is None) != (r.smoothed_level is None)
        or (s is not None and not math.isclose(s, r.smoothed_level, rel_tol=1e-12))
    ]
    if changed:
        session.execute(update(SkyVerdict), changed)
        newest = later[0]
        public = next((c["smoothed_level"] for c in changed if c["frame_id"] == newest.id), None)
        if (
            public is not None
            # the camera's newest reading: none after the 12 hours this frame smooths
            and session.execute(
                readings.where(Frame.captured_at >= frame.captured_at + hours).limit(1)
            ).first()
            is None
        ):
            session.add_all(
                public_level_changed(session, camera.id, newest.id, public, frame.received_at)
            )
    if smoothed is not None:
        _alert_if_called_for(session, frame, smoothed, around, graded)
    return verdict


def _alert_if_called_for(
    session: Session,
    frame: Frame,
    smoothed: float,
    around: Sequence[Any],
    graded: Select[str, datetime, int | None, bool, float | None],
) -> None:
    """Raise an alert when the frame's smoothed level enters an alert category its earlier
    readings (``around``, newest first) were not in, or clear the camera's open episode when
    it is back to ``CLEAR_LEVEL``; neither for a frame older than the camera's newest graded
    reading (history, not an alert)."""
    earlier = (  # newest first
        float(r.smoothed_level)
        for r in around
        if r.captured_at <= frame.captured_at
        and trusted(r.level, r.uncertain)
        and r.smoothed_level is not None
    )
    kind, alert = "raised", airquality.alert_category(smoothed, earlier)
    if alert is None and smoothed >= airquality.CLEAR_LEVEL and in_episode(session, frame):
        kind, alert = "cleared", airquality.category(smoothed)
    if (
        alert is not None
        and session.execute(graded.where(Frame.captured_at > frame.captured_at).limit(1)).first()
        is None
    ):
        session.add(alert_row(frame.camera_id, frame.id, frame.received_at, kind, smoothed, alert))


def grade_verdict(verdict: SkyVerdict, camera: CameraInfo, decoded: Decoded, how: Grading) -> None:
    """Grade a sky verdict by what grades its camera (``grading``): the regression on the
    frame's features, else the T² clusters on its modes; a reason instead of a level when
    the frame is unusable, uncalibrated, measured elsewhere than its calibration, or doubted."""
    cal_row = how.calibration
    regression = as_regression(cal_row) if cal_row is not None else None
    verdict.level = verdict.category = verdict.calibration_id = verdict.reason = None
    verdict.statistic = verdict.p_value = None
    verdict.estimate = verdict.estimate_low = verdict.estimate_high = None
    verdict.estimate_unit, verdict.uncertain, verdict.span = None, False, None
    if decoded.quality is not None:
        verdict.reason = decoded.quality
    elif cal_row is None:
        verdict.reason = "air-quality model not calibrated (POST /air/calibration)"
    elif how.own and how.region != camera.region:  # another part of the view
        verdict.reason = (
            f"its own calibration was made when it measured {describe_region(how.region)}, "
            f"not {describe_region(camera.region)}: calibrate it again (POST /air/calibration)"
        )[:200]
    elif cal_row.method == "regression" and cal_row.regression and regression is None:
        verdict.reason = (
            "its calibration's regression was made on an earlier set of sky features: "
            "calibrate again (POST /air/calibration)"
        )
    elif cal_row.method == "regression" and regression and decoded.features is not None:
        verdict.calibration_id = cal_row.id
        estimated(verdict, regression, decoded.features)
    else:
        g = airquality.grade(as_core(cal_row), decoded.stats.modes)
        verdict.calibration_id = cal_row.id
        verdict.statistic, verdict.p_value, verdict.reason = g.statistic, g.p_value, g.reason
        if g.level is not None:
            verdict.level = g.level
            verdict.category = airquality.category(g.level)


def estimated(
    verdict: SkyVerdict, regression: airquality.Regression, features: NDArray[np.float64]
) -> None:
    """Grade the verdict by the regression: its estimate and interval always; its level
    unless the frame lies outside the calibration (a guess beyond what was learnt); its
    category only when sure. A doubted verdict is ``uncertain``, with the reason: its level is
    the estimate's, to be weighed with the interval, and names no category (the category is
    what is in doubt); it moves neither the camera's public level nor its history
    (``TRUSTED``)."""
    e = regression.estimate(features)
    verdict.estimate, verdict.estimate_unit = e.value, regression.unit
    verdict.estimate_low, verdict.estimate_high = e.low, e.high
    verdict.uncertain = e.uncertain is not None
    verdict.span = list(e.span) if e.span is not None else None
    verdict.reason = f"uncertain: {e.uncertain}"[:200] if e.uncertain is not None else None
    verdict.level = None if e.outside else e.level
    verdict.category = None if e.uncertain is not None else airquality.category(e.level)


REGRADE_LIMIT = 2000
"""Frames re-graded by one request at most: each is read back and decoded (~0.1 s at 1080p);
a longer history is re-graded page by page (``next_since``)."""


@dataclass(frozen=True, slots=True)
class Regraded:
    camera_id: str
    calibration_id: str | None
    since: datetime
    regraded: int
    """Frames measured again and graded by the calibration now in use."""
    missing: int
    """Frames whose bytes are gone (retention, or never stored): they keep their grade."""
    next_since: datetime | None
    """Where the next page starts when more frames remain; None when done."""


def regrade(
    session: Session,
    store: FrameStore | None,
    camera_id: str,
    since: datetime,
    *,
    max_pixels: int,
    limit: int = REGRADE_LIMIT,
) -> Regraded:
    """Measure the camera's stored frames taken since ``since`` again (its region now, the
    current sky features) and grade them by the calibration that grades it now, so its
    history speaks one calibration; then smooth its readings again. Raises no alerts: this is
    history. Each reading then names its calibration (``calibration_id``)."""
    camera = sky_camera(session, camera_id)
    _lock_camera(session, camera_id)
    info = CameraInfo.of(camera)
    how = grading(session, camera_id)
    rows = session.execute(
        with_verdicts(and_(Frame.camera_id == camera_id, Frame.captured_at >= since))
        .order_by(Frame.captured_at, Frame.received_at, Frame.id)
        .limit(limit + 1)
    ).all()
    more = len(rows) > limit
    regraded = missing = 0
    for frame, verdict in rows[:limit]:
        data = store.read(frame.stored_path) if store and frame.stored_path else None
        if data is None:
            missing += 1
            continue
        try:
            decoded = analyse(data, camera=info, max_pixels=max_pixels)
        except VantageError:  # bytes damaged in the store since: keep what it said then
            missing += 1
            continue
        for name, value in stats_columns(decoded.stats).items():
            setattr(verdict, name, value)
        verdict.roi, verdict.usable = info.region, decoded.quality is None
        verdict.details = (
            {"features": decoded.features.tolist()} if decoded.features is not None else None
        )
        grade_verdict(verdict, info, decoded, how)
        regraded += 1
    session.flush()
    last = rows[limit - 1][0].captured_at if more else None
    _smooth_again(session, camera_id, since, last)
    calibration = how.calibration.id if how.calibration is not None else None
    return Regraded(camera_id, calibration, since, regraded, missing, last)


def _smooth_again(session: Session, camera_id: str, since: datetime, last: datetime | None) -> None:
    """The smoothed level of every reading of the camera taken since ``since`` (up to the 12
    hours after ``last``, the last one re-graded, when given), from its graded readings
    (``airquality.nowcasts``)."""
    hours = timedelta(hours=airquality.NOWCAST_HOURS)
    q = _levels_of(camera_id).where(Frame.captured_at > since - hours).order_by(Frame.captured_at)
    if last is not None:
        q = q.where(Frame.captured_at <= last + hours)
    rows = session.execute(q).all()
    graded = [r for r in rows if trusted(r.level, r.uncertain)]
    later = [r for r in rows if r.captured_at >= since]
    smoothed = airquality.nowcasts(
        [r.captured_at for r in graded],
        [float(r.level) for r in graded],
        [r.captured_at for r in later],
    )
    changed = [
        {"frame_id": r.id, "smoothed_level": v}
        for r, v in zip(later, smoothed, strict=True)
        if v != r.smoothed_level
    ]
    if changed:
        session.execute(update(SkyVerdict), changed)


def _lock_camera(session: Session, camera_id: str) -> None:
    """Take the camera's row for this transaction before its readings are read (PostgreSQL):
    another process storing a frame of the same camera waits for this one's commit, and then
    reads its reading. Without it, a backlog sent to two processes at once had each smooth
    without the other's frame (stale smoothed levels, kept), and their updates of the same
    readings in opposite orders deadlocked (a 503). ``FOR NO KEY UPDATE`` does not wait for the
    key-share locks that inserting frames of the camera takes. SQLite has one writer anyway."""
    if session.get_bind().dialect.name == "postgresql":
        session.execute(
            select(Camera.id).where(Camera.id == camera_id).with_for_update(key_share=True)
        )
