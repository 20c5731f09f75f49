"""A sky camera's readings (public): the latest, the sky picture, the history."""

from __future__ import annotations

import csv
import io
from functools import partial
from typing import Annotated, Literal
from zoneinfo import ZoneInfo, ZoneInfoNotFoundError

from fastapi import APIRouter, Query, Request
from fastapi.concurrency import run_in_threadpool
from fastapi.responses import Response

from app.air.schemas import (
    AirAggregate,
    AirLatest,
    AirReading,
)
from app.air.services import readings as sky_readings
from app.platform.frames.deps import FrameCursor, link_next
from app.platform.http.deps import (
    CameraId,
    IdsFilter,
    Limit,
    Offset,
    SessionDep,
    SettingsDep,
    TimeRangeQuery,
    TimingDep,
    UtcTime,
    image_work,
    public_read,
    public_work,
)
from app.platform.http.errors import (
    NotFound,
    Unprocessable,
)
from app.platform.http.responses import (
    NOT_FOUND,
    UNPROCESSABLE,
)
from app.platform.state import app_state

router = APIRouter(prefix="/air", tags=["air quality"])


PUBLIC_MAX_OFFSET = 100_000
"""The deepest ``offset`` of a public listing: each row skipped is read, and a deeper page of
a city's readings is a cursor's job."""


Moment = Annotated[
    UtcTime | None,
    Query(
        description="The reading as it was at this moment (RFC 3339), within the history kept "
        "(422 before it or in the future). Default: now."
    ),
]


@router.get(
    "/cameras/{camera_id}/latest",
    response_model=AirLatest,
    responses={**NOT_FOUND, **UNPROCESSABLE},
)
def latest(
    camera_id: CameraId,
    session: SessionDep,
    timing: TimingDep,
    settings: SettingsDep,
    at: Moment = None,
) -> AirLatest:
    """A sky camera's public reading: the most probable category, its probability, the
    estimate and its range, and what the screen says; the smoothed figures only while the
    latest reading is current (taken in the 3 h before now, or before ``at``)."""
    moment = sky_readings.check_moment(at, timing.now(), sky_readings.kept_days_of(settings))
    place, found = sky_readings.latest_of(session, camera_id, at)
    return sky_readings.latest_out(place, found, moment)


@router.get("/latest", response_model=list[AirLatest], responses={**NOT_FOUND, **UNPROCESSABLE})
async def latest_of_every_camera(
    request: Request,
    timing: TimingDep,
    settings: SettingsDep,
    camera_id: IdsFilter = None,
    limit: Limit = 1000,
    offset: Offset = 0,
    at: Moment = None,
) -> list[AirLatest]:
    """Every sky camera in service, by id, with its latest reading as ``/cameras/{id}/latest``
    gives it (a dashboard's list of the city's cameras in one request, not one per camera);
    with ``camera_id``, those cameras (a district's); with ``at``, as they were then."""
    moment = sky_readings.check_moment(at, timing.now(), sky_readings.kept_days_of(settings))
    rows = await public_read(
        request,
        partial(
            sky_readings.latest_of_every,
            limit=limit,
            offset=offset,
            camera_ids=camera_id,
            at=at,
        ),
    )
    return [sky_readings.latest_out(place, found, moment) for place, found in rows]


@router.get(
    "/cameras/{camera_id}/sky.jpg",
    response_class=Response,
    responses={200: {"content": {"image/jpeg": {}}}, **NOT_FOUND},
)
async def sky_picture(request: Request, camera_id: CameraId, session: SessionDep) -> Response:
    """The sky region of the camera's latest reading (at most 480 px wide): what the map's
    popup shows beside the level. Only the region the camera measures (its bounding box),
    never its street: a camera without a region (``roi``) publishes no picture (404)."""
    place, found = await run_in_threadpool(sky_readings.latest_of, session, camera_id)
    if found is None or found[0].stored_path is None:
        raise NotFound(f"no stored frame of sky camera {place.camera_id!r}")
    frame, verdict = found
    if verdict.roi is None:
        raise NotFound(
            f"sky camera {place.camera_id!r} measures its whole view (no roi): only a sky "
            "region is published, never a street"
        )
    assert frame.stored_path is not None  # refused above
    data = await app_state(request).bounded_store.read(frame.stored_path)
    if data is None:
        raise NotFound(f"the latest frame of {place.camera_id!r} is no longer kept")
    body = await image_work(request, sky_readings.sky_crop, data, verdict.roi)
    return Response(body, media_type="image/jpeg", headers={"Cache-Control": "public, max-age=60"})


CSV_CONTENT = {
    "text/csv": {
        "schema": {"type": "string"},
        "example": "camera_id,frame_id,captured_at,level,category,smoothed_level,reason,"
        "uncertain,estimate,estimate_low,estimate_high,estimate_unit,calibration_id,"
        "probability,smoothed_estimate,smoothed_low,smoothed_high,smoothed_probability,"
        "poor_probability\r\n",
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
                sky_readings.readings,
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
        out = [sky_readings.reading_out(r) for r in rows]
        if format == "csv":
            return _csv_response(out, list(AirReading.model_fields), response)
        return out
    buckets = await public_work(  # every reading of the range: seconds for a city's month
        request,
        sky_readings.aggregate,
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
