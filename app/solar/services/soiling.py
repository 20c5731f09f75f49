"""Soiling in energy and money: a panel's soiling ratio from its output, the farm's prices,
whether cleaning pays, and the cleaning trigger that weighs it (``core.soiling``)."""

from __future__ import annotations

from dataclasses import dataclass
from datetime import UTC, date, datetime, timedelta
from typing import Any

import numpy as np
from sqlalchemy.orm import Session

from app.solar.core import soiling
from app.solar.models import Panel, SolarEconomics
from app.solar.schemas import EconomicsIn
from app.solar.services import energy
from app.solar.services.lookup import get_panel

GATE_WINDOW = timedelta(days=400)
"""The output the cleaning trigger weighs: it runs on a camera's verdict, in the ingest's
transaction, and a decade of output takes 18 ms to analyse (400 days, 2 ms); 400 days hold
the current soiling interval and those before it that give a short one its clean level."""

RECENT = timedelta(days=7)
"""Output older than this does not weigh in the cleaning trigger: the panel's camera does."""


def economics(session: Session) -> SolarEconomics | None:
    return session.get(SolarEconomics, 1)


def put_economics(session: Session, data: EconomicsIn, now: datetime) -> SolarEconomics:
    """Set the farm's prices and trigger (replacing what was set)."""
    row = economics(session)
    if row is None:
        row = SolarEconomics(id=1, updated_at=now, **data.model_dump())
        session.add(row)
    else:
        for field, value in data.model_dump().items():
            setattr(row, field, value)
        row.updated_at = now
    session.flush()
    return row


def per_panel_cost(row: SolarEconomics) -> float:
    """What cleaning one panel costs: a visit's cost shared by the panels it cleans."""
    return row.cleaning_cost / (row.panels_per_visit if row.cost_per == "visit" else 1)


@dataclass(frozen=True, slots=True)
class Report:
    panel_id: str
    days: int
    series: energy.Series
    analysis: soiling.Analysis | None
    recommendation: soiling.Recommendation | None
    economics: SolarEconomics | None
    reason: str | None


def report(
    session: Session, panel_id: str, *, at: date | None = None, since: date | None = None
) -> Report:
    """The panel's soiling from its output in [since, at] (by default all of it). 404 for an
    unknown panel."""
    get_panel(session, panel_id)
    given = energy.series(session, panel_id, since=since, until=at)
    prices = economics(session)
    if given.days.size == 0:
        return Report(panel_id, 0, given, None, None, prices, "no output stored for this panel")
    found = soiling.analyse(
        given.days,
        given.kwh,
        given.expected,
        cleanings=energy.cleanings(session, panel_id),
        rain_mm=given.rain_mm,
    )
    if found.current is None:
        why = (
            f"too few days of usable output since {_iso(found)} "
            f"to measure soiling (it takes {soiling.MIN_DAYS})"
        )
        return Report(panel_id, int(given.days.size), given, found, None, prices, why)
    rec = None
    if prices is not None:
        rec = soiling.recommend(
            found.current,
            price_per_kwh=prices.energy_price_per_kwh,
            cleaning_cost=per_panel_cost(prices),
        )
    return Report(panel_id, int(given.days.size), given, found, rec, prices, None)


def _iso(found: soiling.Analysis) -> str:
    return date.fromordinal(found.intervals[-1].start).isoformat()


@dataclass(frozen=True, slots=True)
class Gate:
    open: bool
    """Open the cleaning task."""
    evidence: str
    """What decided, for the task and the verdict."""


def gate(session: Session, panel: Panel, today: date, *, dirty: int) -> Gate:
    """Whether the cameras' ``dirty`` verdicts in a row open a cleaning task: always under the
    ``camera`` trigger; under ``camera_and_pays``, when the panel has no output in the last
    ``RECENT`` days, or too little to measure, or when its output says cleaning pays."""
    camera = f"camera: {dirty} dirty verdicts in a row"
    prices = economics(session)
    if prices is None or prices.trigger != "camera_and_pays":
        return Gate(True, camera)
    last = energy.last_day(session, panel.id)
    if last is None or last < today - RECENT:
        return Gate(True, f"{camera}; no output in the last {RECENT.days} days to weigh")
    found = report(session, panel.id, since=today - GATE_WINDOW)
    if found.recommendation is None:
        return Gate(True, f"{camera}; {found.reason or 'output too short to weigh'}")
    rec = found.recommendation
    return Gate(rec.clean, f"{camera}; output: {rec.reason}")


def daily(found: Report) -> dict[date, dict[str, Any]]:
    """Each day's energy, performance index and fitted ratio with its band, and whether a
    soiling interval began on it (a cleaning), for the history."""
    given, analysis = found.series, found.analysis
    out: dict[date, dict[str, Any]] = {}
    for n, day in enumerate(given.days.tolist()):
        out[date.fromordinal(day)] = {
            "kwh": float(given.kwh[n]),
            "expected_kwh": float(given.expected[n]),
        }
    if analysis is None:
        return out
    starts = {i.start for i in analysis.intervals if i.cause != "start"}
    for n, day in enumerate(analysis.days.tolist()):
        out[date.fromordinal(day)] |= {
            "performance_index": _num(analysis.pi[n]) if analysis.used[n] else None,
            "soiling_ratio": _num(analysis.ratio[n]),
            "soiling_low": _num(analysis.low[n]),
            "soiling_high": _num(analysis.high[n]),
            "cleaned": day in starts,
        }
    return out


def _num(value: float) -> float | None:
    return float(value) if np.isfinite(value) else None


EMPTY_BUCKET: dict[str, Any] = {
    "frames": 0,
    "clean": 0,
    "dirty": 0,
    "not_judged": 0,
    "t2_mean": None,
    "t2_max": None,
    "p_value_min": None,
    "p_dirty_mean": None,
}


def with_output(
    session: Session,
    panel_id: str,
    buckets: list[dict[str, Any]],
    *,
    since: datetime | None,
    until: datetime | None,
) -> list[dict[str, Any]]:
    """Day buckets of the cameras' verdicts joined with the output's days in [since, until):
    a day with output and no frames gets a bucket of its own (the camera and the output side
    by side). The ratio is of the analysis of all the output up to ``until``."""
    found = report(session, panel_id, at=until.date() if until is not None else None)
    days = daily(found)
    by_day = {b["start"].date(): b for b in buckets}
    for day, values in days.items():
        start = datetime(day.year, day.month, day.day, tzinfo=UTC)
        if since is not None and start + timedelta(days=1) <= since:
            continue
        if until is not None and start >= until:
            continue
        bucket = by_day.get(day)
        if bucket is None:
            bucket = {"start": start, "end": start + timedelta(days=1), **EMPTY_BUCKET}
            by_day[day] = bucket
        bucket |= values
    return [by_day[d] for d in sorted(by_day)]
