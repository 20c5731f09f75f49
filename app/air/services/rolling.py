"""Rolling calibration: every camera within reach of a reference station calibrated again from
it as pairs accrue, and flagged when its readings drift from the station's."""

from __future__ import annotations

import asyncio
import logging
import time
from dataclasses import dataclass
from datetime import datetime, timedelta
from functools import partial

from sqlalchemy import select
from sqlalchemy.orm import Session, sessionmaker

from app.air.core import airquality
from app.air.models import AirCalibration, SkyVerdict
from app.air.schemas import AirCalibrationFromFrames
from app.air.services import stations
from app.air.services.calibration import from_frames, grading
from app.platform.background import in_thread
from app.platform.db.models import Camera, CameraKind
from app.platform.http.errors import Unprocessable
from app.platform.timing import Timing

log = logging.getLogger("vantage.air")

YIELD = 0.002
"""Seconds a rolling pass waits between cameras [s]: without it, the pass took SQLite's one
connection back at once, camera after camera, and the uploads and sweeps waiting for it timed
out after 60 s (bench/stations.py)."""

DRIFT_MIN_PAIRS = 12
"""Pairs a drift is judged on at least."""
DRIFT_SHARE = 0.5
"""A camera has drifted when its readings' 80 % ranges miss the station's value in more than
this share of its pairs: an interval that holds four times in five misses more than half of
12 or more only with a probability under 0.4 % (binomial), unless the camera changed."""


@dataclass(frozen=True, slots=True)
class Rolled:
    recalibrated: list[str]
    drifting: list[str]
    skipped: dict[str, str]
    """Cameras not recalibrated, and why (no station near, too few days paired)."""


def drift(session: Session, current: AirCalibration | None, pairs: stations.Pairs) -> str | None:
    """Why the camera should be recalibrated ("recalibrate: …"), "" when it need not be, or
    None when too few of its frames graded by the calibration that grades it now pair with
    a station value to tell (fewer than ``DRIFT_MIN_PAIRS``): it has drifted when their 80 %
    ranges missed the station's value in more than ``DRIFT_SHARE`` of them. ``current``: the
    calibration that grades the camera now."""
    if current is None or not pairs.frame_ids:
        return None
    value = dict(zip(pairs.frame_ids, pairs.pm25, strict=True))
    rows = session.execute(
        select(SkyVerdict.frame_id, SkyVerdict.estimate_low, SkyVerdict.estimate_high).where(
            SkyVerdict.frame_id.in_(pairs.frame_ids),
            SkyVerdict.calibration_id == current.id,
            SkyVerdict.estimate_unit == "pm25",
            SkyVerdict.estimate_low.is_not(None),
        )
    ).all()
    if len(rows) < DRIFT_MIN_PAIRS:
        return None
    missed = sum(not (r.estimate_low <= value[r.frame_id] <= r.estimate_high) for r in rows)
    if missed <= DRIFT_SHARE * len(rows):
        return ""
    return (
        f"recalibrate: its readings' 80 % ranges missed the station's PM2.5 in {missed} of "
        f"{len(rows)} frames (a calibration that still fits misses about 1 in 5): was it "
        "moved, zoomed or refocused?"
    )


def recalibrate(
    session: Session, camera: Camera, *, now: datetime, days: float, max_km: float
) -> str | None:
    """Flag (or clear) the camera's drift, then calibrate it from its stations' readings of
    the last ``days`` days, by the method that grades it now (the choice on days left out
    when none does); None when done, else why not."""
    try:
        near = stations.near(session, camera, max_km)
    except Unprocessable as exc:
        return exc.detail
    pairs = stations.pair(session, camera, near, since=now - timedelta(days=days))
    current = grading(session, camera.id).calibration
    why = drift(session, current, pairs)
    if why is not None:  # judged: flagged, or cleared; else as it was
        camera.attention = [why] if why else None
    if len(pairs.days) < airquality.MIN_GROUPS:
        return f"{len(pairs.frame_ids)} frames paired, of fewer than 3 days"
    body = AirCalibrationFromFrames(frame_ids=pairs.frame_ids, pm25=pairs.pm25)
    method = current.method if current is not None else None
    try:
        from_frames(session, body, 0.05, 0.0, now, method, [camera.id], None)
    except Unprocessable as exc:
        return exc.detail
    return None


def recalibrate_all(
    sessions: sessionmaker[Session], timing: Timing, *, days: float, max_km: float
) -> Rolled:
    """``recalibrate`` every located sky camera in service, each in its own transaction (one
    camera's refusal leaves the others'), pausing ``YIELD`` between them so that the writes
    waiting for the database's connection (SQLite has one) take it in turn."""
    with sessions() as session:
        ids = session.scalars(
            select(Camera.id)
            .where(
                Camera.kind == CameraKind.sky,
                Camera.retired_at.is_(None),
                Camera.lat.is_not(None),
                Camera.lon.is_not(None),
            )
            .order_by(Camera.id)
        ).all()
    done, drifting, skipped = [], [], {}
    now = timing.now()
    for camera_id in ids:
        with sessions.begin() as session:
            camera = session.get(Camera, camera_id)
            assert camera is not None
            why = recalibrate(session, camera, now=now, days=days, max_km=max_km)
            if camera.attention:
                drifting.append(camera_id)
        time.sleep(YIELD)
        if why is None:
            done.append(camera_id)
        else:
            skipped[camera_id] = why
    return Rolled(done, drifting, skipped)


async def run(
    sessions: sessionmaker[Session], timing: Timing, *, hours: float, days: float, max_km: float
) -> None:
    """``recalibrate_all`` every ``hours`` (the first after one interval)."""
    while True:
        await asyncio.sleep(hours * 3600)
        try:
            job = partial(recalibrate_all, sessions, timing, days=days, max_km=max_km)
            rolled = await in_thread(job)
            log.info(
                "rolling calibration",
                extra={
                    "recalibrated": len(rolled.recalibrated),
                    "drifting": rolled.drifting,
                    "skipped": len(rolled.skipped),
                },
            )
        except Exception:
            log.exception("rolling calibration failed")
