"""A panel's daily energy: imported from JSON or CSV, modelled by pvlib where the expected
energy is not given, stored one row a day, read back as arrays for the soiling analysis."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from datetime import date, datetime, timedelta

import numpy as np
from numpy.typing import NDArray
from pydantic import TypeAdapter, ValidationError
from sqlalchemy import func, select
from sqlalchemy.dialects import postgresql, sqlite
from sqlalchemy.orm import Session

from app.platform.frames.cameras import check_in_service
from app.platform.http.errors import Unprocessable
from app.platform.http.uploads import csv_models, item_error
from app.solar.core import expected
from app.solar.models import CleaningTask, EnergyDay, Panel
from app.solar.schemas import EnergyDayIn
from app.solar.services.lookup import get_panel

MAX_DAYS = 40_000
"""Days one import takes at most (a century of one panel; a farm's export goes per panel)."""

GHI_CHUNK = 2000
"""Days modelled from GHI at once: pvlib works on every hour of them, and 40,000 days at once
took 346 MB."""

FIRST_DAY = date(1980, 1, 1)
"""Output from before this is taken for a mistyped year."""

COLUMNS = ("date", "kwh", "expected_kwh", "poa_kwh_m2", "ghi_kwh_m2", "rain_mm")

_DAYS = TypeAdapter(list[EnergyDayIn])

Named = tuple[str, EnergyDayIn]
"""A day and where it was in the request (``days[3]``, ``line 5``), for the errors."""


def parse_json(body: bytes, today: date) -> list[Named]:
    """A JSON list of days; 422 naming the first bad day's field (``days[3].kwh``)."""
    try:
        days = _DAYS.validate_json(body)
    except ValidationError as exc:
        raise Unprocessable(item_error(exc, "days"), code="bad_energy") from None
    return _bounded(days, [f"days[{i}]" for i in range(len(days))], today)


def parse_csv(text: str, today: date) -> list[Named]:
    """CSV with a header naming ``date`` and ``kwh`` and optionally ``expected_kwh``,
    ``poa_kwh_m2``, ``ghi_kwh_m2``, ``rain_mm`` (other columns ignored, an empty cell is
    left out); 422 naming the first bad line and field."""
    rows = csv_models(
        text,
        EnergyDayIn,
        required=("date", "kwh"),
        columns=COLUMNS,
        code="bad_energy",
        limit=MAX_DAYS,
    )
    return _bounded([d for _, d in rows], [f"line {n}" for n, _ in rows], today)


def _bounded(days: list[EnergyDayIn], names: list[str], today: date) -> list[Named]:
    """At most ``MAX_DAYS``, each from ``FIRST_DAY`` to ``today`` (a day ahead allowed: the
    farm's today may be tomorrow in UTC)."""
    if len(days) > MAX_DAYS:
        raise Unprocessable(
            f"at most {MAX_DAYS} days an import: send them in parts", code="too_many_days"
        )
    latest = today + timedelta(days=1)
    for name, d in zip(names, days, strict=True):
        if not FIRST_DAY <= d.date <= latest:
            raise Unprocessable(
                f"{name}.date: {d.date} is not a day of output (from {FIRST_DAY} to today)",
                code="bad_energy",
            )
    return list(zip(names, days, strict=True))


@dataclass(frozen=True, slots=True)
class Stored:
    stored: int
    modelled: int
    first: date | None
    last: date | None


def _modelled(panel: Panel, named: Sequence[Named]) -> list[tuple[float, str]]:
    """Each day's expected energy [kWh] and where it came from; 422 naming the first day whose
    expected energy can be neither taken nor modelled."""
    names, days = [n for n, _ in named], [d for _, d in named]
    out: list[tuple[float, str] | None] = [None] * len(days)
    poa_at, ghi_at = [], []
    for i, d in enumerate(days):
        if d.expected_kwh is not None:
            out[i] = (d.expected_kwh, "given")
        elif d.poa_kwh_m2 is not None:
            poa_at.append(i)
        elif d.ghi_kwh_m2 is not None:
            ghi_at.append(i)
        else:
            raise Unprocessable(
                f"{names[i]}.expected_kwh: give expected_kwh, or poa_kwh_m2 or ghi_kwh_m2 for "
                "pvlib to model it",
                code="bad_energy",
            )
    if (poa_at or ghi_at) and panel.kwp is None:
        first = min(poa_at + ghi_at)
        field = "poa_kwh_m2" if first in poa_at else "ghi_kwh_m2"
        raise Unprocessable(
            f"{names[first]}.{field}: panel {panel.id!r} has no kwp to model its energy from "
            f"insolation: set it (PATCH /panels/{panel.id}) or send expected_kwh",
            code="panel_not_rated",
        )
    if poa_at:
        poa = np.array([days[i].poa_kwh_m2 for i in poa_at], dtype=np.float64)
        for i, e in zip(poa_at, expected.energy_from_poa(poa, panel.kwp or 0.0), strict=True):
            out[i] = (float(e), "poa")
    if ghi_at:
        unknown = [f for f in ("tilt", "azimuth", "lat", "lon") if getattr(panel, f) is None]
        if unknown:
            raise Unprocessable(
                f"{names[ghi_at[0]]}.ghi_kwh_m2: panel {panel.id!r} has no "
                f"{', '.join(unknown)} to turn horizontal insolation onto its plane: set them "
                f"(PATCH /panels/{panel.id}), or send poa_kwh_m2 or expected_kwh",
                code="panel_not_rated",
            )
        ordinals = np.array([days[i].date.toordinal() for i in ghi_at], dtype=np.int64)
        ghi = np.array([days[i].ghi_kwh_m2 for i in ghi_at], dtype=np.float64)
        poa = np.concatenate(
            [
                expected.poa_from_ghi(
                    ordinals[start : start + GHI_CHUNK],
                    ghi[start : start + GHI_CHUNK],
                    lat=panel.lat or 0.0,
                    lon=panel.lon or 0.0,
                    tilt=panel.tilt or 0.0,
                    azimuth=panel.azimuth or 0.0,
                )
                for start in range(0, len(ghi_at), GHI_CHUNK)
            ]
        )
        for i, e in zip(ghi_at, expected.energy_from_poa(poa, panel.kwp or 0.0), strict=True):
            out[i] = (float(e), "ghi")
    done = [o for o in out if o is not None]
    assert len(done) == len(days)
    return done


def store(session: Session, panel_id: str, named: Sequence[Named], now: datetime) -> Stored:
    """Store the days (a day stored already, or repeated within them, takes the last one).
    Everything is checked before anything is written. 404 for an unknown panel, 409 for a
    retired one."""
    panel = get_panel(session, panel_id)
    check_in_service(panel)
    last = {d.date: i for i, (_, d) in enumerate(named)}
    kept = [named[i] for i in sorted(last.values())]
    modelled = _modelled(panel, kept)
    rows = [
        {
            "panel_id": panel.id,
            "day": d.date,
            "kwh": d.kwh,
            "expected_kwh": e,
            "expected_from": source,
            "poa_kwh_m2": d.poa_kwh_m2,
            "ghi_kwh_m2": d.ghi_kwh_m2,
            "rain_mm": d.rain_mm,
            "received_at": now,
        }
        for (_, d), (e, source) in zip(kept, modelled, strict=True)
    ]
    insert = postgresql.insert if session.get_bind().dialect.name == "postgresql" else sqlite.insert
    for start in range(0, len(rows), 2000):
        stmt = insert(EnergyDay).values(rows[start : start + 2000])
        names = ("kwh", "expected_kwh", "expected_from", "poa_kwh_m2", "ghi_kwh_m2", "rain_mm")
        session.execute(
            stmt.on_conflict_do_update(
                index_elements=["panel_id", "day"],
                set_={**{n: stmt.excluded[n] for n in names}, "received_at": now},
            )
        )
    return Stored(
        stored=len(rows),
        modelled=sum(1 for _, source in modelled if source != "given"),
        first=min(last) if last else None,
        last=max(last) if last else None,
    )


@dataclass(frozen=True, slots=True)
class Series:
    days: NDArray[np.int64]
    """Proleptic ordinals, sorted."""
    kwh: NDArray[np.float64]
    expected: NDArray[np.float64]
    rain_mm: NDArray[np.float64]
    """NaN where not given."""


def series(
    session: Session, panel_id: str, *, since: date | None = None, until: date | None = None
) -> Series:
    """The panel's stored days in [since, until], oldest first."""
    q = select(EnergyDay.day, EnergyDay.kwh, EnergyDay.expected_kwh, EnergyDay.rain_mm).where(
        EnergyDay.panel_id == panel_id
    )
    if since is not None:
        q = q.where(EnergyDay.day >= since)
    if until is not None:
        q = q.where(EnergyDay.day <= until)
    rows = session.execute(q.order_by(EnergyDay.day)).all()
    return Series(
        days=np.array([r[0].toordinal() for r in rows], dtype=np.int64),
        kwh=np.array([r[1] for r in rows], dtype=np.float64),
        expected=np.array([r[2] for r in rows], dtype=np.float64),
        rain_mm=np.array([np.nan if r[3] is None else r[3] for r in rows], dtype=np.float64),
    )


def rows(
    session: Session, panel_id: str, since: date | None, until: date | None
) -> Sequence[EnergyDay]:
    """The panel's stored days in [since, until], oldest first, at most ``MAX_DAYS``. 404 for
    an unknown panel."""
    get_panel(session, panel_id)
    q = select(EnergyDay).where(EnergyDay.panel_id == panel_id)
    if since is not None:
        q = q.where(EnergyDay.day >= since)
    if until is not None:
        q = q.where(EnergyDay.day <= until)
    return session.scalars(q.order_by(EnergyDay.day).limit(MAX_DAYS)).all()


def last_day(session: Session, panel_id: str) -> date | None:
    return session.scalar(select(func.max(EnergyDay.day)).where(EnergyDay.panel_id == panel_id))


def cleanings(session: Session, panel_id: str) -> list[int]:
    """The first whole day after each of the panel's completed cleanings [ordinals], the
    cleanings the cameras did not find ineffective (the day of the cleaning itself is half
    dirty, half clean)."""
    done = session.scalars(
        select(CleaningTask.completed_at).where(
            CleaningTask.panel_id == panel_id,
            CleaningTask.completed_at.is_not(None),
            (CleaningTask.outcome.is_(None)) | (CleaningTask.outcome == "effective"),
        )
    ).all()
    return sorted({t.date().toordinal() + 1 for t in done if t is not None})
