"""A panel's output: its daily energy in, its soiling ratio and whether cleaning pays out, and
the farm's prices."""

from __future__ import annotations

import datetime as dt
from typing import Annotated

from fastapi import APIRouter, Query, Request
from fastapi.concurrency import run_in_threadpool

from app.platform.http.deps import (
    Admin,
    PanelId,
    Reader,
    SessionDep,
    SettingsDep,
    TimingDep,
)
from app.platform.http.errors import NotFound, UnsupportedMediaType
from app.platform.http.responses import (
    AUTH_ERRORS,
    BODY_ERRORS,
    NOT_FOUND,
    PANEL_RETIRED,
    UNPROCESSABLE,
)
from app.platform.http.uploads import content_type, read_capped
from app.solar.models import SolarEconomics
from app.solar.schemas import (
    EconomicsIn,
    EconomicsOut,
    EnergyDayOut,
    EnergyStored,
    RecommendationOut,
    SoilingIntervalOut,
    SoilingOut,
)
from app.solar.services import energy, soiling

router = APIRouter(tags=["energy"])

_DAY = {
    "type": "object",
    "properties": {
        "date": {"type": "string", "format": "date"},
        "kwh": {"type": "number", "minimum": 0},
        "expected_kwh": {"type": "number", "minimum": 0},
        "poa_kwh_m2": {"type": "number", "minimum": 0},
        "ghi_kwh_m2": {"type": "number", "minimum": 0},
        "rain_mm": {"type": "number", "minimum": 0},
    },
    "required": ["date", "kwh"],
}


@router.post(
    "/panels/{panel_id}/energy",
    response_model=EnergyStored,
    responses={**AUTH_ERRORS, **NOT_FOUND, **PANEL_RETIRED, **BODY_ERRORS, **UNPROCESSABLE},
    openapi_extra={
        "requestBody": {
            "required": True,
            "content": {
                "application/json": {"schema": {"type": "array", "items": _DAY}},
                "text/csv": {
                    "schema": {"type": "string"},
                    "example": "date,kwh,expected_kwh\n2026-06-01,1.92,2.05\n",
                },
            },
        }
    },
)
async def import_energy(
    request: Request,
    panel_id: PanelId,
    session: SessionDep,
    settings: SettingsDep,
    timing: TimingDep,
    _: Admin,
) -> EnergyStored:
    """Store a panel's daily energy: a JSON list of ``{"date", "kwh", "expected_kwh"}`` (or
    ``poa_kwh_m2``/``ghi_kwh_m2`` for pvlib to model the expected energy, and ``rain_mm``), or
    CSV with those columns. A day sent again replaces the stored one; a bad day refuses the
    whole import (422 naming it), storing nothing."""
    kind = content_type(request)
    body = await read_capped(request, settings.max_body_bytes)
    today = timing.now().date()
    if kind == "application/json":
        given = energy.parse_json(body, today)
    elif kind in ("text/csv", "text/plain"):
        given = energy.parse_csv(body.decode("utf-8", errors="replace"), today)
    else:
        raise UnsupportedMediaType("send application/json or text/csv (date,kwh,expected_kwh)")
    done = await run_in_threadpool(energy.store, session, panel_id, given, timing.now())
    return EnergyStored(
        panel_id=panel_id,
        stored=done.stored,
        modelled=done.modelled,
        first=done.first,
        last=done.last,
    )


@router.get(
    "/panels/{panel_id}/energy",
    response_model=list[EnergyDayOut],
    responses={**AUTH_ERRORS, **NOT_FOUND, **UNPROCESSABLE},
)
def read_energy(
    panel_id: PanelId,
    session: SessionDep,
    _: Reader,
    since: Annotated[dt.date | None, Query(description="First day.")] = None,
    until: Annotated[dt.date | None, Query(description="Last day.")] = None,
) -> list[EnergyDayOut]:
    """The panel's stored days in [since, until], oldest first (at most 40,000)."""
    return [EnergyDayOut.model_validate(r) for r in energy.rows(session, panel_id, since, until)]


@router.get(
    "/panels/{panel_id}/soiling",
    response_model=SoilingOut,
    responses={**AUTH_ERRORS, **NOT_FOUND, **UNPROCESSABLE},
)
def panel_soiling(
    panel_id: PanelId,
    session: SessionDep,
    _: Reader,
    at: Annotated[
        dt.date | None, Query(description="Analyse the output up to this day (default: all).")
    ] = None,
) -> SoilingOut:
    """The panel's soiling ratio from its output, with its 95 % interval, the energy it loses,
    the soiling intervals found, and whether cleaning pays (with the farm's prices)."""
    found = soiling.report(session, panel_id, at=at)
    return _soiling_out(found)


def _soiling_out(found: soiling.Report) -> SoilingOut:
    analysis, prices = found.analysis, found.economics
    now = analysis.current if analysis is not None else None
    rec = found.recommendation
    iso = dt.date.fromordinal
    return SoilingOut(
        panel_id=found.panel_id,
        as_of=iso(int(found.series.days[-1])) if found.series.days.size else None,
        soiling_ratio=now.ratio if now else None,
        low=now.low if now else None,
        high=now.high if now else None,
        rate_per_day=now.rate if now else None,
        loss_kwh_per_day=now.loss_kwh_per_day if now else None,
        loss_since_cleaning_kwh=now.loss_since_cleaning_kwh if now else None,
        since_cleaning_days=now.day - now.since if now else None,
        last_cleaning=iso(now.since) if now and now.cause != "start" else None,
        days=found.days,
        intervals=[
            SoilingIntervalOut(
                start=iso(i.start),
                end=iso(i.end),
                cause=i.cause,
                days=i.days,
                rate_per_day=i.rate,
                rate_low=i.rate_low,
                rate_high=i.rate_high,
            )
            for i in (analysis.intervals if analysis else [])
        ],
        recommendation=None
        if rec is None or prices is None
        else RecommendationOut(
            clean=rec.clean,
            by=iso(rec.by) if rec.by is not None else None,
            reason=rec.reason,
            optimal_interval_days=rec.optimal_days,
            lost_value=rec.lost_value,
            cleaning_cost=soiling.per_panel_cost(prices),
            currency=prices.currency,
        ),
        reason=found.reason
        or (None if prices else "no prices set: PUT /solar/economics to weigh cleaning"),
    )


def _economics_out(row: SolarEconomics) -> EconomicsOut:
    return EconomicsOut(
        energy_price_per_kwh=row.energy_price_per_kwh,
        cleaning_cost=row.cleaning_cost,
        cost_per=row.cost_per,
        panels_per_visit=row.panels_per_visit,
        currency=row.currency,
        trigger=row.trigger,
        per_panel_cost=soiling.per_panel_cost(row),
        updated_at=row.updated_at,
    )


@router.put(
    "/solar/economics",
    response_model=EconomicsOut,
    responses={**AUTH_ERRORS, **UNPROCESSABLE},
)
def put_economics(
    body: EconomicsIn, session: SessionDep, timing: TimingDep, _: Admin
) -> EconomicsOut:
    """Set what the farm's energy is worth, what a cleaning costs (a panel's, or a robot
    visit's shared by the panels it cleans) and whether the cleaning trigger weighs them."""
    return _economics_out(soiling.put_economics(session, body, timing.now()))


@router.get("/solar/economics", response_model=EconomicsOut, responses={**AUTH_ERRORS, **NOT_FOUND})
def get_economics(session: SessionDep, _: Reader) -> EconomicsOut:
    """The farm's prices and cleaning trigger; 404 before they are set."""
    row = soiling.economics(session)
    if row is None:
        raise NotFound("no prices set: PUT /solar/economics")
    return _economics_out(row)
