"""Reference stations: the monitors, their PM2.5 readings, the cameras within reach of them,
and a camera's frames paired with their readings."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from datetime import datetime, timedelta

import numpy as np
from pydantic import TypeAdapter, ValidationError
from sqlalchemy import delete, func, select
from sqlalchemy.dialects import postgresql, sqlite
from sqlalchemy.orm import Session

from app.air.core import airquality
from app.air.models import AirCalibration, AirStation, SkyVerdict, StationReading
from app.air.schemas import (
    AirCalibrationFromFrames,
    StationCreate,
    StationReadingIn,
    StationUpdate,
)
from app.air.services.calibration import from_frames, solar_day
from app.air.services.cameras import sky_camera
from app.platform.db.models import Camera, Frame
from app.platform.frames.cameras import insert_new
from app.platform.http.errors import Unprocessable
from app.platform.http.uploads import csv_models, item_error
from app.platform.lookup import get_or_404

EARTH_RADIUS_KM = 6371.0088
"""The mean Earth radius [km] (IUGG)."""

PAIR_WINDOW = timedelta(minutes=30)
"""A frame pairs with a station's reading taken within this of it."""

MAX_READINGS = 100_000
"""Readings one import takes at most."""


def distance_km(lat1: float, lon1: float, lat2: float, lon2: float) -> float:
    """The great-circle distance [km] between two WGS 84 points (haversine on the mean
    sphere: within 0.5 % of the ellipsoid's)."""
    p1, p2 = math.radians(lat1), math.radians(lat2)
    dp, dl = p2 - p1, math.radians(lon2 - lon1)
    a = math.sin(dp / 2) ** 2 + math.cos(p1) * math.cos(p2) * math.sin(dl / 2) ** 2
    return 2 * EARTH_RADIUS_KM * math.asin(min(1.0, math.sqrt(a)))


def create(session: Session, data: StationCreate, now: datetime) -> AirStation:
    station = AirStation(**data.model_dump(), created_at=now)
    insert_new(session, station, "station")
    return station


def get(session: Session, station_id: str) -> AirStation:
    return get_or_404(session, AirStation, station_id, "station")


def update(session: Session, station_id: str, data: StationUpdate) -> AirStation:
    """Change the fields ``data`` carries; lat and lon cannot be cleared (422)."""
    station = get(session, station_id)
    for field, value in data.model_dump(include=data.model_fields_set).items():
        if value is None and field in ("lat", "lon"):
            raise Unprocessable(f"{field}: a station stands somewhere; it cannot be cleared")
        setattr(station, field, value)
    session.flush()
    return station


def remove(session: Session, station_id: str) -> None:
    """Delete the station and its readings."""
    station = get(session, station_id)
    session.execute(delete(StationReading).where(StationReading.station_id == station_id))
    session.delete(station)
    session.flush()


@dataclass(frozen=True, slots=True)
class Latest:
    at: datetime
    pm25: float


def listing(
    session: Session, *, limit: int, offset: int, ids: Sequence[str] | None = None
) -> list[tuple[AirStation, Latest | None]]:
    """Stations by id, each with its latest reading: one statement for the page's newest
    times, one for their values."""
    q = select(AirStation)
    if ids is not None:
        q = q.where(AirStation.id.in_(ids))
    page = session.scalars(q.order_by(AirStation.id).limit(limit).offset(offset)).all()
    return list(zip(page, latest_of(session, [s.id for s in page]), strict=True))


def latest_of(
    session: Session, station_ids: Sequence[str], until: datetime | None = None
) -> list[Latest | None]:
    """Each station's newest reading (at or before ``until``), or None."""
    if not station_ids:
        return []
    newest = select(StationReading.station_id, func.max(StationReading.at).label("at")).where(
        StationReading.station_id.in_(station_ids)
    )
    if until is not None:
        newest = newest.where(StationReading.at <= until)
    sub = newest.group_by(StationReading.station_id).subquery()
    rows = session.execute(
        select(StationReading.station_id, StationReading.at, StationReading.pm25).join(
            sub,
            (sub.c.station_id == StationReading.station_id) & (sub.c.at == StationReading.at),
        )
    ).all()
    found = {r.station_id: Latest(r.at, r.pm25) for r in rows}
    return [found.get(i) for i in station_ids]


_READINGS = TypeAdapter(list[StationReadingIn])


def parse_json(body: bytes) -> list[StationReadingIn]:
    """A JSON list of ``{"at", "pm25"}``; 422 naming the first bad item's field
    (``readings[3].pm25``)."""
    try:
        readings = _READINGS.validate_json(body)
    except ValidationError as exc:
        raise Unprocessable(item_error(exc, "readings"), code="bad_readings") from None
    return _bounded(readings)


def parse_csv(text: str) -> list[StationReadingIn]:
    """CSV with a header ``at,pm25`` (other columns ignored); 422 naming the first bad row
    (its line number) and field."""
    rows = csv_models(
        text,
        StationReadingIn,
        required=("at", "pm25"),
        columns=("at", "pm25"),
        code="bad_readings",
        limit=MAX_READINGS,
    )
    return _bounded([r for _, r in rows])


def _bounded(readings: list[StationReadingIn]) -> list[StationReadingIn]:
    if len(readings) > MAX_READINGS:
        raise Unprocessable(
            f"at most {MAX_READINGS} readings an import: send them in parts",
            code="too_many_readings",
        )
    return readings


def store(session: Session, station_id: str, readings: Sequence[StationReadingIn]) -> int:
    """Store the readings (a time already stored, or repeated within them, takes the last
    value: an import can be sent again); how many distinct times. One statement per 5,000
    (the database's upsert: SQLite's and PostgreSQL's ``ON CONFLICT DO UPDATE``)."""
    get(session, station_id)
    rows = list(
        {r.at: {"station_id": station_id, "at": r.at, "pm25": r.pm25} for r in readings}.values()
    )
    dialect = session.get_bind().dialect.name
    insert = postgresql.insert if dialect == "postgresql" else sqlite.insert
    for start in range(0, len(rows), 5000):
        stmt = insert(StationReading).values(rows[start : start + 5000])
        session.execute(
            stmt.on_conflict_do_update(
                index_elements=["station_id", "at"], set_={"pm25": stmt.excluded.pm25}
            )
        )
    return len(rows)


def readings(
    session: Session,
    station_id: str,
    *,
    since: datetime | None,
    until: datetime | None,
    limit: int,
    offset: int,
) -> Sequence[StationReading]:
    """The station's readings in [since, until), newest first."""
    get(session, station_id)
    q = select(StationReading).where(StationReading.station_id == station_id)
    if since is not None:
        q = q.where(StationReading.at >= since)
    if until is not None:
        q = q.where(StationReading.at < until)
    return session.scalars(q.order_by(StationReading.at.desc()).limit(limit).offset(offset)).all()


@dataclass(frozen=True, slots=True)
class Near:
    station: AirStation
    km: float


def near(session: Session, camera: Camera, max_km: float) -> list[Near]:
    """The stations within ``max_km`` of the camera, nearest first; 422 naming the nearest
    one's distance when none is (or the camera has no place)."""
    if camera.lat is None or camera.lon is None:
        raise Unprocessable(
            f"camera {camera.id!r} has no position (lat, lon): stations near it cannot be found",
            code="no_station_near",
        )
    found = sorted(
        (
            Near(s, distance_km(camera.lat, camera.lon, s.lat, s.lon))
            for s in session.scalars(select(AirStation))
        ),
        key=lambda n: n.km,
    )
    if not found:
        raise Unprocessable(
            "no reference station is registered (POST /air/stations)", code="no_station_near"
        )
    within = [n for n in found if n.km <= max_km]
    if not within:
        nearest = found[0]
        raise Unprocessable(
            f"no station within max_distance_km={max_km:g} of camera {camera.id!r}: the "
            f"nearest, {nearest.station.id!r}, is {nearest.km:.1f} km away",
            code="no_station_near",
        )
    return within


MAX_PAIRS = 10_000
"""Pairs a calibration takes at most (a calibration from stored frames takes as many): a
camera posting every minute pairs 43,000 frames in 30 days, and evenly spaced ones of them
measure the same."""


def evenly(n: int, at_most: int) -> list[int]:
    """Indices of at most ``at_most`` of ``n`` items, evenly spaced (all of them when fewer)."""
    if n <= at_most:
        return list(range(n))
    return [int(i) for i in np.unique(np.linspace(0, n - 1, at_most).round())]


@dataclass(frozen=True, slots=True)
class Pairs:
    frame_ids: list[str]
    pm25: list[float]
    stations: list[str]
    """The stations that gave values."""
    days: set[str]
    """The days the pairs cover (``solar_day``, as the calibration groups them)."""


def pair(
    session: Session, camera: Camera, stations: Sequence[Near], since: datetime | None = None
) -> Pairs:
    """The camera's graded-or-not stored sky frames (usable, measured with sky features)
    paired with the readings of ``stations`` within ``PAIR_WINDOW``: each station's reading
    nearest the frame's time; of several stations, the inverse-distance-weighted mean (the
    nearest alone when it stands within 100 m). Frames taken since ``since`` only, when
    given; at most ``MAX_PAIRS`` of them."""
    q = (
        select(Frame.id, Frame.captured_at)
        .join(SkyVerdict, SkyVerdict.frame_id == Frame.id)
        .where(Frame.camera_id == camera.id, SkyVerdict.usable.is_(True))
    )
    if since is not None:
        q = q.where(Frame.captured_at >= since)
    frames = session.execute(q.order_by(Frame.captured_at)).all()
    if not frames:
        return Pairs([], [], [], set())
    first, last = frames[0].captured_at - PAIR_WINDOW, frames[-1].captured_at + PAIR_WINDOW
    series = {}
    for n in stations:
        rows = session.execute(
            select(StationReading.at, StationReading.pm25)
            .where(
                StationReading.station_id == n.station.id,
                StationReading.at >= first,
                StationReading.at <= last,
            )
            .order_by(StationReading.at)
        ).all()
        if rows:
            t = np.array([r.at.timestamp() for r in rows])
            series[n.station.id] = (t, np.array([r.pm25 for r in rows]), max(n.km, 0.1))
    ids: list[str] = []
    values: list[float] = []
    used: set[str] = set()
    taken: list[datetime] = []
    window = PAIR_WINDOW.total_seconds()
    for f in frames:
        t0 = f.captured_at.timestamp()
        got = []
        for sid, (t, v, km) in series.items():
            i = int(np.searchsorted(t, t0))
            near_i = [j for j in (i - 1, i) if 0 <= j < len(t)]
            j = min(near_i, key=lambda j: abs(t[j] - t0))
            if abs(t[j] - t0) <= window:
                got.append((sid, float(v[j]), km))
        if not got:
            continue
        w = np.array([1 / km for _, _, km in got])
        ids.append(f.id)
        values.append(float(w @ np.array([v for _, v, _ in got]) / w.sum()))
        taken.append(f.captured_at)
        used.update(sid for sid, _, _ in got)
    keep = evenly(len(ids), MAX_PAIRS)
    ids, values, taken = [ids[i] for i in keep], [values[i] for i in keep], [taken[i] for i in keep]
    days = {solar_day(t, camera.lon) for t in taken}
    return Pairs(ids, values, sorted(used), days)


def calibrate_from_stations(
    session: Session,
    camera_ids: Sequence[str],
    method: str | None,
    table: str | None,
    *,
    max_km: float,
    significance: float,
    shrinkage: float,
    now: datetime,
) -> AirCalibration:
    """A calibration of ``camera_ids`` from their stored frames paired with the readings of
    the stations within ``max_km`` of each (``near``, ``pair``), fitted as one from ``pm25``
    (``calibration.from_frames``): the method chosen on days left out unless given. 422
    naming the distance when no station is near a camera, or the days when fewer than three
    pair."""
    if not camera_ids:
        raise Unprocessable(
            "from=stations calibrates the cameras named in applies_to: name at least one",
            code="no_station_near",
        )
    frame_ids: list[str] = []
    values: list[float] = []
    used: set[str] = set()
    days: set[str] = set()
    for camera_id in sorted(set(camera_ids)):
        camera = sky_camera(session, camera_id)
        found = pair(session, camera, near(session, camera, max_km))
        frame_ids += found.frame_ids
        values += found.pm25
        used.update(found.stations)
        days |= found.days
    keep = evenly(len(frame_ids), MAX_PAIRS)  # several cameras' together
    frame_ids, values = [frame_ids[i] for i in keep], [values[i] for i in keep]
    if len(days) < airquality.MIN_GROUPS:
        raise Unprocessable(
            f"{len(frame_ids)} frames of {', '.join(sorted(set(camera_ids)))} pair with a "
            f"station reading within {PAIR_WINDOW.total_seconds() / 60:g} minutes, over "
            f"{len(days)} day{'s' if len(days) != 1 else ''}: a calibration needs "
            f"{airquality.MIN_GROUPS} days or more",
            code="too_few_days",
        )
    body = AirCalibrationFromFrames(frame_ids=frame_ids, pm25=values)
    row = from_frames(session, body, significance, shrinkage, now, method, list(camera_ids), table)
    row.warnings = [
        *row.warnings,
        f"from stations {', '.join(used)}: {len(frame_ids)} frames paired over {len(days)} "
        f"days (readings within {PAIR_WINDOW.total_seconds() / 60:g} minutes, stations "
        f"within {max_km:g} km)",
    ]
    session.flush()
    return row
