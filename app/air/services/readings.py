"""A sky camera's readings as the public reads them: the latest, the history, hourly and
daily means, the sky picture."""

from __future__ import annotations

import math
from collections.abc import Sequence
from datetime import UTC, datetime, time, timedelta, timezone
from typing import Any, Literal
from zoneinfo import ZoneInfo

import numpy as np
from sqlalchemy import (
    Select,
    func,
    literal_column,
    select,
)
from sqlalchemy.orm import QueryableAttribute, Session

from app.air.core import airquality, public
from app.air.models import SkyVerdict
from app.air.schemas import (
    AirLatest,
    AirReading,
)
from app.air.services.cameras import TRUSTED, Place, Reading, sky_camera, sky_cameras, with_verdicts
from app.air.services.grading import NOT_CALIBRATED
from app.platform.db.base import time_slot
from app.platform.db.models import Camera, CameraKind, Frame
from app.platform.frames import retention
from app.platform.frames.cameras import NEWEST_FIRST, FrameKey, after, taken_in
from app.platform.http.errors import Unprocessable
from app.platform.schemas import SkyEstimate
from app.platform.settings import Settings


def kept_days_of(settings: Settings) -> float:
    """How far back the service keeps readings [d] (``retention.kept_days``)."""
    return retention.kept_days(settings.frame_retention_days, settings.history_retention_days)


def check_moment(at: datetime | None, now: datetime, kept_days: float) -> datetime:
    """The moment a public reading is asked of (``?at=``): now by default; 422 ``bad_time``
    for one in the future or before the history kept (``kept_days``)."""
    if at is None:
        return now
    if at > now:
        raise Unprocessable(f"at {at.isoformat()} lies in the future", code="bad_time")
    if at < now - timedelta(days=kept_days):
        raise Unprocessable(
            f"at {at.isoformat()} is more than {kept_days:g} days ago, before the history "
            "this service keeps",
            code="bad_time",
        )
    return at


def latest_of(
    session: Session, camera_id: str, at: datetime | None = None
) -> tuple[Place, Reading | None]:
    """The sky camera (404 when there is none) and its latest reading (taken at or before
    ``at``, when given), if any."""
    camera = sky_camera(session, camera_id)
    place = Place(camera.id, camera.name, camera.lat, camera.lon)
    row = session.execute(
        with_verdicts(Frame.id == _newest_reading(camera_id, at).scalar_subquery())
    ).first()
    return place, ((row[0], row[1]) if row else None)


def latest_of_every(
    session: Session,
    *,
    limit: int,
    offset: int,
    camera_ids: Sequence[str] | None = None,
    at: datetime | None = None,
) -> list[tuple[Place, Reading | None]]:
    """Each sky camera in service (by id, a page of them), or each of ``camera_ids`` (retired
    ones too: they were asked for), with its latest reading, if any: one statement, an index
    lookup per camera for its newest graded frame; then those frames. 404 for ids in
    ``camera_ids`` that name no sky camera."""
    sky_cameras(session, camera_ids)
    newest = _newest_reading(Camera.id, at).correlate(Camera).scalar_subquery()
    which = Camera.retired_at.is_(None) if camera_ids is None else Camera.id.in_(camera_ids)
    page = session.execute(
        select(Camera.id, Camera.name, Camera.lat, Camera.lon, newest)
        .where(Camera.kind == CameraKind.sky, which)
        .order_by(Camera.id)
        .limit(limit)
        .offset(offset)
    ).all()
    wanted = [row[-1] for row in page if row[-1] is not None]
    found = {f.camera_id: (f, v) for f, v in session.execute(with_verdicts(Frame.id.in_(wanted)))}
    return [(Place(cid, name, lat, lon), found.get(cid)) for cid, name, lat, lon, _ in page]


def _newest_reading(
    camera_id: str | QueryableAttribute[str], at: datetime | None = None
) -> Select[str]:
    """The id of the camera's newest graded frame, taken at or before ``at`` when given (the
    (camera_id, captured_at) index)."""
    q = select(Frame.id).join(SkyVerdict, SkyVerdict.frame_id == Frame.id)
    q = q.where(Frame.camera_id == camera_id)
    if at is not None:
        q = q.where(Frame.captured_at <= at)
    return q.order_by(Frame.captured_at.desc(), Frame.received_at.desc()).limit(1)


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
        SkyVerdict.probability,
        SkyVerdict.smoothed_estimate,
        SkyVerdict.smoothed_low,
        SkyVerdict.smoothed_high,
        SkyVerdict.smoothed_probability,
        SkyVerdict.poor_probability,
    ).join(SkyVerdict, SkyVerdict.frame_id == Frame.id)
    q = q.where(*taken_in(camera_ids, since, until), *after(cursor))
    return session.execute(q.order_by(*NEWEST_FIRST).limit(limit).offset(offset)).all()


def estimate_out(verdict: SkyVerdict) -> SkyEstimate | None:
    """The regression's estimate of a verdict, or None (graded by the clusters)."""
    if verdict.estimate is None or verdict.estimate_unit is None:
        return None
    return SkyEstimate(
        unit=verdict.estimate_unit,
        value=verdict.estimate,
        low=verdict.estimate_low,
        high=verdict.estimate_high,
    )


def reading_out(r: Any) -> AirReading:
    """A row of ``readings`` as the API gives it."""
    return AirReading(
        camera_id=r.camera_id,
        frame_id=r.id,
        captured_at=r.captured_at,
        level=r.level,
        category=r.category,
        smoothed_level=r.smoothed_level,
        reason=r.reason,
        uncertain=r.uncertain,
        estimate=r.estimate,
        estimate_low=r.estimate_low,
        estimate_high=r.estimate_high,
        estimate_unit=r.estimate_unit,
        calibration_id=r.calibration_id,
        probability=r.probability,
        smoothed_estimate=r.smoothed_estimate,
        smoothed_low=r.smoothed_low,
        smoothed_high=r.smoothed_high,
        smoothed_probability=r.smoothed_probability,
        poor_probability=r.poor_probability,
    )


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


def latest_out(place: Place, found: tuple[Frame, SkyVerdict] | None, now: datetime) -> AirLatest:
    """The camera's public reading at ``now`` from its latest reading (``found``): the
    smoothed reading while current (taken in the last ``airquality.FRESH``), with its
    probability and range; what the screen says (``message``) in public words."""
    if found is None:
        return AirLatest(
            camera_id=place.camera_id,
            name=place.name,
            lat=place.lat,
            lon=place.lon,
            level=None,
            category=None,
            message=NOT_MEASURED,
            captured_at=None,
            smoothed_level=None,
            smoothed_category=None,
            frame_level=None,
            frame_category=None,
            reason="no frames yet",
            current=False,
        )
    frame, v = found
    age = now - frame.captured_at
    current = age < airquality.FRESH  # else a camera gone quiet: not today's air
    # the public level is the smoothed one (the map's and the alerts'), not the latest
    # frame's: one hazy frame said "Today's Air Quality is Poor" while the map, from the
    # same readings, drew the camera Fair
    level_now = v.smoothed_level
    level = airquality.rounded(level_now) if level_now is not None else None
    category = airquality.category(level_now) if level_now is not None else None
    probability = v.smoothed_probability if level_now is not None else None
    return AirLatest(
        camera_id=place.camera_id,
        name=place.name,
        lat=place.lat,
        lon=place.lon,
        level=level,
        category=category,
        message=_message(category, probability, current, v, age),
        captured_at=frame.captured_at,
        smoothed_level=level_now if current else None,
        smoothed_category=category if current else None,
        probability=probability if current else None,
        poor_probability=v.poor_probability if current else None,
        smoothed_estimate=_smoothed_estimate(v) if current else None,
        frame_level=v.level,
        frame_category=v.category,
        uncertain=(probability < public.SURE) if probability is not None else bool(v.uncertain),
        span=v.span if current else None,
        estimate=estimate_out(v),
        reason=v.reason
        if current
        else f"no reading in the last 3 hours: the latest was taken {_ago(age)}",
        current=current,
    )


def _smoothed_estimate(v: SkyVerdict) -> SkyEstimate | None:
    """The camera's smoothed estimate with its range, if a regression grades it."""
    if v.smoothed_estimate is None or v.estimate_unit is None:
        return None
    return SkyEstimate(
        unit=v.estimate_unit, value=v.smoothed_estimate, low=v.smoothed_low, high=v.smoothed_high
    )


def _ago(age: timedelta) -> str:
    """How long ago, as a person says it: hours up to two days, then days."""
    hours = age / timedelta(hours=1)
    return f"{hours:.0f} h ago" if hours < 48 else f"{age / timedelta(days=1):.0f} days ago"


NOT_MEASURED = "Air quality not measured here yet"
"""What the screen of a camera without a calibration, or without frames, says."""


def _message(
    category: str | None,
    probability: float | None,
    current: bool,
    v: SkyVerdict,
    age: timedelta,
) -> str:
    """What the public screen says, in its words (never the API's): today's category, "likely"
    when its probability is below ``public.SURE``; that the air is not measured yet (no
    calibration); that the camera cannot judge it now (every recent frame outside what it was
    calibrated on, or unusable); or that it has no reading in the last hours."""
    if not current:
        return f"No reading in the last 3 hours (the latest was taken {_ago(age)})"
    if category is not None:
        likely = "likely " if probability is not None and probability < public.SURE else ""
        return f"Today's Air Quality is {likely}{category}"
    if v.calibration_id is None and v.reason == NOT_CALIBRATED:
        return NOT_MEASURED
    return "The camera cannot judge the air now: its sky is unlike what it was calibrated on"


SKY_WIDTH = 480
"""Width of the public sky picture at most [px]."""


def sky_crop(data: bytes, region: Any) -> bytes:
    """The region's bounding box of a stored JPEG, at most ``SKY_WIDTH`` wide, as JPEG."""
    import cv2

    from app.platform.frames.camera_info import parse_region
    from app.platform.frames.jpeg import decode_rgb
    from app.platform.frames.stats import bounding_box, crop

    image = decode_rgb(data, max_pixels=1_000_000_000)[1]
    roi, polygon = parse_region(region)
    box = bounding_box(polygon) if polygon is not None else roi
    bgr: Any = np.ascontiguousarray(crop(image, box)[:, :, ::-1])
    if bgr.shape[1] > SKY_WIDTH:
        height = max(1, round(bgr.shape[0] * SKY_WIDTH / bgr.shape[1]))
        bgr = cv2.resize(bgr, (SKY_WIDTH, height), interpolation=cv2.INTER_AREA)
    ok, buf = cv2.imencode(".jpg", bgr)
    assert ok
    return bytes(buf.tobytes())
