"""``vantage energy import``: a farm's SCADA export, a column per panel or string, into the
panels' daily energy (``POST /panels/{id}/energy``)."""

from __future__ import annotations

import argparse
import math
from collections import defaultdict
from datetime import date, datetime
from pathlib import Path
from typing import Any

from rich.progress import Progress

from app.cli.common import Failed, Service, err, number, rows, say

CHUNK = 5000
"""Days sent in one request."""

TIME_COLUMNS = ("date", "day", "timestamp", "time", "datetime")
FARM_COLUMNS = ("poa_kwh_m2", "ghi_kwh_m2", "rain_mm")
"""Columns of the whole farm, summed by day and given to every panel."""
EXPECTED_SUFFIX = ":expected"
"""``p1:expected``: what panel p1 would have made clean, per row [kWh]."""


def _day(text: str, line: int) -> date:
    try:
        return datetime.fromisoformat(text.replace("Z", "+00:00")).date()
    except ValueError:
        raise Failed(f"row {line}: {text!r} is not a date or time (ISO 8601)") from None


def _columns(header: list[str], mapping: list[str]) -> tuple[str, dict[str, str]]:
    """The time column, and each energy column's panel: ``--panel COLUMN=PANEL`` where given,
    else every column not of time, the farm or expected energy, named by its panel's id."""
    when = next((c for c in header if c.lower() in TIME_COLUMNS), None)
    if when is None:
        raise Failed(f"the header names no time column ({', '.join(TIME_COLUMNS)})")
    if mapping:
        pairs = [m.split("=", 1) for m in mapping]
        if any(len(p) != 2 or p[0] not in header for p in pairs):
            raise Failed("--panel takes COLUMN=PANEL_ID with a column of the file")
        return when, {col: panel for col, panel in pairs}
    skip = {when, *FARM_COLUMNS}
    panels = {c: c for c in header if c not in skip and not c.endswith(EXPECTED_SUFFIX)}
    if not panels:
        raise Failed("the file has no column of a panel's energy")
    return when, panels


def daily(given: list[dict[str, str]], mapping: list[str]) -> dict[str, list[dict[str, Any]]]:
    """Each panel's days: its rows' energy (and expected energy, and the farm's insolation
    and rain) summed by the day of the time column. A day a panel has no value for is left
    out of it; a day with no expected energy nor insolation is refused by the service."""
    if not given:
        raise Failed("the file has no rows")
    when, panels = _columns(list(given[0]), mapping)
    sums: dict[str, dict[date, dict[str, float]]] = defaultdict(lambda: defaultdict(dict))
    farm: dict[date, dict[str, float]] = defaultdict(dict)
    for line, row in enumerate(given, start=2):
        day = _day(row.get(when, ""), line)
        for col in FARM_COLUMNS:
            value = number(row.get(col, ""), col, line)
            if value is not None:
                farm[day][col] = farm[day].get(col, 0.0) + value
        for col, panel in panels.items():
            values = {
                "kwh": number(row.get(col, ""), col, line),
                "expected_kwh": number(row.get(col + EXPECTED_SUFFIX, ""), col, line),
            }
            for key, value in values.items():
                if value is not None and not math.isfinite(value):
                    raise Failed(f"row {line}: {col} is {value}, not a measured energy")
                if value is not None:
                    sums[panel][day][key] = sums[panel][day].get(key, 0.0) + value
    out: dict[str, list[dict[str, Any]]] = {}
    for panel, days in sums.items():
        out[panel] = [
            {"date": d.isoformat(), **farm.get(d, {}), **v}
            for d, v in sorted(days.items())
            if "kwh" in v
        ]
    return out


def import_energy(service: Service, args: argparse.Namespace) -> None:
    """Send each panel's days, ``CHUNK`` at a time; a day already stored takes the file's."""
    per_panel = daily(rows(args.csv), args.panel or [])
    stored: dict[str, int] = {}
    with Progress(console=err) as progress:
        task = progress.add_task("days", total=sum(len(d) for d in per_panel.values()))
        for panel, days in per_panel.items():
            for start in range(0, len(days), CHUNK):
                part = days[start : start + CHUNK]
                try:
                    r = service.call("POST", f"/panels/{panel}/energy", json=part)
                except Failed as exc:  # name the panel's column, and the day
                    raise Failed(f"panel {panel}: {exc}") from None
                stored[panel] = stored.get(panel, 0) + int(r.json()["stored"])
                progress.advance(task, len(part))
    say(
        args,
        f"{sum(stored.values())} days of {len(stored)} panels stored",
        {"stored": stored},
    )


def commands(sub: Any) -> None:
    """energy import."""
    en = sub.add_parser("energy", help="panels' daily energy").add_subparsers(
        dest="action", required=True
    )
    i = en.add_parser(
        "import",
        help="import a farm's export: a time column, a column of kWh per panel (named by its "
        "id, or --panel COLUMN=ID), optional <panel>:expected, poa_kwh_m2, ghi_kwh_m2, "
        "rain_mm; finer rows are summed by day",
    )
    i.add_argument("csv", type=Path)
    i.add_argument(
        "--panel",
        action="append",
        metavar="COLUMN=PANEL_ID",
        help="the panel a column is (repeat it); without it every other column is a panel id",
    )
    i.set_defaults(run=import_energy)
