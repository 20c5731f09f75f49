"""Air quality: calibration (admin); latest, readings, alerts and isopleths (public)."""

from __future__ import annotations

import csv
import io
import json
import math
from collections.abc import Callable
from dataclasses import dataclass
from datetime import UTC, datetime, timedelta
from functools import partial
from typing import Annotated, Any, Literal
from zoneinfo import ZoneInfo, ZoneInfoNotFoundError

import numpy as np
from fastapi import APIRouter, Depends, Query, Request
from fastapi.concurrency import run_in_threadpool
from fastapi.responses import Response
from pydantic import StringConstraints
from sqlalchemy.orm import Session

from app.air import alerts as webhooks
from app.air import service as air
from app.air.core import airquality, breakpoints, isopleths
from app.air.isopleth_cache import MapCache
from app.air.kind import estimate_out
from app.air.models import SkyVerdict
from app.air.schemas import (
    AirAggregate,
    AirAlertOut,
    AirCalibrationFromFrames,
    AirCalibrationOut,
    AirLatest,
    AirReading,
    AirRegradeOut,
    WebhookTestOut,
)
from app.platform import webhooks as platform_webhooks
from app.platform.db.models import Frame
from app.platform.db.session import release
from app.platform.frames import ingest
from app.platform.frames.deps import FrameCursor, link_next
from app.platform.http.compression import accepts_gzip
from app.platform.http.crowds import Crowds
from app.platform.http.deps import (
    ID_PATTERN,
    Admin,
    CameraId,
    IdFilter,
    IdsFilter,
    Limit,
    Offset,
    OptionalPrincipal,
    PolicyDep,
    SessionDep,
    SettingsDep,
    TimeRangeQuery,
    UtcTime,
    get_principal,
    image_work,
    public_read,
    public_work,
)
from app.platform.http.errors import Conflict, NotFound, Unprocessable, UnsupportedMediaType
from app.platform.http.responses import (
    AUTH_ERRORS,
    BODY_ERRORS,
    NOT_FOUND,
    UNPROCESSABLE,
    multipart_body,
    not_modified,
)
from app.platform.http.uploads import content_type, read_form, read_json
from app.platform.policy import Policy

router = APIRouter(prefix="/air", tags=["air quality"])

Significance = Annotated[float, Query(ge=1e-6, le=0.05, description="ς (eq. 6.21).")]
PUBLIC_MAX_OFFSET = 100_000
"""The deepest ``offset`` of a public listing: each row skipped is read, and a deeper page of
a city's readings is a cursor's job."""
Shrinkage = Annotated[
    float,
    Query(
        ge=0,
        le=100,
        description="Variance added to the diagonal of each level's Σ̂ of modes [grey level²]; "
        "0.0833 when a channel's mode is the same in all of a level's images.",
    ),
]


@dataclass(frozen=True, slots=True)
class References:
    levels: list[int]
    notes: list[str]
    """How the levels were made, for the calibration's warnings."""
    reference: tuple[str, list[float]] | None
    """("pm25" or "aqi", values) when given in a reference unit: the regression's unit."""
    table: str = "us_epa"
    """The breakpoint table the reference values became levels by."""


def _check_table(table: str | None, pm25_given: bool) -> None:
    """Refuse a table other than the EPA's for references that are not PM2.5."""
    if table is not None and table != "us_epa" and not pm25_given:
        raise Unprocessable(
            f"breakpoints={table} maps PM2.5 to levels: give pm25 (the US AQI and levels "
            "need no table of it)",
            code="breakpoints_without_pm25",
        )


Raw = tuple[list[int] | None, list[float] | None, list[float] | None]
"""(levels, pm25, aqi) as given, one of them."""


def _as_levels(session: Session, raw: Raw, table: str | None, applies_to: list[str]) -> References:
    """Levels as given, or from reference PM2.5 or AQI values by the breakpoint ``table``
    (``core.breakpoints``); the European table maps PM2.5 only. Without a table, PM2.5 takes
    the one of the graded cameras' place (``air.breakpoints_of_place``)."""
    levels, pm25, aqi = raw
    _check_table(table, pm25 is not None)
    if levels is not None:
        return References(levels, [], None)
    if pm25 is not None:
        chosen, why = (table, "") if table else air.breakpoints_of_place(session, applies_to)
        mapped = [breakpoints.level_of_pm25(v, chosen) for v in pm25]
        note = f"levels from PM2.5 by the {breakpoints.TABLES[chosen]}"
        if why:
            note += f": {why} (breakpoints=us_epa or eu_eaqi chooses a table)"
        return References(mapped, [note], ("pm25", pm25), chosen)
    assert aqi is not None
    return References(
        [breakpoints.level_of_aqi(v) for v in aqi],
        [f"levels from the {breakpoints.SOURCE}"],
        ("aqi", aqi),
    )


def _calibration_out(row: Any) -> AirCalibrationOut:
    return AirCalibrationOut.model_validate(row)


def _from_files(
    session: Session,
    files: list[tuple[str | None, bytes]],
    raw: Raw,
    table: str | None,
    camera_id: str | None,
    significance: float,
    shrinkage: float,
    max_pixels: int,
    policy: Policy,
    method: str,
    applies_to: list[str],
    groups: list[str] | None,
) -> AirCalibrationOut:
    refs = _as_levels(session, raw, table, applies_to)
    camera, warnings = air.upload_region(session, camera_id, applies_to)
    release(session)  # while decoding
    decoded = ingest.decode_all(files, camera, max_pixels=max_pixels)
    feats = np.array([d.features for d in decoded], dtype=np.float64)
    row = air.calibrate(
        session,
        ingest.modes_of(decoded),
        refs.levels,
        significance=significance,
        shrinkage=shrinkage,
        frame_ids=None,
        now=policy.now(),
        method=method,
        features=feats,
        camera_ids=applies_to,
        warnings=[*refs.notes, *warnings],
        reference=refs.reference,
        groups=groups,
        table=refs.table,
    )
    return _calibration_out(row)


def _from_frames(
    session: Session,
    body: AirCalibrationFromFrames,
    significance: float,
    shrinkage: float,
    policy: Policy,
    method: str,
    applies_to: list[str],
    table: str | None,
) -> AirCalibrationOut:
    refs = _as_levels(session, (body.levels, body.pm25, body.aqi), table, applies_to)
    if len(body.frame_ids) != len(refs.levels):
        raise Unprocessable(f"{len(body.frame_ids)} frames but {len(refs.levels)} reference values")
    stored = air.of_frames(session, body.frame_ids)
    row = air.calibrate(
        session,
        stored.modes,
        refs.levels,
        significance=significance,
        shrinkage=shrinkage,
        frame_ids=body.frame_ids,
        now=policy.now(),
        method=method,
        features=stored.features,
        camera_ids=applies_to,
        regions=stored.regions,
        warnings=refs.notes,
        reference=refs.reference,
        groups=stored.days,
        table=refs.table,
    )
    return _calibration_out(row)


def _references(name: str, raw: list[str]) -> Raw:
    """A multipart field of levels (integers 1–10) or of PM2.5 or AQI values (finite, ≥ 0)."""
    if name == "levels":
        try:
            levels = [int(v) for v in raw]
        except ValueError:
            raise Unprocessable("levels must be integers 1–10") from None
        if any(not 1 <= v <= 10 for v in levels):
            raise Unprocessable("levels must be integers 1–10")
        return levels, None, None
    try:
        values = [float(v) for v in raw]
    except ValueError:
        raise Unprocessable(f"{name} must be numbers") from None
    if not all(math.isfinite(v) and v >= 0 for v in values):
        raise Unprocessable(f"{name} must be finite numbers ≥ 0")
    return (None, values, None) if name == "pm25" else (None, None, values)


@router.post(
    "/calibration",
    status_code=201,
    response_model=AirCalibrationOut,
    responses={**AUTH_ERRORS, **NOT_FOUND, **BODY_ERRORS, **UNPROCESSABLE},
    openapi_extra=multipart_body(
        json=AirCalibrationFromFrames,
        files="files",
        levels="texts",
        pm25="texts",
        aqi="texts",
        groups="texts",
    ),
)
async def calibrate(
    request: Request,
    session: SessionDep,
    settings: SettingsDep,
    policy: PolicyDep,
    _: Admin,
    significance: Significance = 0.05,
    shrinkage: Shrinkage = 0.0,
    camera_id: Annotated[
        str | None,
        Query(
            description="The sky camera whose region (ROI) the uploads are measured in: they "
            "are its full frames. Default: the region of the cameras in applies_to when they "
            "all have the same one, else the whole image (a warning names the cameras graded "
            "that measure another region)."
        ),
    ] = None,
    applies_to: Annotated[
        list[Annotated[str, StringConstraints(pattern=ID_PATTERN)]] | None,
        Query(
            max_length=10_000,
            description="Sky cameras this calibration grades from now on (repeat the "
            "parameter). Without it, it is the city-wide calibration of every camera that has "
            "none of its own: calibrate a camera from its own labelled frames where its view "
            "or white balance differs from the rest.",
        ),
    ] = None,
    method: Annotated[
        Literal["clusters", "regression"],
        Query(
            description="Grade by the T² level clusters (the dissertation, eqs. 6.19–6.22) or "
            "by a ridge regression on richer sky features (better on real photos)."
        ),
    ] = "clusters",
    breakpoints_table: Annotated[
        breakpoints.Table | None,
        Query(
            alias="breakpoints",
            description="The table that makes reference pm25 values levels: the US EPA AQI "
            "breakpoints (2024) or the European Air Quality Index's PM2.5 bands (EEA, 2017), "
            "finer between 5 and 50 µg/m³ and narrower in its categories. PM2.5 only. "
            "Default: the European index when the cameras it grades (applies_to; else every "
            "sky camera) all stand in Europe, else the EPA's.",
        ),
    ] = None,
) -> AirCalibrationOut:
    """Calibrate the level clusters (eqs. 6.12–6.13) from labelled sky images.

    Multipart: repeated ``files`` and ``levels`` (1–10, same order), and optionally ``groups``
    (each image's capture day or session: the regression leaves a group's images out together
    when it measures its interval, as it leaves out a day of stored frames); or JSON
    ``{"frame_ids": [...], "levels": [...]}`` of stored sky frames. In place of ``levels``,
    the reference ``pm25`` [µg/m³] or US ``aqi`` of each, mapped to levels by the US EPA AQI
    breakpoints (2024) or, for PM2.5 with ``breakpoints=eu_eaqi``, the European Air Quality
    Index's bands (``app.air.core.breakpoints``); PM2.5 without ``breakpoints`` takes the
    European index where the cameras it grades stand in Europe, the EPA's elsewhere.
    """
    kind = content_type(request)
    if kind == "multipart/form-data":
        form = await read_form(
            request,
            settings.max_upload_bytes,
            max_files=5000,
            parts=("files", "levels", "pm25", "aqi", "groups"),
        )
        files = form.files_of("files")
        groups = form.groups_of(len(files))
        given = {k: form.fields[k] for k in ("levels", "pm25", "aqi") if form.fields.get(k)}
        if len(given) != 1:
            raise Unprocessable("give one of levels, pm25 or aqi per file")
        [(name, raw)] = given.items()
        if len(files) != len(raw):
            raise Unprocessable(f"{len(files)} files but {len(raw)} {name}; give one each")
        raw_refs = _references(name, raw)
        _check_table(breakpoints_table, name == "pm25")
        return await image_work(
            request,
            partial(
                _from_files,
                session,
                files,
                raw_refs,
                breakpoints_table,
                camera_id,
                significance,
                shrinkage,
                settings.max_pixels,
                policy,
                method,
                applies_to or [],
                groups,
            ),
        )
    if kind == "application/json":
        body = await read_json(request, AirCalibrationFromFrames, settings.max_body_bytes)
        return await run_in_threadpool(  # stored features, no image: no image_work
            partial(
                _from_frames,
                session,
                body,
                significance,
                shrinkage,
                policy,
                method,
                applies_to or [],
                breakpoints_table,
            ),
        )
    raise UnsupportedMediaType(
        "send multipart/form-data (files, levels) or JSON (frame_ids, levels)"
    )


@router.post(
    "/cameras/{camera_id}/regrade",
    response_model=AirRegradeOut,
    responses={**AUTH_ERRORS, **NOT_FOUND, **UNPROCESSABLE},
)
async def regrade(
    request: Request,
    camera_id: CameraId,
    since: Annotated[UtcTime, Query(description="Re-grade the frames taken since this time.")],
    session: SessionDep,
    settings: SettingsDep,
    _: Admin,
    limit: Annotated[
        int, Query(ge=1, le=air.REGRADE_LIMIT, description="Frames in this call at most.")
    ] = air.REGRADE_LIMIT,
) -> AirRegradeOut:
    """Grade the sky camera's stored frames taken since ``since`` again by the calibration
    that grades it now (after a new calibration), measured in its region now; smooth its
    readings again. Its history then speaks one calibration: each reading names it
    (``calibration_id``). Raises no alerts (history). Oldest first, ``limit`` at a time."""
    store = request.app.state.frame_store if settings.store_frames else None
    done = await image_work(
        request,
        partial(
            air.regrade,
            session,
            store,
            camera_id,
            since,
            max_pixels=settings.max_pixels,
            limit=limit,
        ),
    )
    return AirRegradeOut(
        camera_id=done.camera_id,
        calibration_id=done.calibration_id,
        since=done.since,
        regraded=done.regraded,
        missing=done.missing,
        next_since=done.next_since,
    )


@router.get("/calibration", response_model=AirCalibrationOut, responses=NOT_FOUND)
def current_calibration(session: SessionDep, camera_id: IdFilter = None) -> AirCalibrationOut:
    """The calibration in use: the city-wide one, or the one that grades ``camera_id``'s
    frames (its own, else the city-wide one)."""
    if camera_id is not None:
        air.sky_camera(session, camera_id)
    row = air.calibration_for(session, camera_id)
    if row is None:
        raise NotFound("no air-quality calibration yet")
    return _calibration_out(air.with_cameras(session, row))


@router.delete(
    "/cameras/{camera_id}/calibration",
    status_code=204,
    response_class=Response,
    responses={**AUTH_ERRORS, **NOT_FOUND},
)
def release_camera(camera_id: CameraId, session: SessionDep, _: Admin) -> Response:
    """Grade the sky camera by the city-wide calibration again, not by one made for it."""
    air.release_camera(session, camera_id)
    return Response(status_code=204)


@router.get(
    "/calibrations",
    response_model=list[AirCalibrationOut],
    responses={**NOT_FOUND, **UNPROCESSABLE},
)
def list_calibrations(
    session: SessionDep,
    camera_id: IdFilter = None,
    limit: Limit = 50,
    offset: Offset = 0,
) -> list[AirCalibrationOut]:
    """Every calibration, newest first, with the cameras each was made for (none: city-wide);
    with ``camera_id``, those made for that sky camera."""
    if camera_id is not None:
        air.sky_camera(session, camera_id)
    rows = air.calibrations(session, camera_id=camera_id, limit=limit, offset=offset)
    return [_calibration_out(r) for r in rows]


@router.get("/cameras/{camera_id}/latest", response_model=AirLatest, responses=NOT_FOUND)
def latest(camera_id: CameraId, session: SessionDep, policy: PolicyDep) -> AirLatest:
    """A sky camera's latest reading: level, category, message, and the smoothed level; the
    message and the smoothed level only while the reading is current (taken in the last 3 h)."""
    place, found = air.latest(session, camera_id)
    return _latest_out(place, found, policy.now())


@router.get("/latest", response_model=list[AirLatest], responses={**NOT_FOUND, **UNPROCESSABLE})
async def latest_of_every_camera(
    request: Request,
    policy: PolicyDep,
    camera_id: IdsFilter = None,
    limit: Limit = 1000,
    offset: Offset = 0,
) -> list[AirLatest]:
    """Every sky camera in service, by id, with its latest reading as ``/cameras/{id}/latest``
    gives it (a dashboard's list of the city's cameras in one request, not one per camera);
    with ``camera_id``, those cameras (a district's)."""
    rows = await public_read(
        request, partial(air.latest_of_every, limit=limit, offset=offset, camera_ids=camera_id)
    )
    now = policy.now()
    return [_latest_out(place, found, now) for place, found in rows]


def _latest_out(
    place: air.Place, found: tuple[Frame, SkyVerdict] | None, now: datetime
) -> AirLatest:
    if found is None:
        return AirLatest(
            camera_id=place.camera_id,
            name=place.name,
            lat=place.lat,
            lon=place.lon,
            level=None,
            category=None,
            message=None,
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
    public = v.smoothed_level
    level = airquality.rounded(public) if public is not None else None
    category = airquality.category(public) if public is not None else None
    return AirLatest(
        camera_id=place.camera_id,
        name=place.name,
        lat=place.lat,
        lon=place.lon,
        level=level,
        category=category,
        message=_message(category, current, v),
        captured_at=frame.captured_at,
        smoothed_level=public if current else None,
        smoothed_category=category if current else None,
        frame_level=v.level,
        frame_category=v.category,
        uncertain=v.uncertain,
        span=v.span if current else None,
        estimate=estimate_out(v),
        reason=v.reason
        if current
        else f"no reading in the last 3 hours: the latest was taken {_ago(age)}",
        current=current,
    )


def _ago(age: timedelta) -> str:
    """How long ago, as a person says it: hours up to two days, then days."""
    hours = age / timedelta(hours=1)
    return f"{hours:.0f} h ago" if hours < 48 else f"{age / timedelta(days=1):.0f} days ago"


def _message(category: str | None, current: bool, v: SkyVerdict) -> str | None:
    """The public message: today's category; when the camera has no current public level
    because its latest frames are uncertain, that it is not sure, not a guess, and which
    categories its latest frame is torn between."""
    if current and category:
        return airquality.message(category)
    if current and v.uncertain and v.span:
        return (
            "No current reading: the camera is not sure whether the air is "
            f"{airquality.span_words(v.span)}"
        )
    if current and v.uncertain:
        return "No current reading: the camera cannot judge the air with confidence now"
    return None


SKY_WIDTH = 480
"""Width of the public sky picture at most [px]."""


@router.get(
    "/cameras/{camera_id}/sky.jpg",
    response_class=Response,
    responses={200: {"content": {"image/jpeg": {}}}, **NOT_FOUND},
)
async def sky_picture(request: Request, camera_id: CameraId, session: SessionDep) -> Response:
    """The sky region of the camera's latest reading (at most 480 px wide): what the map's
    popup shows beside the level. Only the region the camera measures (its bounding box),
    never its street: a camera without a region (``roi``) publishes no picture (404)."""
    place, found = await run_in_threadpool(air.latest, session, camera_id)
    if found is None or found[0].stored_path is None:
        raise NotFound(f"no stored frame of sky camera {place.camera_id!r}")
    frame, verdict = found
    if verdict.roi is None:
        raise NotFound(
            f"sky camera {place.camera_id!r} measures its whole view (no roi): only a sky "
            "region is published, never a street"
        )
    data = await request.app.state.bounded_store.read(frame.stored_path)
    if data is None:
        raise NotFound(f"the latest frame of {place.camera_id!r} is no longer kept")
    body = await image_work(request, _sky_crop, data, verdict.roi)
    return Response(body, media_type="image/jpeg", headers={"Cache-Control": "public, max-age=60"})


def _sky_crop(data: bytes, region: Any) -> bytes:
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


CSV_CONTENT = {
    "text/csv": {
        "schema": {"type": "string"},
        "example": "camera_id,frame_id,captured_at,level,category,smoothed_level,reason,"
        "uncertain,estimate,estimate_low,estimate_high,estimate_unit,calibration_id\r\n",
    }
}


@router.get(
    "/readings",
    response_model=list[AirReading] | list[AirAggregate],
    responses={200: {"content": CSV_CONTENT}, **NOT_FOUND, **UNPROCESSABLE},
)
async def readings(
    request: Request,
    response: Response,
    session: SessionDep,
    span: TimeRangeQuery,
    camera_id: IdsFilter = None,
    aggregate: Annotated[Literal["none", "hourly", "daily"], Query()] = "none",
    tz: Annotated[
        str,
        Query(
            max_length=64,
            description="IANA time zone of the hourly and daily buckets (Asia/Kolkata).",
        ),
    ] = "UTC",
    limit: Annotated[int, Query(ge=1, le=10_000)] = 100,
    offset: Annotated[
        int,
        Query(
            ge=0,
            le=PUBLIC_MAX_OFFSET,
            description="Rows to skip (at most 100,000: page further with `cursor`).",
        ),
    ] = 0,
    cursor: FrameCursor = None,
    format: Annotated[
        Literal["json", "csv"],
        Query(
            description="csv: the same rows as a CSV table with a header (for a spreadsheet: "
            "Google Sheets' IMPORTDATA, Excel's From Web), paged alike."
        ),
    ] = "json",
) -> list[AirReading] | list[AirAggregate] | Response:
    """Readings newest first, paginated; or their hourly or daily means, over every reading
    in the range, in the time zone ``tz`` (its local hours and days; UTC by default).

    A full page of readings names the next in its ``Link: <…>; rel="next"`` header (a
    ``cursor``): each page then costs the same however deep, and readings arriving meanwhile
    shift nothing (with ``offset`` they push rows onto the next page again)."""
    since, until = span.since, span.until
    zone = _zone(tz)
    if cursor is not None and aggregate != "none":
        raise Unprocessable("cursor pages readings, not aggregates: use offset")
    if aggregate == "none":
        rows = await run_in_threadpool(
            partial(
                air.readings,
                session,
                camera_ids=camera_id,
                since=since,
                until=until,
                limit=limit,
                offset=offset,
                cursor=cursor,
            )
        )
        link_next(request, response, rows, limit)
        out = [
            AirReading(
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
            )
            for r in rows
        ]
        if format == "csv":
            return _csv_response(out, list(AirReading.model_fields), response)
        return out
    buckets = await public_work(  # every reading of the range: seconds for a city's month
        request,
        air.aggregate,
        camera_ids=camera_id,
        since=since,
        until=until,
        bucket=aggregate,
        tz=zone,
    )
    means = [AirAggregate(**b) for b in buckets[offset : offset + limit]]
    if format == "csv":
        return _csv_response(means, list(AirAggregate.model_fields), response)
    return means


def _csv_response(
    rows: list[AirReading] | list[AirAggregate], fields: list[str], response: Response
) -> Response:
    """``rows`` as CSV with a header of ``fields``, each value as in the JSON answer (RFC 3339
    times in UTC; an empty cell for null), with the page's Link header."""
    out = io.StringIO()
    writer = csv.DictWriter(out, fieldnames=fields)
    writer.writeheader()
    writer.writerows(r.model_dump(mode="json") for r in rows)
    link = {"Link": response.headers["link"]} if "link" in response.headers else {}
    return Response(out.getvalue(), media_type="text/csv; charset=utf-8", headers=link)


def _zone(name: str) -> ZoneInfo:
    try:
        return ZoneInfo(name)
    except (ZoneInfoNotFoundError, ValueError):
        raise Unprocessable(
            f"unknown time zone {name!r}: give an IANA name such as Europe/Rome or Asia/Kolkata"
        ) from None


@router.post(
    "/alerts/test",
    response_model=WebhookTestOut,
    responses={**AUTH_ERRORS, 409: {"description": "No webhook is configured."}},
)
def try_alert_webhook(
    request: Request, settings: SettingsDep, policy: PolicyDep, _: Admin
) -> WebhookTestOut:
    """POST a test alert (``kind: "test"``, recorded nowhere) to ``VANTAGE_ALERT_WEBHOOK_URL``
    now, signed as every alert is, and say whether the receiver took it (a 2xx) or why not: a
    receiver and its signing secret can be checked before the air turns Poor."""
    if settings.alert_webhook_url is None:
        raise Conflict("no webhook is configured: set VANTAGE_ALERT_WEBHOOK_URL", code="no_webhook")
    key = request.app.state.webhook_key
    msg_id, error = platform_webhooks.send_test(settings.alert_webhook_url, policy.now(), key=key)
    return WebhookTestOut(
        webhook_id=msg_id, delivered=error is None, error=error, signed=key is not None
    )


@router.get(
    "/alerts",
    response_model=list[AirAlertOut],
    responses={**NOT_FOUND, **UNPROCESSABLE, 401: AUTH_ERRORS[401]},
)
def alerts(
    session: SessionDep,
    settings: SettingsDep,
    policy: PolicyDep,
    span: TimeRangeQuery,
    caller: OptionalPrincipal,
    camera_id: IdsFilter = None,
    kind: Annotated[
        Literal["raised", "cleared"] | None, Query(description="Only alerts of this kind.")
    ] = None,
    limit: Limit = 100,
    offset: Offset = 0,
) -> list[AirAlertOut]:
    """Alerts, newest first, made in [``since``, ``until``): ``raised`` when a camera's smoothed
    level entered Poor or Very Poor, ``cleared`` when, after that, it came back to 5.0 or
    better; with where each one's webhook delivery stands. Why the last delivery failed
    (``last_error``: the receiver's answer, a redirect's address) is the operator's to read:
    null without the admin token."""
    operator = caller is not None and caller.role == "admin"
    rows = air.alerts(
        session,
        camera_ids=camera_id,
        limit=limit,
        offset=offset,
        since=span.since,
        until=span.until,
        kind=kind,
    )
    now = policy.now()
    retry_for = timedelta(hours=settings.alert_retry_hours) if settings.alert_webhook_url else None
    return [
        AirAlertOut(
            id=a.id,
            camera_id=a.camera_id,
            frame_id=a.frame_id,
            created_at=a.created_at,
            kind=a.kind,
            smoothed_level=a.smoothed_level,
            category=a.category,
            delivered=a.delivered,
            attempts=a.attempts,
            delivery=webhooks.delivery(a, now, retry_for=retry_for),
            last_error=a.last_error if operator else None,
            next_attempt_at=a.next_attempt_at,
        )
        for a in rows
    ]


def _bbox(value: str | None) -> tuple[float, float, float, float] | None:
    if value is None:
        return None
    try:
        parts = tuple(float(v) for v in value.split(","))
        isopleths.check_bbox(parts)
    except isopleths.IsoplethError as exc:
        raise Unprocessable(str(exc)) from None
    except ValueError:
        raise Unprocessable("bbox must be minlon,minlat,maxlon,maxlat") from None
    x0, y0, x1, y1 = parts
    return x0, y0, x1, y1


Method = Annotated[Literal["idw", "kriging", "rbf"], Query(description="Interpolation.")]
Bbox = Annotated[str | None, Query(description="minlon,minlat,maxlon,maxlat [°].")]
Window = Annotated[int, Query(ge=60, le=30 * 86400, description="Readings of the last … [s].")]
Resolution = Annotated[int, Query(ge=8, le=512, description="Grid cells per side.")]
MaxDistance = Annotated[
    float,
    Query(
        gt=0, le=200_000, description="Leave cells farther than this from every camera empty [m]."
    ),
]


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


At = Annotated[
    UtcTime | None,
    Query(
        description="The map as it was at this time (RFC 3339): each camera's latest reading "
        "in the window before it. Default: now."
    ),
]


Layer = Annotated[
    Literal["levels", "uncertainty"],
    Query(
        description="levels: the category bands; uncertainty: how far to trust them, as bands "
        "of kriging's standard deviation [level] (method=kriging) or of the distance to the "
        "nearest camera [m] (idw, rbf)."
    ),
]


ANONYMOUS_RESOLUTION = 256
"""The finest map an anonymous caller may ask for: the grid is what a map's CPU grows with
(kriging at 512 cells a side took ~7.6 s, at 256 a quarter of that); a token lifts it to 512."""
ANONYMOUS_WINDOW = 86_400
"""The longest window of readings an anonymous map may gather [s] (a day; a past moment is
``at``): the readings' query grows with it; a token lifts it to 30 days."""


def _map_query(
    request: Request,
    bbox: Bbox = None,
    window: Window = 3600,
    method: Method = "idw",
    resolution: Resolution = 128,
    max_distance: MaxDistance = 5000.0,
    at: At = None,
    layer: Layer = "levels",
) -> MapQuery:
    """The map's parameters. For an anonymous caller, the resolution and window bounded
    (``ANONYMOUS_RESOLUTION``, ``ANONYMOUS_WINDOW``; 422 past them; max_distance, which costs
    little, keeps its own bound) and the parameters rounded so that nearby
    requests share the cache: the bbox outward to 0.01°, ``at`` down to the minute, the
    window to the minute, max_distance to 100 m, the resolution to a multiple of 16. A
    token given must be valid (401)."""
    box = _bbox(bbox)
    crowds: Crowds = request.app.state.crowds
    anonymous = crowds.anonymous(request.scope)
    if anonymous and request.headers.get("authorization"):
        get_principal(request)  # a token given must be valid (401)
        anonymous = False
    if anonymous:
        if resolution > ANONYMOUS_RESOLUTION:
            raise Unprocessable(
                f"resolution: at most {ANONYMOUS_RESOLUTION} without a token; got {resolution}"
            )
        if window > ANONYMOUS_WINDOW:
            raise Unprocessable(
                f"window: at most {ANONYMOUS_WINDOW} s without a token; got {window}"
            )
        if box is not None:
            box = (
                max(-180.0, math.floor(box[0] * 100) / 100),
                max(-90.0, math.floor(box[1] * 100) / 100),
                min(180.0, math.ceil(box[2] * 100) / 100),
                min(90.0, math.ceil(box[3] * 100) / 100),
            )
        at = at.replace(second=0, microsecond=0) if at is not None else None
        window = max(60, round(window / 60) * 60)
        max_distance = max(100.0, round(max_distance / 100) * 100.0)
        resolution = max(16, round(resolution / 16) * 16)
    return MapQuery(box, window, method, resolution, max_distance, at, layer)


MapQueryDep = Annotated[MapQuery, Depends(_map_query)]


def _window_start(at: datetime, window: int) -> datetime:
    """``window`` seconds before ``at``; the first instant of year 1 for a window reaching
    before it (``at=0001-01-01T00:00:00Z`` overflowed: a 500)."""
    try:
        return at - timedelta(seconds=window)
    except OverflowError:
        return datetime.min.replace(tzinfo=UTC)


@dataclass(frozen=True)
class MapData:
    """What a map is drawn from: the cameras' levels in the window [since, at] and the islands
    interpolated from them (none without any) over ``box`` (the bbox asked for, else the
    islands' together)."""

    stations: list[air.Station]
    islands: list[isopleths.Island]
    box: tuple[float, float, float, float] | None
    since: datetime
    at: datetime
    max_distance: float


def _field(session: Session, policy: Policy, q: MapQuery) -> MapData:
    now = policy.now()
    if q.at is not None and q.at > now:
        raise Unprocessable(f"at {q.at.isoformat()} lies in the future", code="bad_time")
    at = q.at or now
    since = _window_start(at, q.window)
    st = air.stations(session, since=since, until=at)
    if not st:
        return MapData(st, [], q.bbox, since, at, q.max_distance)
    lon = np.array([s.lon for s in st])
    lat = np.array([s.lat for s in st])
    try:
        found = isopleths.interpolate_islands(
            lon,
            lat,
            np.array([s.level for s in st]),
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
    return MapData(st, found, box, since, at, q.max_distance)


async def _cached_map(
    request: Request,
    key: tuple[object, ...],
    compute: Callable[[Session], bytes],
    media_type: str,
    *,
    compress: bool = False,
) -> Response:
    """The map for ``key``, computed at most once per ``VANTAGE_ISOPLETH_CACHE_SECONDS`` (as
    ``public_work``, one at a time; a kept map waits for none); 304 when the client's
    ``If-None-Match`` names it. With ``compress``, kept gzipped too, and sent so to clients
    that take it (compressed once, not at every poll)."""
    cache: MapCache = request.app.state.isopleth_cache
    kept = cache.kept(key)
    if kept is None:
        kept = await public_work(
            request, lambda session: cache.get(key, partial(compute, session), compress=compress)
        )
    headers = {"ETag": kept.etag, "Cache-Control": f"public, max-age={int(cache.ttl)}"}
    # Vary as the 200 would carry it (app.platform.http.compression adds it to a body sent as it is)
    varies = {"Vary": "Accept-Encoding"} if kept.gzipped is not None else {}
    if not_modified(request.headers.get("if-none-match"), kept.etag):
        return Response(status_code=304, headers={**headers, **varies})
    if kept.gzipped is not None and accepts_gzip(request.headers):
        # app.platform.http.compression passes a body already encoded as it is
        encoded = {**headers, **varies, "Content-Encoding": "gzip"}
        return Response(kept.gzipped, media_type=media_type, headers=encoded)
    return Response(kept.body, media_type=media_type, headers=headers)


MAP_RESPONSES: dict[int | str, dict[str, Any]] = {
    **UNPROCESSABLE,
    304: {"description": "Not modified: the map named by If-None-Match is current."},
}


@router.get(
    "/isopleths",
    response_class=Response,
    responses={**MAP_RESPONSES, 200: {"content": {"application/geo+json": {}}}},
)
async def isopleths_geojson(request: Request, policy: PolicyDep, q: MapQueryDep) -> Response:
    """City-wide category bands (RFC 7946 GeoJSON), one feature per category present: now,
    or as they were at ``at`` (``at`` in the answer says which).

    Kept for ``VANTAGE_ISOPLETH_CACHE_SECONDS`` (30): ``computed_at`` says when it was made,
    and its ETag answers ``If-None-Match`` with 304."""

    def compute(session: Session) -> bytes:
        m = _field(session, policy, q)
        off_map = air.unplaced(session, since=m.since, until=m.at)
        body = _geojson(m, off_map, policy.now(), q)
        return json.dumps(body, ensure_ascii=False, allow_nan=False, separators=(",", ":")).encode()

    return await _cached_map(
        request, ("geojson", q), compute, "application/geo+json", compress=True
    )


def _empty_reason(m: MapData, off_map: list[str], window: int) -> str | None:
    """Why a map has no bands, or None when it has some."""
    if any(np.isfinite(i.field.value).any() for i in m.islands):
        return None
    if m.stations:
        return (
            f"no cell of the bbox lies within max_distance ({m.max_distance:g} m) of a camera"
            " with a reading"
        )
    if off_map:
        return "the sky cameras with readings have no place (lat/lon) to draw them at"
    return (
        f"no sky camera has a graded reading in the {window} s before {m.at.isoformat()} (window)"
    )


def _geojson(m: MapData, off_map: list[str], now: datetime, q: MapQuery) -> dict[str, Any]:
    """The collection: the bands (or the uncertainty layer) of every island, one feature per
    band; the cameras; the islands; why nothing is drawn when nothing is; and warnings of
    cameras drawn in another category's band and of graded cameras with no place."""
    st, box, at = m.stations, m.box, m.at
    per_island = [
        isopleths.bands(i.field) if q.layer == "levels" else isopleths.uncertainty_bands(i.field)
        for i in m.islands
    ]
    features = isopleths.merged(per_island)
    own = [airquality.category(s.level) for s in st]
    drawn: list[str | None] = [None] * len(st)
    warnings = []
    for island in m.islands:
        idx = island.cameras
        found = isopleths.band_at(
            island.field,
            np.array([st[k].lon for k in idx]),
            np.array([st[k].lat for k in idx]),
        )
        for k, band in zip(idx.tolist(), found, strict=True):
            drawn[k] = band
    cell = None
    if m.islands:
        cell = [round(v, 1) for v in isopleths.cell_size_m(m.islands[0].field)]
        off = sum(1 for o, d in zip(own, drawn, strict=True) if d is not None and d != o)
        if off:
            warnings.append(
                f"{off} of {len(st)} cameras lie in the band of another category than their"
                f" own reading, with cells of {cell[0]:.0f} × {cell[1]:.0f} m: ask for a"
                " smaller bbox or a larger resolution (up to 512); cameras close together"
                " that disagree stay so at any resolution"
            )
    for n, island in enumerate(m.islands):
        if island.method != q.method:
            warnings.append(
                f"island {n + 1} has cameras at fewer than 3 places, which {q.method} needs:"
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
    kinds = {i.field.uncertainty_kind for i in m.islands}
    return {
        "type": "FeatureCollection",
        "features": features,
        "bbox": list(box) if box else None,
        "method": q.method,
        "layer": q.layer,
        "computed_at": now.isoformat(),
        "at": at.isoformat(),
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
            }
            for s, category, band in zip(st, own, drawn, strict=True)
        ],
        "islands": [
            {
                "bbox": list(i.bbox),
                "cell_m": [round(v, 1) for v in isopleths.cell_size_m(i.field)],
                "cells": [len(i.field.lon), len(i.field.lat)],
                "method": i.method,
                "camera_ids": [st[k].camera_id for k in i.cameras.tolist()],
            }
            for i in m.islands
        ],
        "cell_m": cell,
        "empty_reason": _empty_reason(m, off_map, q.window),
        "warnings": warnings,
        "uncertainty": None
        if not m.islands
        else {
            "kind": kinds.pop() if len(kinds) == 1 else "mixed",
            "max": max(float(np.nanmax(i.field.uncertainty)) for i in m.islands),
            "mean": float(
                np.nanmean(np.concatenate([i.field.uncertainty.ravel() for i in m.islands]))
            ),
        },
    }


@router.get(
    "/isopleths.png",
    response_class=Response,
    responses={**MAP_RESPONSES, 200: {"content": {"image/png": {}}}},
)
async def isopleths_png(request: Request, policy: PolicyDep, q: MapQueryDep) -> Response:
    """The map drawn (matplotlib): a panel per island with its bands, the cameras labelled
    with name and level, coordinates, a scale bar, a legend with units and what blank means;
    without readings, why not. Kept as the GeoJSON is."""
    from app.air.airmap import figure, png

    def compute(session: Session) -> bytes:
        m = _field(session, policy, q)
        off_map = air.unplaced(session, since=m.since, until=m.at)
        return png(
            figure(
                m.islands,
                m.stations,
                m.at,
                layer=q.layer,
                max_distance=q.max_distance,
                empty_reason=_empty_reason(m, off_map, q.window),
            )
        )

    return await _cached_map(request, ("png", q), compute, "image/png")
