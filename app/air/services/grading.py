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

from app.air.core import airquality, public
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


def _levels_of(camera_id: str) -> Select[Any]:
    """A camera's readings as smoothing reads them: id, capture time, level, estimate with
    its range and unit, and what smoothing made of them."""
    columns: tuple[Any, ...] = (
        Frame.id,
        Frame.captured_at,
        SkyVerdict.level,
        SkyVerdict.estimate,
        SkyVerdict.estimate_low,
        SkyVerdict.estimate_high,
        SkyVerdict.estimate_unit,
        *SMOOTHED,
    )
    return (
        select(*columns)
        .join(SkyVerdict, SkyVerdict.frame_id == Frame.id)
        .where(Frame.camera_id == camera_id)
    )


SMOOTHED = (
    SkyVerdict.smoothed_level,
    SkyVerdict.smoothed_estimate,
    SkyVerdict.smoothed_low,
    SkyVerdict.smoothed_high,
    SkyVerdict.smoothed_probability,
    SkyVerdict.poor_probability,
)
"""What smoothing writes on a reading (``Smoothed.columns``)."""


@dataclass(frozen=True, slots=True)
class Held:
    """A reading as smoothing reads it (the columns of ``_levels_of``)."""

    captured_at: datetime
    level: int | None
    estimate: float | None = None
    estimate_low: float | None = None
    estimate_high: float | None = None
    estimate_unit: str | None = None


@dataclass(frozen=True, slots=True)
class Smoothed:
    """A camera's public reading after a frame: the smoothed level, and, graded by a
    regression, the smoothed estimate, its range, its category's probability and that of
    Poor or worse (``public.smooth``)."""

    level: float | None
    estimate: float | None = None
    low: float | None = None
    high: float | None = None
    probability: float | None = None
    poor: float | None = None

    def columns(self) -> dict[str, float | None]:
        return {
            "smoothed_level": self.level,
            "smoothed_estimate": self.estimate,
            "smoothed_low": self.low,
            "smoothed_high": self.high,
            "smoothed_probability": self.probability,
            "poor_probability": self.poor,
        }

    @classmethod
    def of(cls, row: Any) -> Smoothed:
        return cls(*(getattr(row, c.key) for c in SMOOTHED))


def smooth(
    rows: Sequence[Any], ats: Sequence[datetime], model: airquality.Regression | None
) -> list[Smoothed]:
    """The camera's public reading at each of ``ats`` from its graded readings ``rows``
    (``Held``-like): by ``model`` (the regression that grades the camera now) the readings'
    estimates in its unit smoothed as distributions (``public.smooth``); graded by clusters,
    the NowCast of their levels (``airquality.nowcasts``)."""
    graded = [r for r in rows if trusted(r.level)]
    if model is None or model.sigma is None:
        levels = airquality.nowcasts(
            [r.captured_at for r in graded], [float(r.level) for r in graded], ats
        )
        return [Smoothed(v) for v in levels]
    shape = public.Shape.of(model)
    reads = [
        public.Read(r.captured_at, p.loc, p.scale)
        for r in graded
        if r.estimate_unit == model.unit
        and r.estimate is not None
        and r.estimate_low is not None
        and r.estimate_high is not None
        for p in (public.predictive_of(r.estimate, r.estimate_low, r.estimate_high, shape),)
    ]
    out = []
    for at in ats:
        p = public.smooth(reads, at, shape)
        if p is None:
            out.append(Smoothed(None))
            continue
        r = public.public(p)
        out.append(Smoothed(float(r.level), r.value, r.low, r.high, r.probability, r.poor))
    return out


def _model(how: Grading) -> airquality.Regression | None:
    """The regression that grades by ``how``, if any (what smoothing weighs by)."""
    row = how.calibration
    if row is None or row.method != "regression":
        return None
    return as_regression(row)


def classify_frame(session: Session, prepared: Prepared, timing: Timing) -> SkyVerdict:
    """Grade a sky frame, smooth the camera's reading, and raise an alert when it turns Poor
    (or clear the camera's open one when it is clear again)."""
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
    how = grading(session, camera.id)
    grade_verdict(verdict, camera, decoded, how)
    _lock_camera(session, camera.id)
    # the camera's readings of the 12 hours before this frame and the 12 after: those up to
    # its capture smooth it (a frame uploaded late, a backlog, is smoothed with the hours
    # before it was taken, not with the readings taken since); those after it, smoothed
    # before it arrived, are smoothed again with it
    # (an ungraded reading has a smoothed reading too: the camera's, from the readings before)
    readings = _levels_of(camera.id)
    hours = timedelta(hours=airquality.NOWCAST_HOURS)
    around = session.execute(
        readings.where(
            Frame.captured_at > frame.captured_at - hours,
            Frame.captured_at < frame.captured_at + hours,
        ).order_by(Frame.captured_at.desc(), Frame.received_at.desc())
    ).all()
    held: list[Any] = list(around)
    later = []
    if trusted(verdict.level):
        later = [r for r in around if r.captured_at >= frame.captured_at]
        held.append(
            Held(
                frame.captured_at,
                verdict.level,
                verdict.estimate,
                verdict.estimate_low,
                verdict.estimate_high,
                verdict.estimate_unit,
            )
        )
    model = _model(how)
    now, *again = smooth(
        [r for r in held if r.captured_at <= frame.captured_at + hours],
        [frame.captured_at, *(r.captured_at for r in later)],
        model,
    )
    for name, value in now.columns().items():
        setattr(verdict, name, value)
    _smooth_later(session, camera.id, frame, later, again, live=not prepared.backfill)
    if now.level is not None and not prepared.backfill:  # an archive raises nothing live
        _alert_if_called_for(session, frame, now, around, readings.where(TRUSTED))
    return verdict


def _changed(a: Smoothed, b: Smoothed) -> bool:
    """Whether two smoothed readings differ (beyond float noise)."""
    pairs = zip(a.columns().values(), b.columns().values(), strict=True)
    return any(
        x != y if x is None or y is None else not math.isclose(x, y, rel_tol=1e-12)
        for x, y in pairs
    )


def _smooth_later(
    session: Session,
    camera_id: str,
    frame: Frame,
    later: Sequence[Any],
    again: list[Smoothed],
    *,
    live: bool,
) -> None:
    """Write the readings taken after a late frame smoothed again with it (``later``, newest
    first, and ``again``), and, ``live`` (not an archive's frame), the alert the camera's
    public reading calls for when the newest of them is the camera's newest
    (``public_level_changed``)."""
    changed = [(r, s) for r, s in zip(later, again, strict=True) if _changed(s, Smoothed.of(r))]
    if not changed:
        return
    session.execute(update(SkyVerdict), [{"frame_id": r.id, **s.columns()} for r, s in changed])
    newest, public_now = changed[0]
    hours = timedelta(hours=airquality.NOWCAST_HOURS)
    if (
        live
        and newest.id == later[0].id
        and public_now.level is not None
        # the camera's newest reading: none after the 12 hours this frame smooths
        and session.execute(
            _levels_of(camera_id).where(Frame.captured_at >= frame.captured_at + hours).limit(1)
        ).first()
        is None
    ):
        session.add_all(
            public_level_changed(
                session,
                camera_id,
                newest.id,
                public_now.level,
                frame.received_at,
                poor=public_now.poor,
            )
        )


def _alert_if_called_for(
    session: Session,
    frame: Frame,
    now: Smoothed,
    around: Sequence[Any],
    graded: Select[Any],
) -> None:
    """Raise an alert when the frame's smoothed reading turns Poor or worse, or clear the
    camera's open one when it is clear again: by the smoothed probability of Poor or worse
    when a regression grades it (``public.alert_kind``), else by the smoothed level
    (``airquality.alert_category``, ``CLEAR_LEVEL``); neither for a frame older than the
    camera's newest graded reading (history, not an alert)."""
    assert now.level is not None
    before = [
        r
        for r in around  # newest first
        if r.captured_at <= frame.captured_at and trusted(r.level) and r.smoothed_level is not None
    ]
    if now.poor is not None:
        kind = public.alert_kind(
            now.poor,
            (r.poor_probability for r in before if r.poor_probability is not None),
            in_episode(session, frame),
        )
        alert = None
        if kind is not None:
            named = airquality.category(now.level)
            worse = named if named in airquality.ALERT_CATEGORIES else "Poor"
            alert = worse if kind == "raised" else named
    else:
        kind, alert = (
            "raised",
            airquality.alert_category(now.level, (float(r.smoothed_level) for r in before)),
        )
        if alert is None and now.level >= airquality.CLEAR_LEVEL and in_episode(session, frame):
            kind, alert = "cleared", airquality.category(now.level)
    if (
        alert is not None
        and kind is not None
        and session.execute(graded.where(Frame.captured_at > frame.captured_at).limit(1)).first()
        is None
    ):
        session.add(
            alert_row(
                frame.camera_id,
                frame.id,
                frame.received_at,
                kind,
                now.level,
                alert,
                probability=now.poor,
            )
        )


def grade_verdict(verdict: SkyVerdict, camera: CameraInfo, decoded: Decoded, how: Grading) -> None:
    """Grade a sky verdict by what grades its camera (``grading``): the regression on the
    frame's features, else the T² clusters on its modes; a reason instead of a level when
    the frame is unusable, uncalibrated, measured elsewhere than its calibration, or lies
    outside it."""
    cal_row = how.calibration
    regression = as_regression(cal_row) if cal_row is not None else None
    verdict.level = verdict.category = verdict.calibration_id = verdict.reason = None
    verdict.statistic = verdict.p_value = verdict.probability = None
    verdict.estimate = verdict.estimate_low = verdict.estimate_high = None
    verdict.estimate_unit, verdict.uncertain, verdict.span = None, False, None
    if decoded.quality is not None:
        verdict.reason = decoded.quality
    elif cal_row is None:
        verdict.reason = NOT_CALIBRATED
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


NOT_CALIBRATED = "air-quality model not calibrated (POST /air/calibration)"
"""The reason of a frame no calibration grades (the public screen says "not measured
yet")."""


def estimated(
    verdict: SkyVerdict, regression: airquality.Regression, features: NDArray[np.float64]
) -> None:
    """Grade the verdict by the regression: its estimate and interval always; inside the
    calibration, the most probable category under the predictive distribution, its
    probability and level (``public.public``), ``uncertain`` when that probability is below
    ``public.SURE`` (information: the reading counts). Outside the calibration (a guess
    beyond what was learnt): no level, no category, uncertain."""
    e = regression.estimate(features)
    verdict.estimate, verdict.estimate_unit = e.value, regression.unit
    verdict.estimate_low, verdict.estimate_high = e.low, e.high
    verdict.span = list(e.span) if e.span is not None else None
    if e.outside:
        verdict.uncertain, verdict.level = True, None
        verdict.reason = f"uncertain: {e.uncertain}"[:200]
        return
    if e.scale is None:  # a model kept without its interval: the estimate's level alone
        verdict.level, verdict.category = e.level, airquality.category(e.level)
        return
    r = public.public(
        public.Predictive(e.loc, e.scale, regression.dof, regression.unit, regression.table)
    )
    verdict.level, verdict.category, verdict.probability = r.level, r.category, r.probability
    verdict.uncertain = r.uncertain
    if r.uncertain:
        verdict.reason = f"uncertain: likely {r.category}, probability {r.probability:.2f}"
        if e.span is not None:
            verdict.reason += f"; {e.uncertain}"
        verdict.reason = verdict.reason[:200]


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
    _smooth_again(session, camera_id, since, last, how)
    calibration = how.calibration.id if how.calibration is not None else None
    return Regraded(camera_id, calibration, since, regraded, missing, last)


def _smooth_again(
    session: Session, camera_id: str, since: datetime, last: datetime | None, how: Grading
) -> None:
    """The smoothed reading of every reading of the camera taken since ``since`` (up to the
    12 hours after ``last``, the last one re-graded, when given), from its graded readings
    (``smooth``)."""
    hours = timedelta(hours=airquality.NOWCAST_HOURS)
    q = _levels_of(camera_id).where(Frame.captured_at > since - hours).order_by(Frame.captured_at)
    if last is not None:
        q = q.where(Frame.captured_at <= last + hours)
    rows = session.execute(q).all()
    later = [r for r in rows if r.captured_at >= since]
    smoothed = smooth(rows, [r.captured_at for r in later], _model(how))
    changed = [
        {"frame_id": r.id, **s.columns()}
        for r, s in zip(later, smoothed, strict=True)
        if _changed(s, Smoothed.of(r))
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
