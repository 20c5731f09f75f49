"""The city's map: each camera's level in a window, interpolated into category bands
(``core.isopleths``), as a GeoJSON document."""

from __future__ import annotations

from dataclasses import dataclass
from datetime import UTC, datetime, timedelta
from typing import Any, Literal

import numpy as np
from sqlalchemy import (
    func,
    or_,
    select,
)
from sqlalchemy.orm import Session

from app.air.core import airquality, breakpoints, isopleths
from app.air.models import AirCalibration, AirStation, SkyVerdict
from app.air.services.calibration import as_regression
from app.air.services.cameras import TRUSTED
from app.air.services.stations import latest_of
from app.platform.db.models import Camera, CameraKind, Frame
from app.platform.http.errors import (
    Unprocessable,
)
from app.platform.timing import Timing


@dataclass(frozen=True, slots=True)
class Station:
    camera_id: str
    lon: float
    lat: float
    level: float
    captured_at: datetime
    name: str | None = None
    error: float = 0.0
    """The standard error of its level [level]: from its reading's 80 % range (``level_error``),
    0 for a clusters' level (no range)."""
    probability: float | None = None
    """The probability of its reading's category."""
    attention: tuple[str, ...] = ()
    """What its operator should do ("recalibrate: …")."""


Z80 = 1.2816
"""The standard normal's 90th percentile: an 80 % range is ±1.2816 σ."""
QUANTUM = 1 / np.sqrt(12)
"""The standard deviation of rounding to whole levels [level]: a range within one level is
no surer than its level's rounding."""


def level_error(low: float, high: float, unit: str, table: str) -> float:
    """The standard error [level] of a reading whose 80 % range in ``unit`` is [low, high]:
    the levels of its ends, apart by 2 × 1.2816 σ, at least ``QUANTUM``."""
    a, b = (airquality.level_of(v, unit, table) for v in (low, high))
    return max(abs(a - b) / (2 * Z80), float(QUANTUM))


@dataclass(frozen=True, slots=True)
class Monitor:
    """A reference station on the map: its newest reading in the window."""

    station_id: str
    name: str | None
    lon: float
    lat: float
    pm25: float
    at: datetime
    level: float
    """The level of its PM2.5 by the breakpoint table of its place."""


STATION_ERROR = float(QUANTUM)
"""A station's standard error on the map [level]: it measures, so only the rounding of its
value to a level."""


def monitors(session: Session, *, since: datetime, until: datetime) -> list[Monitor]:
    """Each reference station with a reading in [``since``, ``until``]: its newest one there,
    as a level by the table of its place (``breakpoints.table_for_places``)."""
    every = session.scalars(select(AirStation).order_by(AirStation.id)).all()
    out = []
    for station, latest in zip(
        every, latest_of(session, [s.id for s in every], until), strict=True
    ):
        if latest is None or latest.at < since:
            continue
        table = breakpoints.table_for_places([(station.lat, station.lon)])
        level = float(breakpoints.level_of_pm25(latest.pm25, table))
        out.append(
            Monitor(
                station.id, station.name, station.lon, station.lat, latest.pm25, latest.at, level
            )
        )
    return out


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
            SkyVerdict.smoothed_low,
            SkyVerdict.smoothed_high,
            SkyVerdict.estimate_unit,
            SkyVerdict.calibration_id,
            SkyVerdict.smoothed_probability,
            Camera.attention,
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
    tables = _tables(session, {r.calibration_id for r in rows if r.calibration_id is not None})
    for cid, name, lon, lat, smooth, level, t, low, high, unit, cal, prob, attention in rows:
        value = smooth if smooth is not None else level
        if lon is None or lat is None or value is None:
            continue
        error = 0.0
        if smooth is not None and low is not None and high is not None and unit and cal in tables:
            error = level_error(low, high, unit, tables[cal])
        seen[cid] = Station(
            cid,
            float(lon),
            float(lat),
            float(value),
            t,
            name,
            error,
            prob if smooth else None,
            tuple(attention or ()),
        )
    return sorted(seen.values(), key=lambda s: s.camera_id)


def _tables(session: Session, calibration_ids: set[str]) -> dict[str, str]:
    """The breakpoint table of each regression among ``calibration_ids``."""
    out = {}
    for row in session.scalars(
        select(AirCalibration).where(AirCalibration.id.in_(sorted(calibration_ids)))
    ):
        regression = as_regression(row)
        if regression is not None:
            out[row.id] = regression.table
    return out


@dataclass(frozen=True)
class MapQuery:
    """What a map is of: the query parameters both renderings take (and their cache key)."""

    bbox: tuple[float, float, float, float] | None
    window: int
    method: Literal["idw", "kriging", "rbf"]
    resolution: int
    max_distance: float
    at: datetime | None
    """The time the map is of; None: now."""
    layer: Literal["levels", "uncertainty"] = "levels"


@dataclass(frozen=True)
class MapData:
    """What a map is drawn from: the cameras' levels in the window [since, at] and the islands
    interpolated from them (none without any) over ``box`` (the bbox asked for, else the
    islands' together)."""

    stations: list[Station]
    islands: list[isopleths.Island]
    """Interpolated from the cameras (indices below len(stations)) and the monitors (the
    rest, in order)."""
    box: tuple[float, float, float, float] | None
    since: datetime
    at: datetime
    max_distance: float
    monitors: tuple[Monitor, ...] = ()


def _window_start(at: datetime, window: int) -> datetime:
    """``window`` seconds before ``at``; the first instant of year 1 for a window reaching
    before it (``at=0001-01-01T00:00:00Z`` overflowed: a 500)."""
    try:
        return at - timedelta(seconds=window)
    except OverflowError:
        return datetime.min.replace(tzinfo=UTC)


def field(session: Session, timing: Timing, q: MapQuery) -> MapData:
    now = timing.now()
    if q.at is not None and q.at > now:
        raise Unprocessable(f"at {q.at.isoformat()} lies in the future", code="bad_time")
    at = q.at or now
    since = _window_start(at, q.window)
    st = stations(session, since=since, until=at)
    mons = monitors(session, since=since, until=at)
    if not st and not mons:
        return MapData(st, [], q.bbox, since, at, q.max_distance)
    points: list[Station | Monitor] = [*st, *mons]
    lon = np.array([p.lon for p in points])
    lat = np.array([p.lat for p in points])
    errors = [s.error for s in st] + [STATION_ERROR] * len(mons)
    try:
        found = isopleths.interpolate_islands(
            lon,
            lat,
            np.array([p.level for p in points]),
            errors=np.array(errors),
            bbox=q.bbox,
            method=q.method,
            resolution=q.resolution,
            max_distance=q.max_distance,
        )
    except isopleths.IsoplethError as exc:
        raise Unprocessable(str(exc), code="bad_field") from None
    box = q.bbox
    if box is None and found:
        boxes = np.array([i.bbox for i in found])
        box = (
            float(boxes[:, 0].min()),
            float(boxes[:, 1].min()),
            float(boxes[:, 2].max()),
            float(boxes[:, 3].max()),
        )
    return MapData(st, found, box, since, at, q.max_distance, tuple(mons))


def empty_reason(m: MapData, off_map: list[str], window: int) -> str | None:
    """Why a map has no bands, or None when it has some."""
    if any(np.isfinite(i.field.value).any() for i in m.islands):
        return None
    if m.stations or m.monitors:
        return (
            f"no cell of the bbox lies within max_distance ({m.max_distance:g} m) of a camera"
            " with a reading"
        )
    if off_map:
        return "the sky cameras with readings have no place (lat/lon) to draw them at"
    return (
        f"no sky camera has a graded reading in the {window} s before {m.at.isoformat()} (window)"
    )


def geojson(m: MapData, off_map: list[str], now: datetime, q: MapQuery) -> dict[str, Any]:
    """The collection: the bands (or the uncertainty layer) of every island, one feature per
    band; the cameras; the islands; why nothing is drawn when nothing is; and warnings of
    cameras drawn in another category's band and of graded cameras with no place."""
    st = m.stations
    per_island = [
        isopleths.bands(i.field) if q.layer == "levels" else isopleths.uncertainty_bands(i.field)
        for i in m.islands
    ]
    own = [airquality.category(s.level) for s in st]
    drawn = _bands_drawn(m)
    cell = [round(v, 1) for v in isopleths.cell_size_m(m.islands[0].field)] if m.islands else None
    return {
        "type": "FeatureCollection",
        "features": isopleths.merged(per_island),
        "bbox": list(m.box) if m.box else None,
        "method": q.method,
        "layer": q.layer,
        "computed_at": now.isoformat(),
        "at": m.at.isoformat(),
        "window_s": q.window,
        "max_distance_m": q.max_distance,
        "cameras": [
            {
                "camera_id": s.camera_id,
                "name": s.name,
                "lon": s.lon,
                "lat": s.lat,
                "level": s.level,
                "category": category,
                "band": band,
                "captured_at": s.captured_at.isoformat(),
                "probability": s.probability,
                "level_error": s.error,
                "recalibrate": any(a.startswith("recalibrate") for a in s.attention),
            }
            for s, category, band in zip(st, own, drawn, strict=True)
        ],
        "islands": [
            {
                "bbox": list(i.bbox),
                "cell_m": [round(v, 1) for v in isopleths.cell_size_m(i.field)],
                "cells": [len(i.field.lon), len(i.field.lat)],
                "method": i.method,
                "camera_ids": [st[k].camera_id for k in i.cameras.tolist() if k < len(st)],
                "station_ids": [
                    m.monitors[k - len(st)].station_id for k in i.cameras.tolist() if k >= len(st)
                ],
            }
            for i in m.islands
        ],
        "stations": [
            {
                "station_id": s.station_id,
                "name": s.name,
                "lon": s.lon,
                "lat": s.lat,
                "value": s.pm25,
                "unit": "pm25",
                "at": s.at.isoformat(),
                "level": s.level,
                "category": airquality.category(s.level),
                "band": band,
            }
            for s, band in zip(m.monitors, _monitor_bands(m), strict=True)
        ],
        "cell_m": cell,
        "empty_reason": empty_reason(m, off_map, q.window),
        "warnings": _warnings(m, own, drawn, cell, off_map, q.method),
        "uncertainty": _uncertainty(m.islands),
    }


def _monitor_bands(m: MapData) -> list[str | None]:
    """The category band each reference station of ``m`` is drawn in (None: off the map)."""
    drawn: list[str | None] = [None] * len(m.monitors)
    first = len(m.stations)
    for island in m.islands:
        idx = island.cameras[island.cameras >= first] - first
        found = isopleths.band_at(
            island.field,
            np.array([m.monitors[k].lon for k in idx]),
            np.array([m.monitors[k].lat for k in idx]),
        )
        for k, band in zip(idx.tolist(), found, strict=True):
            drawn[k] = band
    return drawn


def _bands_drawn(m: MapData) -> list[str | None]:
    """The category band each camera of ``m`` is drawn in (None: off every island)."""
    st = m.stations
    drawn: list[str | None] = [None] * len(st)
    for island in m.islands:
        idx = island.cameras[island.cameras < len(st)]
        found = isopleths.band_at(
            island.field,
            np.array([st[k].lon for k in idx]),
            np.array([st[k].lat for k in idx]),
        )
        for k, band in zip(idx.tolist(), found, strict=True):
            drawn[k] = band
    return drawn


def _warnings(
    m: MapData,
    own: list[str],
    drawn: list[str | None],
    cell: list[float] | None,
    off_map: list[str],
    method: str,
) -> list[str]:
    """What the reader of the map should know: cameras drawn in another category's band than
    their own reading, islands drawn by another method than asked, graded cameras with no
    place."""
    warnings = []
    off = sum(1 for o, d in zip(own, drawn, strict=True) if d is not None and d != o)
    if off and cell is not None:
        warnings.append(
            f"{off} of {len(own)} cameras lie in the band of another category than their"
            f" own reading, with cells of {cell[0]:.0f} × {cell[1]:.0f} m: ask for a"
            " smaller bbox or a larger resolution (up to 512); cameras close together"
            " that disagree stay so at any resolution"
        )
    for n, island in enumerate(m.islands):
        if island.method != method:
            warnings.append(
                f"island {n + 1} has cameras at fewer than 3 places, which {method} needs:"
                f" drawn by {island.method}"
            )
    if off_map:
        named = ", ".join(off_map[:10]) + (" …" if len(off_map) > 10 else "")
        some = (
            "1 sky camera with readings has"
            if len(off_map) == 1
            else f"{len(off_map)} sky cameras with readings have"
        )
        warnings.append(
            f"{some} no lat/lon and so no place on the map: {named} (PATCH /cameras/{{id}}"
            " with both)"
        )
    return warnings


def _uncertainty(islands: list[isopleths.Island]) -> dict[str, Any] | None:
    """The uncertainty layer's kind (kriging's standard deviation [level] or the distance to
    the nearest camera [m]), its largest and mean value; None without islands."""
    if not islands:
        return None
    kinds = {i.field.uncertainty_kind for i in islands}
    return {
        "kind": kinds.pop() if len(kinds) == 1 else "mixed",
        "max": max(float(np.nanmax(i.field.uncertainty)) for i in islands),
        "mean": float(np.nanmean(np.concatenate([i.field.uncertainty.ravel() for i in islands]))),
    }
