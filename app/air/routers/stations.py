"""Reference stations: register them (admin), import their readings (admin), read both
(public)."""

from __future__ import annotations

from functools import partial
from typing import Annotated

from fastapi import APIRouter, Path, Query, Request
from fastapi.concurrency import run_in_threadpool
from fastapi.responses import Response

from app.air.schemas import (
    ReadingsStored,
    RollingOut,
    StationCreate,
    StationOut,
    StationReadingOut,
    StationUpdate,
)
from app.air.services import rolling, stations
from app.platform.http.deps import (
    ID_PATTERN,
    Admin,
    Limit,
    Offset,
    SessionDep,
    SettingsDep,
    TimeRangeQuery,
    TimingDep,
)
from app.platform.http.errors import UnsupportedMediaType
from app.platform.http.responses import AUTH_ERRORS, BODY_ERRORS, CONFLICT, NOT_FOUND, UNPROCESSABLE
from app.platform.http.uploads import content_type, read_capped
from app.platform.state import app_state

router = APIRouter(prefix="/air", tags=["air quality"])

StationId = Annotated[str, Path(pattern=ID_PATTERN, description="Station id.")]


def _out(station: object, latest: stations.Latest | None) -> StationOut:
    out = StationOut.model_validate(station)
    out.latest = StationReadingOut(at=latest.at, pm25=latest.pm25) if latest else None
    return out


@router.post(
    "/stations",
    status_code=201,
    response_model=StationOut,
    responses={**AUTH_ERRORS, **CONFLICT, **UNPROCESSABLE},
)
def create_station(
    body: StationCreate, session: SessionDep, timing: TimingDep, _: Admin
) -> StationOut:
    """Register a reference station (a monitor of PM2.5) where it stands; 409 for an id in
    use."""
    return _out(stations.create(session, body, timing.now()), None)


@router.post(
    "/stations/recalibrate", response_model=RollingOut, responses={**AUTH_ERRORS, **UNPROCESSABLE}
)
async def recalibrate_now(
    request: Request, settings: SettingsDep, timing: TimingDep, _: Admin
) -> RollingOut:
    """Run a rolling calibration now (as ``VANTAGE_AIR_RECALIBRATE_HOURS`` does on its
    schedule): every located sky camera with a station within ``VANTAGE_AIR_STATION_KM``
    calibrated from the readings of the last ``VANTAGE_AIR_RECALIBRATE_DAYS``, each flagged
    ``recalibrate`` (its ``attention``) when its readings had drifted from its station's."""
    job = partial(
        rolling.recalibrate_all,
        app_state(request).sessionmaker,
        timing,
        days=settings.air_recalibrate_days,
        max_km=settings.air_station_km,
    )
    done = await run_in_threadpool(job)
    return RollingOut(recalibrated=done.recalibrated, drifting=done.drifting, skipped=done.skipped)


@router.get("/stations", response_model=list[StationOut])
def list_stations(session: SessionDep, limit: Limit = 1000, offset: Offset = 0) -> list[StationOut]:
    """Every station by id, with its newest reading."""
    return [_out(s, latest) for s, latest in stations.listing(session, limit=limit, offset=offset)]


@router.get("/stations/{station_id}", response_model=StationOut, responses=NOT_FOUND)
def get_station(station_id: StationId, session: SessionDep) -> StationOut:
    station = stations.get(session, station_id)
    return _out(station, stations.latest_of(session, [station.id])[0])


@router.patch(
    "/stations/{station_id}",
    response_model=StationOut,
    responses={**AUTH_ERRORS, **NOT_FOUND, **UNPROCESSABLE},
)
def update_station(
    station_id: StationId, body: StationUpdate, session: SessionDep, _: Admin
) -> StationOut:
    """Rename or move a station (the fields given)."""
    station = stations.update(session, station_id, body)
    return _out(station, stations.latest_of(session, [station.id])[0])


@router.delete(
    "/stations/{station_id}",
    status_code=204,
    response_class=Response,
    responses={**AUTH_ERRORS, **NOT_FOUND},
)
def delete_station(station_id: StationId, session: SessionDep, _: Admin) -> Response:
    """Remove a station and its readings."""
    stations.remove(session, station_id)
    return Response(status_code=204)


@router.post(
    "/stations/{station_id}/readings",
    response_model=ReadingsStored,
    responses={**AUTH_ERRORS, **NOT_FOUND, **BODY_ERRORS, **UNPROCESSABLE},
    openapi_extra={
        "requestBody": {
            "required": True,
            "content": {
                "application/json": {
                    "schema": {
                        "type": "array",
                        "items": {
                            "type": "object",
                            "properties": {
                                "at": {"type": "string", "format": "date-time"},
                                "pm25": {"type": "number", "minimum": 0},
                            },
                            "required": ["at", "pm25"],
                        },
                    }
                },
                "text/csv": {
                    "schema": {"type": "string"},
                    "example": "at,pm25\n2025-01-29T15:00:00Z,18.9\n",
                },
            },
        }
    },
)
async def import_readings(
    request: Request, station_id: StationId, session: SessionDep, settings: SettingsDep, _: Admin
) -> ReadingsStored:
    """Store a station's readings: a JSON list of ``{"at", "pm25"}``, or CSV with a header
    ``at,pm25``. A time already stored takes the new value (an import can be sent again);
    a bad row refuses the whole import (422 naming it), storing nothing."""
    kind = content_type(request)
    body = await read_capped(request, settings.max_body_bytes)
    if kind == "application/json":
        given = stations.parse_json(body)
    elif kind in ("text/csv", "text/plain"):
        given = stations.parse_csv(body.decode("utf-8", errors="replace"))
    else:
        raise UnsupportedMediaType("send application/json or text/csv (at,pm25)")
    stored = await run_in_threadpool(stations.store, session, station_id, given)
    return ReadingsStored(station_id=station_id, stored=stored)


@router.get(
    "/stations/{station_id}/readings",
    response_model=list[StationReadingOut],
    responses={**NOT_FOUND, **UNPROCESSABLE},
)
def station_readings(
    station_id: StationId,
    session: SessionDep,
    span: TimeRangeQuery,
    limit: Annotated[int, Query(ge=1, le=10_000)] = 1000,
    offset: Offset = 0,
) -> list[StationReadingOut]:
    """The station's readings in [since, until), newest first, paged."""
    rows = stations.readings(
        session, station_id, since=span.since, until=span.until, limit=limit, offset=offset
    )
    return [StationReadingOut(at=r.at, pm25=r.pm25) for r in rows]
