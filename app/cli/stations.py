"""``vantage stations``: register reference stations, import their readings."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from rich.progress import Progress

from app.cli.common import Failed, Service, err, number, rows, say

CHUNK = 5000
"""Readings sent in one request."""


def import_stations(service: Service, args: argparse.Namespace) -> None:
    """Register stations from a CSV of id, lat, lon and optionally name."""
    given = rows(args.csv)
    made = []
    with Progress(console=err) as progress:
        task = progress.add_task("stations", total=len(given))
        for i, row in enumerate(given, start=2):
            lat, lon = number(row.get("lat", ""), "lat", i), number(row.get("lon", ""), "lon", i)
            if not row.get("id") or lat is None or lon is None:
                raise Failed(f"row {i}: id, lat and lon are needed")
            body: dict[str, Any] = {"id": row["id"], "lat": lat, "lon": lon}
            if row.get("name"):
                body["name"] = row["name"]
            made.append(service.call("POST", "/air/stations", json=body).json())
            progress.advance(task)
    say(args, f"{len(made)} stations registered", made)


def import_readings(service: Service, args: argparse.Namespace) -> None:
    """Import a station's readings from a CSV with the columns at and pm25 (others ignored),
    ``CHUNK`` at a time; a time already stored takes the file's value."""
    given = rows(args.csv)
    if given and not {"at", "pm25"} <= set(given[0]):
        raise Failed(f"{args.csv}: the header must name at and pm25")
    stored = 0
    with Progress(console=err) as progress:
        task = progress.add_task(f"readings of {args.station_id}", total=len(given))
        for start in range(0, len(given), CHUNK):
            part = given[start : start + CHUNK]
            body = "at,pm25\n" + "".join(f"{r['at']},{r['pm25']}\n" for r in part)
            try:
                r = service.call(
                    "POST",
                    f"/air/stations/{args.station_id}/readings",
                    content=body.encode(),
                    headers={"Content-Type": "text/csv"},
                )
            except Failed as exc:  # name the file's line, not the chunk's
                raise Failed(f"rows {start + 2}–{start + len(part) + 1}: {exc}") from None
            stored += r.json()["stored"]
            progress.advance(task, len(part))
    say(
        args,
        f"{stored} readings of {args.station_id} stored",
        {"station_id": args.station_id, "stored": stored},
    )


def commands(sub: Any) -> None:
    """stations import, stations readings."""
    st = sub.add_parser("stations", help="reference stations").add_subparsers(
        dest="action", required=True
    )
    i = st.add_parser("import", help="register stations from a CSV (id,name,lat,lon)")
    i.add_argument("csv", type=Path)
    i.set_defaults(run=import_stations)
    r = st.add_parser("readings", help="import a station's readings from a CSV (at,pm25)")
    r.add_argument("station_id")
    r.add_argument("csv", type=Path)
    r.set_defaults(run=import_readings)
