"""Air quality: calibration, grading frames, smoothing, alerts, readings, isopleths."""

from __future__ import annotations

import math
import uuid
from collections.abc import Sequence
from dataclasses import dataclass
from datetime import UTC, datetime, time, timedelta, timezone
from typing import Any, Literal
from zoneinfo import ZoneInfo

import numpy as np
from numpy.typing import NDArray
from sqlalchemy import (
    ColumnElement,
    Row,
    Select,
    and_,
    func,
    literal_column,
    or_,
    select,
    update,
)
from sqlalchemy.orm import QueryableAttribute, Session, selectinload

from app.air.core import airquality, breakpoints
from app.air.models import AirAlert, AirCalibration, AirCalibrationCamera, SkyVerdict
from app.platform.db.base import time_slot
from app.platform.db.models import Camera, CameraKind, Frame
from app.platform.frames import hotelling as soiling
from app.platform.frames.camera_info import (
    CameraInfo,
    Region,
    describe_region,
    one_view,
    region_now,
    uploads_in,
)
from app.platform.frames.cameras import NEWEST_FIRST, FrameKey, after, taken_in
from app.platform.frames.ingest import analyse
from app.platform.frames.kinds import Decoded, Prepared
from app.platform.frames.storage import FrameStore
from app.platform.frames.verdicts import check_usable, stats_columns
from app.platform.http.errors import NotFound, Unprocessable, VantageError
from app.platform.memo import ById
from app.platform.policy import Policy


def calibration_for(session: Session, camera_id: str | None) -> AirCalibration | None:
    """The calibration that grades a camera's frames: the newest made for that camera, else
    the newest city-wide one (made for no camera in particular). ``None``: the city-wide one."""
    return grading(session, camera_id).calibration


@dataclass(frozen=True, slots=True)
class Grading:
    calibration: AirCalibration | None
    own: bool
    """Made for this camera (not the city-wide one)."""
    region: Region
    """Its own: the camera's region of interest when it was made."""


def grading(session: Session, camera_id: str | None) -> Grading:
    """What grades a camera's frames (``calibration_for``), and whether it is its own.

    One query (it runs for every sky frame, on the writer): the camera's own calibrations and
    the city-wide ones, its own first. For ``None`` the join's ``camera_id IS NULL`` matches no
    row, which leaves the city-wide ones.
    """
    mine = and_(
        AirCalibrationCamera.calibration_id == AirCalibration.id,
        AirCalibrationCamera.camera_id == camera_id,
    )
    row = session.execute(
        select(AirCalibration, AirCalibrationCamera.camera_id, AirCalibrationCamera.roi)
        .outerjoin(AirCalibrationCamera, mine)
        .where(or_(AirCalibrationCamera.camera_id.is_not(None), AirCalibration.city_wide))
        .order_by(
            AirCalibrationCamera.camera_id.is_(None),  # its own first (false sorts before true)
            AirCalibration.created_at.desc(),
            AirCalibration.id,
        )
        .limit(1)
    ).first()
    if row is None:
        return Grading(None, False, None)
    return Grading(row[0], row[1] is not None, row[2])


def release_camera(session: Session, camera_id: str) -> None:
    """Grade the sky camera by the city-wide calibration again: it is taken off every
    calibration made for it (which keep grading their other cameras). NotFound when it has none
    of its own."""
    sky_camera(session, camera_id)
    links = session.scalars(
        select(AirCalibrationCamera).where(AirCalibrationCamera.camera_id == camera_id)
    ).all()
    if not links:
        raise NotFound(f"sky camera {camera_id!r} has no calibration of its own")
    for link in links:
        session.delete(link)
    session.flush()


def calibrations(
    session: Session, *, camera_id: str | None, limit: int, offset: int
) -> Sequence[AirCalibration]:
    """Calibrations, newest first (only those made for ``camera_id`` when given), with the
    cameras each was made for loaded."""
    q = select(AirCalibration).options(selectinload(AirCalibration.cameras))
    if camera_id is not None:
        q = q.join(AirCalibrationCamera).where(AirCalibrationCamera.camera_id == camera_id)
    q = q.order_by(AirCalibration.created_at.desc(), AirCalibration.id)
    return session.scalars(q.limit(limit).offset(offset)).all()


def with_cameras(session: Session, row: AirCalibration) -> AirCalibration:
    """The calibration with the cameras it was made for loaded (for its ``camera_ids``)."""
    session.refresh(row, ["cameras"])
    return row


def as_core(row: AirCalibration) -> airquality.Calibration:
    clusters = tuple(
        airquality.Cluster(
            levels=tuple(c["levels"]),
            level=int(c["level"]),
            baseline=soiling.Baseline(
                n=int(c["n"]),
                mean_modes=np.asarray(c["mean_modes"], dtype=np.float64),
                covariance=np.asarray(c["covariance"], dtype=np.float64),
                significance=float(c["significance"]),
                f_critical=float(c["f_critical"]),
                condition_number=float(c["condition_number"]),
                shrinkage=float(c["shrinkage"]),
            ),
        )
        for c in row.clusters
    )
    return airquality.Calibration(clusters, tuple(row.warnings))


def fit_regression(
    features: NDArray[np.float64],
    targets: Sequence[float],
    *,
    unit: str = "level",
    groups: Sequence[str] | None = None,
    table: str = "us_epa",
) -> dict[str, Any]:
    """The ridge regression of ``targets`` (levels, or the reference in ``unit``, whose levels
    come by the breakpoint ``table``) on the sky features (``airquality.fit_regression``), as
    the calibration keeps it."""
    if len(targets) < 10 or len({airquality.level_of(t, unit, table) for t in targets}) < 3:
        raise Unprocessable("the regression needs at least 10 images of at least 3 levels")
    if features.ndim != 2 or features.shape[1] != len(airquality.SKY_FEATURES):
        raise Unprocessable(
            "some images' sky features were measured by an earlier version: re-grade their "
            "cameras first (POST /air/cameras/{id}/regrade) or upload the images",
            code="stale_features",
        )
    if not np.isfinite(features).all():
        raise Unprocessable("some images gave non-finite features")
    model, alpha = airquality.fit_regression(
        features, targets, unit=unit, groups=groups, table=table
    )
    left_out = airquality.groups_left_out(groups)
    assert model.gram_inv is not None
    return {
        "features": list(airquality.SKY_FEATURES),
        "unit": unit,
        "breakpoints": table,
        "mean": model.mean.tolist(),
        "scale": model.scale.tolist(),
        "coef": model.coef.tolist(),
        "intercept": model.intercept,
        "alpha": alpha,
        "gram_inv": model.gram_inv.tolist(),
        "n": model.n,
        "sigma": model.sigma,
        "dof": model.dof,
        "max_leverage": model.max_leverage,
        "interval": airquality.INTERVAL,
        "sigma_from": "images left out" if left_out is None else "days left out",
        "groups": left_out,
    }


_REGRESSIONS: ById[airquality.Regression | None] = ById()
"""Regressions as read, by calibration id: a calibration never changes once made."""


def as_regression(row: AirCalibration) -> airquality.Regression | None:
    """The calibration's regression; None without one, or one made on features that are no
    longer measured (its frames must be graded by a new calibration). One made before
    features were added grades by the features it was fitted on."""
    return _REGRESSIONS.get(row.id, lambda: _read_regression(row.regression))


def _read_regression(r: dict[str, Any] | None) -> airquality.Regression | None:
    if not r:
        return None
    names = list(airquality.SKY_FEATURES)
    fitted_on = r.get("features", [])
    if not fitted_on or not set(fitted_on) <= set(names):
        return None
    gram = r.get("gram_inv")
    return airquality.Regression(
        np.asarray(r["mean"]),
        np.asarray(r["scale"]),
        np.asarray(r["coef"]),
        float(r["intercept"]),
        unit=str(r.get("unit", "level")),
        gram_inv=None if gram is None else np.asarray(gram, dtype=np.float64),
        n=int(r.get("n", 0)),
        sigma=r.get("sigma"),
        dof=float(r.get("dof", 1.0)),
        max_leverage=r.get("max_leverage"),
        table=str(r.get("breakpoints", "us_epa")),  # made before the choice: the EPA's
        columns=None if fitted_on == names else tuple(names.index(n) for n in fitted_on),
    )


def calibrate(
    session: Session,
    modes: NDArray[np.float64],
    levels: Sequence[int],
    *,
    significance: float,
    shrinkage: float,
    frame_ids: list[str] | None,
    now: datetime,
    method: str = "clusters",
    features: NDArray[np.float64] | None = None,
    camera_ids: Sequence[str] = (),
    warnings: Sequence[str] = (),
    regions: Sequence[tuple[str, str, Region]] = (),
    reference: tuple[str, Sequence[float]] | None = None,
    groups: Sequence[str] | None = None,
    table: str = "us_epa",
) -> AirCalibration:
    """The level clusters (always) and, for ``method="regression"``, the regression too:
    fitted to ``reference`` (unit "pm25" or "aqi", one value per image) when given, so its
    verdicts carry an estimate in that unit, made a level by the breakpoint ``table``; else to
    the levels. ``groups``: each image's capture day, for the regression's out-of-sample
    residuals.

    ``warnings`` are kept in the model beside its own (levels pooled for want of images).
    ``regions``: (frame, camera, region) of stored frames it is made from; a camera it is made
    for must have measured its own frames among them where it measures now.

    Made for ``camera_ids`` (sky cameras), it grades those cameras' frames from now on; made for
    none, it is the city-wide calibration of every camera without one of its own.
    """
    cameras = sorted(set(camera_ids))
    sky: dict[str, Camera] = {}
    if cameras:
        sky = {
            c.id: c
            for c in session.scalars(
                select(Camera).where(Camera.id.in_(cameras), Camera.kind == CameraKind.sky)
            )
        }
        missing = [c for c in cameras if c not in sky]
        if missing:
            raise Unprocessable(
                f"applies_to: no sky camera {missing[0]!r}"
                + (f" (and {len(missing) - 1} more)" if len(missing) > 1 else ""),
                code="not_a_sky_camera",
            )
    for frame_id, camera_id, region in regions:
        now_at = region_now(sky[camera_id]) if camera_id in sky else region
        if region != now_at:
            raise Unprocessable(
                f"frame {frame_id} of camera {camera_id!r} was measured in "
                f"{describe_region(region)}, but the camera now measures "
                f"{describe_region(now_at)}: a calibration made for it from that frame would "
                "grade another part of the view; use frames taken since its roi changed",
                code="region_not_in_use",
            )
    regression = None
    if method == "regression":
        if features is None:
            raise Unprocessable("the regression needs the images' sky features")
        unit, targets = reference if reference is not None else ("level", levels)
        regression = fit_regression(features, list(targets), unit=unit, groups=groups, table=table)
    try:
        cal = airquality.calibrate(modes, levels, significance=significance, shrinkage=shrinkage)
    except soiling.BaselineError as exc:
        if regression is None:
            raise Unprocessable(f"cannot calibrate: {exc}", code="bad_calibration") from None
        # the regression grades without the clusters (they grade only a frame stored without
        # sky features): a level whose modes vary along fewer than three directions (one grey
        # sky at several exposures) refused a regression for a covariance it never uses
        cal = airquality.Calibration(
            (), (f"no T² clusters, the regression grades without them: {exc}",)
        )
    except ValueError as exc:
        raise Unprocessable(str(exc)) from None
    row = AirCalibration(
        id=str(uuid.uuid4()),
        created_at=now,
        clusters=[
            {
                "levels": list(c.levels),
                "level": c.level,
                "n": c.baseline.n,
                "mean_modes": c.baseline.mean_modes.tolist(),
                "covariance": c.baseline.covariance.tolist(),
                "significance": c.baseline.significance,
                "f_critical": c.baseline.f_critical,
                "condition_number": c.baseline.condition_number,
                "shrinkage": c.baseline.shrinkage,
            }
            for c in cal.clusters
        ],
        warnings=[*cal.warnings, *warnings],
        n_images=len(levels),
        frame_ids=frame_ids,
        method=method,
        regression=regression,
        city_wide=not cameras,
        cameras=[AirCalibrationCamera(camera_id=c, roi=region_now(sky[c])) for c in cameras],
    )
    session.add(row)
    session.flush()
    return row


@dataclass(frozen=True, slots=True)
class StoredSkies:
    modes: NDArray[np.float64]
    features: NDArray[np.float64] | None
    """None unless every frame kept them."""
    regions: list[tuple[str, str, Region]]
    """(frame, camera, the region it was measured in) of each frame."""
    days: list[str]
    """The day each frame was captured, by the sun at its camera (``solar_day``)."""


def solar_day(captured_at: datetime, lon: float | None) -> str:
    """The ISO date of ``captured_at`` by the sun at longitude ``lon`` [° east]: UTC shifted
    by lon/15 h (mean solar time), so that a day's frames, which share its weather, share a
    date; at 151° E daylight runs across UTC midnight. UTC's date without a longitude."""
    shift = timedelta(hours=(lon or 0.0) / 15.0)
    return (captured_at.astimezone(UTC) + shift).date().isoformat()


def of_frames(session: Session, frame_ids: Sequence[str]) -> StoredSkies:
    """Mode vectors, sky features and regions of stored sky frames."""
    rows = session.execute(
        select(
            SkyVerdict.frame_id,
            SkyVerdict.mode_r,
            SkyVerdict.mode_g,
            SkyVerdict.mode_b,
            SkyVerdict.details,
            SkyVerdict.camera_id,
            SkyVerdict.roi,
            SkyVerdict.usable,
            SkyVerdict.reason,
            Frame.captured_at,
            Camera.lon,
        )
        .join(Frame, Frame.id == SkyVerdict.frame_id)
        .join(Camera, Camera.id == SkyVerdict.camera_id)
        .where(SkyVerdict.frame_id.in_(frame_ids))
    ).all()
    found = {r[0]: r for r in rows}
    missing = [f for f in frame_ids if f not in found]
    if missing:
        raise Unprocessable(f"no sky frames {', '.join(missing[:10])}", missing=missing)
    check_usable([(r[0], r[8]) for r in rows if not r[7]])
    modes = np.array([found[f][1:4] for f in frame_ids], dtype=np.float64)
    feats = [(found[f][4] or {}).get("features") for f in frame_ids]
    regions = [(f, found[f][5], found[f][6]) for f in frame_ids]
    days = [solar_day(found[f][9], found[f][10]) for f in frame_ids]
    if any(x is None for x in feats) or len({len(x or ()) for x in feats}) != 1:
        return StoredSkies(modes, None, regions, days)
    return StoredSkies(modes, np.array(feats, dtype=np.float64), regions, days)


TRUSTED = and_(SkyVerdict.level.is_not(None), SkyVerdict.uncertain.is_(False))
"""A reading whose level counts: graded, and not doubted. An uncertain reading's level is
shown with it but moves neither the camera's public level, its history nor the map."""


def trusted(level: int | None, uncertain: bool | None) -> bool:
    """``TRUSTED`` for a row already read."""
    return level is not None and not uncertain


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


def classify_frame(session: Session, prepared: Prepared, policy: Policy) -> SkyVerdict:
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
                _public_level_changed(session, camera.id, newest.id, public, frame.received_at)
            )
    earlier = (  # newest first
        float(r.smoothed_level)
        for r in around
        if r.captured_at <= frame.captured_at
        and trusted(r.level, r.uncertain)
        and r.smoothed_level is not None
    )
    if smoothed is None:
        return verdict
    kind, alert = "raised", airquality.alert_category(smoothed, earlier)
    if alert is None and smoothed >= airquality.CLEAR_LEVEL and _in_episode(session, frame):
        kind, alert = "cleared", airquality.category(smoothed)
    if (
        alert is not None
        # the air of hours ago, seen after newer readings: history, not an alert
        and session.execute(graded.where(Frame.captured_at > frame.captured_at).limit(1)).first()
        is None
    ):
        session.add(_alert(camera.id, frame.id, frame.received_at, kind, smoothed, alert))
    return verdict


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
        _with_verdicts(and_(Frame.camera_id == camera_id, Frame.captured_at >= since))
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


def _alert(
    camera_id: str, frame_id: str, at: datetime, kind: str, level: float, category: str
) -> AirAlert:
    return AirAlert(
        id=str(uuid.uuid4()),
        camera_id=camera_id,
        frame_id=frame_id,
        created_at=at,
        kind=kind,
        smoothed_level=level,
        category=category,
        delivered=False,
        attempts=0,
    )


def _public_level_changed(
    session: Session, camera_id: str, reading_id: str, level: float, at: datetime
) -> list[AirAlert]:
    """The alert called for when a camera's public level (its newest reading's smoothed level)
    becomes ``level`` through a reading taken before it that arrived after it (a backlog sent
    newest first): raised when the level is in an alert category that no open episode has
    raised yet (as bad or worse), cleared when it is back to ``CLEAR_LEVEL`` in an open one.
    The late reading's own hours are history and raise nothing; without this, a backlog sent
    newest first whose newest frame alone read Fair, the hours before it Poor, left the camera
    public Poor with no alert ever raised."""
    name = airquality.category(level)
    last = _last_alert(session, camera_id)
    episode = last if last is not None and last.kind == "raised" else None  # still open
    severity = airquality.ALERT_CATEGORIES.index
    if name in airquality.ALERT_CATEGORIES:
        if episode is not None and severity(episode.category) >= severity(name):
            return []
        kind = "raised"
    elif episode is not None and level >= airquality.CLEAR_LEVEL:
        kind = "cleared"
    else:
        return []
    return [_alert(camera_id, reading_id, at, kind, level, name)]


def _last_alert(session: Session, camera_id: str) -> Row[str, str, datetime] | None:
    """The camera's last alert: its kind, category and when its frame was taken."""
    return session.execute(
        select(AirAlert.kind, AirAlert.category, Frame.captured_at)
        .join(Frame, Frame.id == AirAlert.frame_id)
        .where(AirAlert.camera_id == camera_id)
        .order_by(AirAlert.created_at.desc(), AirAlert.id.desc())
        .limit(1)
    ).first()


def _in_episode(session: Session, frame: Frame) -> bool:
    """Whether the camera's last alert was raised and no reading at ``CLEAR_LEVEL`` has been
    taken since (before ``frame``): an episode of bad air not yet cleared. (Without the
    second test, alerts raised before cleared ones existed would each be cleared by the next
    clean frame, months after their air had cleared.)"""
    last = _last_alert(session, frame.camera_id)
    if last is None or last.kind != "raised":
        return False
    clear_since = session.scalar(
        select(Frame.id)
        .join(SkyVerdict, SkyVerdict.frame_id == Frame.id)
        .where(
            Frame.camera_id == frame.camera_id,
            Frame.captured_at > last.captured_at,
            Frame.captured_at < frame.captured_at,
            SkyVerdict.smoothed_level >= airquality.CLEAR_LEVEL,
        )
        .limit(1)
    )
    return clear_since is None


def upload_region(
    session: Session, camera_id: str | None, applies_to: Sequence[str]
) -> tuple[CameraInfo, list[str]]:
    """How uploaded calibration images are measured (a camera's region, or the whole image),
    and warnings naming the cameras the calibration grades that measure another region.

    A calibration's features must be measured where its cameras measure their frames: a
    calibration from whole photos of street and sky grades a camera that sees only its sky
    region as far hazier than it is. The region is the named camera's (``camera_id``); else,
    when every camera in ``applies_to`` measures the same region, theirs (the uploads are their
    frames); else the whole image, each upload being taken to be a sky image.
    """
    source = sky_camera(session, camera_id) if camera_id is not None else None
    graded = session.scalars(graded_cameras(applies_to).order_by(Camera.id)).all()
    if source is None and applies_to:
        source = one_view(graded)
    region = source.roi if source is not None else None
    differ = [c.id for c in graded if c.roi != region]
    measured = uploads_in(source, CameraKind.sky)
    if not differ:
        return measured, []
    where = (
        f"camera {source.id!r}'s region"
        if source is not None and region is not None
        else "the whole image"
    )
    named = ", ".join(differ[:5]) + (f" and {len(differ) - 5} more" if len(differ) > 5 else "")
    return measured, [
        f"the uploads were measured over {where}, but the cameras it grades {named} measure "
        "another region: unless the uploads are just what those regions see, calibrate with "
        "camera_id naming a camera whose full frames they are, or each group of cameras with "
        "one region with applies_to"
    ]


def graded_cameras(applies_to: Sequence[str]) -> Select[Camera]:
    """The sky cameras in service a calibration grades: ``applies_to``, or, for a city-wide
    one, every one."""
    query = select(Camera).where(Camera.kind == CameraKind.sky, Camera.retired_at.is_(None))
    return query.where(Camera.id.in_(sorted(set(applies_to)))) if applies_to else query


def breakpoints_of_place(session: Session, applies_to: Sequence[str]) -> tuple[str, str]:
    """The breakpoint table of the cameras a calibration grades (``graded_cameras``), and
    why: the European index where all those with a position stand in Europe, else the EPA's
    (``breakpoints.table_for_places``)."""
    places = [(c.lat, c.lon) for c in session.scalars(graded_cameras(applies_to))]
    table = breakpoints.table_for_places(places)
    if all(lat is None or lon is None for lat, lon in places):
        return table, "no camera it grades has a position"
    if table == "eu_eaqi":
        return table, "the cameras it grades stand in Europe"
    return table, "a camera it grades stands outside Europe"


def sky_cameras(session: Session, camera_ids: Sequence[str] | None) -> None:
    """Refuse (404) ids that name no sky camera, all of them in one answer: a misspelt id is
    an error, not a camera with no readings."""
    if not camera_ids:
        return
    known = set(
        session.scalars(
            select(Camera.id).where(Camera.id.in_(camera_ids), Camera.kind == CameraKind.sky)
        )
    )
    unknown = sorted(set(camera_ids) - known)
    if unknown:
        raise NotFound(f"no sky camera {', '.join(map(repr, unknown))}", unknown=unknown)


def sky_camera(session: Session, camera_id: str) -> Camera:
    camera = session.get(Camera, camera_id)
    if camera is None or camera.kind != CameraKind.sky:
        raise NotFound(f"no sky camera {camera_id!r}")
    return camera


@dataclass(frozen=True, slots=True)
class Place:
    """A sky camera as the public sees it: its id, name and position."""

    camera_id: str
    name: str | None
    lat: float | None
    lon: float | None


Reading = tuple[Frame, SkyVerdict]


def latest(session: Session, camera_id: str) -> tuple[Place, Reading | None]:
    """The sky camera (404 when there is none) and its latest reading, if any."""
    camera = sky_camera(session, camera_id)
    place = Place(camera.id, camera.name, camera.lat, camera.lon)
    row = session.execute(
        _with_verdicts(Frame.id == _newest_reading(camera_id).scalar_subquery())
    ).first()
    return place, ((row[0], row[1]) if row else None)


def latest_of_every(
    session: Session, *, limit: int, offset: int, camera_ids: Sequence[str] | None = None
) -> list[tuple[Place, Reading | None]]:
    """Each sky camera in service (by id, a page of them), or each of ``camera_ids`` (retired
    ones too: they were asked for), with its latest reading, if any: one statement, an index
    lookup per camera for its newest graded frame; then those frames. 404 for ids in
    ``camera_ids`` that name no sky camera."""
    sky_cameras(session, camera_ids)
    newest = _newest_reading(Camera.id).correlate(Camera).scalar_subquery()
    which = Camera.retired_at.is_(None) if camera_ids is None else Camera.id.in_(camera_ids)
    page = session.execute(
        select(Camera.id, Camera.name, Camera.lat, Camera.lon, newest)
        .where(Camera.kind == CameraKind.sky, which)
        .order_by(Camera.id)
        .limit(limit)
        .offset(offset)
    ).all()
    wanted = [row[-1] for row in page if row[-1] is not None]
    found = {f.camera_id: (f, v) for f, v in session.execute(_with_verdicts(Frame.id.in_(wanted)))}
    return [(Place(cid, name, lat, lon), found.get(cid)) for cid, name, lat, lon, _ in page]


def _newest_reading(camera_id: str | QueryableAttribute[str]) -> Select[str]:
    """The id of the camera's newest graded frame (the (camera_id, captured_at) index)."""
    return (
        select(Frame.id)
        .join(SkyVerdict, SkyVerdict.frame_id == Frame.id)
        .where(Frame.camera_id == camera_id)
        .order_by(Frame.captured_at.desc(), Frame.received_at.desc())
        .limit(1)
    )


def _with_verdicts(which: ColumnElement[bool]) -> Select[Frame, SkyVerdict]:
    return select(Frame, SkyVerdict).join(SkyVerdict, SkyVerdict.frame_id == Frame.id).where(which)


def readings(
    session: Session,
    *,
    camera_ids: Sequence[str] | None,
    since: datetime | None,
    until: datetime | None,
    limit: int,
    offset: int,
    cursor: FrameKey | None = None,
) -> Sequence[Any]:
    """Sky readings taken in [since, until), newest first (after ``cursor``); 404 for ids in
    ``camera_ids`` that name no sky camera."""
    sky_cameras(session, camera_ids)
    q = select(
        Frame.camera_id,
        Frame.id,
        Frame.captured_at,
        SkyVerdict.level,
        SkyVerdict.category,
        SkyVerdict.smoothed_level,
        SkyVerdict.reason,
        SkyVerdict.uncertain,
        SkyVerdict.estimate,
        SkyVerdict.estimate_low,
        SkyVerdict.estimate_high,
        SkyVerdict.estimate_unit,
        SkyVerdict.calibration_id,
    ).join(SkyVerdict, SkyVerdict.frame_id == Frame.id)
    q = q.where(*taken_in(camera_ids, since, until), *after(cursor))
    return session.execute(q.order_by(*NEWEST_FIRST).limit(limit).offset(offset)).all()


def aggregate(
    session: Session,
    *,
    camera_ids: Sequence[str] | None,
    since: datetime | None,
    until: datetime | None,
    bucket: Literal["hourly", "daily"],
    tz: ZoneInfo,
) -> list[dict[str, Any]]:
    """Hourly or daily means of the graded readings in the time zone ``tz``, newest first.

    All readings in the range count, summed by the database by camera and local hour or day
    (count, sum, min, max): Python sees one row per camera a bucket (6,000 for a month of 200
    cameras by day, from 1.7 million readings). The range is cut where ``tz`` changes its
    offset from UTC; within each piece a local hour or day is a fixed stretch of UTC. A local
    hour that occurs twice (clocks put back) is two buckets, told apart by their UTC offset; a
    local day is 23 to 25 hours long around a change of clocks (its pieces are added up). 404
    for ids in ``camera_ids`` that name no sky camera."""
    sky_cameras(session, camera_ids)
    length = 3600 if bucket == "hourly" else 86400
    first, last = session.execute(
        select(func.min(Frame.captured_at), func.max(Frame.captured_at)).where(
            *taken_in(camera_ids, since, until)
        )
    ).one()
    if first is None:
        return []
    sums: dict[tuple[str, datetime, datetime], list[float]] = {}
    for begin, end, offset in _offset_spans(tz, first, last):
        shift = int(offset.total_seconds())
        key = time_slot(
            Frame.captured_at, literal_column(str(length)), literal_column(str(shift))
        ).label("key")
        q = (
            select(
                Frame.camera_id,
                key,
                func.count(SkyVerdict.level),
                func.sum(SkyVerdict.level),
                func.min(SkyVerdict.level),
                func.max(SkyVerdict.level),
            )
            .join(SkyVerdict, SkyVerdict.frame_id == Frame.id)
            .where(TRUSTED, *taken_in(camera_ids, since, until))
            .group_by(key, Frame.camera_id)  # this order: SQLite scans the readings, not the
            # (camera, time) index with a lookup per row (3.4 against 11 s for 1.7 M readings)
        )
        if begin is not None:
            q = q.where(Frame.captured_at >= begin)
        if end is not None:
            q = q.where(Frame.captured_at < end)
        for row in session.execute(q):
            cam, index, n = row[0], int(row[1]), int(row[2])
            total, lo, hi = (float(v or 0) for v in row[3:])  # never NULL: ungraded left out
            # the bucket's start on the local clock of this piece
            wall = datetime.fromtimestamp(index * length, UTC).replace(tzinfo=None)
            acc = sums.setdefault(
                (cam, *_bucket(wall, offset, bucket, tz)), [0.0, 0.0, math.inf, -math.inf]
            )
            acc[0] += n
            acc[1] += total
            acc[2] = min(acc[2], lo)
            acc[3] = max(acc[3], hi)
    result = [
        {
            "camera_id": cam,
            "start": start,
            "end": end,
            "n": int(n),
            "mean_level": total / n,
            "min_level": lo,
            "max_level": hi,
            "category": airquality.category(total / n),
        }
        for (cam, start, end), (n, total, lo, hi) in sums.items()
    ]
    return sorted(result, key=lambda d: (d["start"], d["camera_id"]), reverse=True)


def _offset_spans(
    tz: ZoneInfo, first: datetime, last: datetime
) -> list[tuple[datetime | None, datetime | None, timedelta]]:
    """[begin, end) pieces covering ``first``..``last`` in each of which ``tz`` keeps one UTC
    offset (the first piece open before, the last after); to the second, found by stepping
    an hour at a time and halving the hour where the offset changed."""

    def offset(epoch: int) -> timedelta:
        return datetime.fromtimestamp(epoch, tz).utcoffset() or timedelta(0)

    spans: list[tuple[datetime | None, datetime | None, timedelta]] = []
    begin: datetime | None = None
    t = math.floor(first.timestamp())
    stop = math.ceil(last.timestamp())
    current = offset(t)
    while t < stop:
        nxt = min(t + 3600, stop)
        if offset(nxt) != current:
            a, b = t, nxt  # the offset at a is current's, at b not: halve to one second
            while b - a > 1:
                mid = (a + b) // 2
                a, b = (mid, b) if offset(mid) == current else (a, mid)
            change = datetime.fromtimestamp(b, UTC)
            spans.append((begin, change, current))
            begin, current = change, offset(b)
        t = nxt
    spans.append((begin, None, current))
    return spans


def _bucket(
    wall: datetime, offset: timedelta, bucket: str, tz: ZoneInfo
) -> tuple[datetime, datetime]:
    """The local hour or day (start, end) that begins at the naive local time ``wall`` of a
    stretch of ``tz`` at UTC offset ``offset``."""
    if bucket == "hourly":
        # the hour's own offset: the repeated hour of an autumn night is two hours
        start = wall.replace(tzinfo=timezone(offset))
        return start, start + timedelta(hours=1)
    day = wall.date()
    start = datetime.combine(day, time(), tzinfo=tz)
    end = datetime.combine(day + timedelta(days=1), time(), tzinfo=tz)
    return _fixed(start), _fixed(end)


def _fixed(t: datetime) -> datetime:
    """The same instant with its offset as a fixed zone (compares and sorts by the instant)."""
    return t.astimezone(timezone(t.utcoffset() or timedelta(0)))


def alerts(
    session: Session,
    *,
    camera_ids: Sequence[str] | None,
    limit: int,
    offset: int,
    since: datetime | None = None,
    until: datetime | None = None,
    kind: str | None = None,
) -> Sequence[AirAlert]:
    """Alerts newest first, made in [``since``, ``until``); only ``kind`` ones when given; 404
    for ids in ``camera_ids`` that name no sky camera."""
    sky_cameras(session, camera_ids)
    q = select(AirAlert)
    if kind is not None:
        q = q.where(AirAlert.kind == kind)
    if camera_ids is not None:
        q = q.where(AirAlert.camera_id.in_(camera_ids))
    if since is not None:
        q = q.where(AirAlert.created_at >= since)
    if until is not None:
        q = q.where(AirAlert.created_at < until)
    return session.scalars(
        q.order_by(AirAlert.created_at.desc(), AirAlert.id).limit(limit).offset(offset)
    ).all()


@dataclass(frozen=True, slots=True)
class Station:
    camera_id: str
    lon: float
    lat: float
    level: float
    captured_at: datetime
    name: str | None = None


def unplaced(session: Session, *, since: datetime, until: datetime) -> list[str]:
    """Sky cameras in service at ``until`` with a level taken in [``since``, ``until``] but no
    place (no ``lat``/``lon``): graded, yet not on the map."""
    graded = (
        select(Frame.camera_id)
        .join(SkyVerdict, SkyVerdict.frame_id == Frame.id)
        .where(
            Frame.camera_id == Camera.id,
            Frame.captured_at >= since,
            Frame.captured_at <= until,
            TRUSTED,
        )
    )
    return list(
        session.scalars(
            select(Camera.id)
            .where(
                Camera.kind == CameraKind.sky,
                or_(Camera.lat.is_(None), Camera.lon.is_(None)),
                or_(Camera.retired_at.is_(None), Camera.retired_at > until),
                graded.exists(),
            )
            .order_by(Camera.id)
        )
    )


def stations(session: Session, *, since: datetime, until: datetime) -> list[Station]:
    """Each located sky camera in service at ``until``: the smoothed (else graded) level of its
    latest reading taken in [``since``, ``until``] that has either (as smoothed when it was
    taken).

    A night frame has no grade but keeps the camera's smoothed level while NowCast has a
    graded reading in the 3 hours before it: the camera's public level, which /latest and
    the alerts give. Taking graded readings alone, the map lost a camera an hour (its window)
    after dusk while /latest still gave its level."""
    has_level = or_(TRUSTED, SkyVerdict.smoothed_level.is_not(None))
    newest = (
        select(Frame.camera_id, func.max(Frame.captured_at).label("t"))
        .join(SkyVerdict, SkyVerdict.frame_id == Frame.id)
        .where(Frame.captured_at >= since, Frame.captured_at <= until, has_level)
        .group_by(Frame.camera_id)
        .subquery()
    )
    rows = session.execute(
        select(
            Camera.id,
            Camera.name,
            Camera.lon,
            Camera.lat,
            SkyVerdict.smoothed_level,
            SkyVerdict.level,
            Frame.captured_at,
        )
        .join(Frame, Frame.camera_id == Camera.id)
        .join(SkyVerdict, SkyVerdict.frame_id == Frame.id)
        .join(newest, (newest.c.camera_id == Frame.camera_id) & (newest.c.t == Frame.captured_at))
        .where(
            Camera.lat.is_not(None),
            Camera.lon.is_not(None),
            # a camera taken down no longer paints the map, but did before it was
            or_(Camera.retired_at.is_(None), Camera.retired_at > until),
            has_level,
        )
    ).all()
    seen: dict[str, Station] = {}
    for cid, name, lon, lat, smooth, level, t in rows:
        value = smooth if smooth is not None else level
        if lon is None or lat is None or value is None:
            continue
        seen[cid] = Station(cid, float(lon), float(lat), float(value), t, name)
    return sorted(seen.values(), key=lambda s: s.camera_id)
