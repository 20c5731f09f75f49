"""Hourly and daily air-quality means over a city's month: ``readings.aggregate`` (the database sums
15-minute slots) against reading the same readings one row each (``readings.readings``, which the
aggregates were computed from before, capped at the newest 100,000).

Readings are written straight to the tables of a scratch database: ``--cameras`` cameras, one
reading every ``--every`` seconds each, for ``--days`` days.

    python bench/air_trends.py                       # SQLite, 200 cameras, 30 days, every 5 min
    python bench/air_trends.py --backend postgresql  # a scratch database on 127.0.0.1:5432
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from collections.abc import Iterator
from contextlib import contextmanager
from datetime import UTC, datetime, timedelta
from pathlib import Path
from zoneinfo import ZoneInfo

import numpy as np
from sqlalchemy import Engine, create_engine
from sqlalchemy.orm import Session

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from app.air.services import readings as sky_readings  # noqa: E402
from tests.factories import migrate  # noqa: E402
from tests.factories.air import store  # noqa: E402

PG_ADMIN = "postgresql://postgres@127.0.0.1:5432/test"
PG_BENCH = "postgresql+psycopg://postgres@127.0.0.1:5432/vantage_trends_bench"


def database(backend: str) -> str:
    if backend == "sqlite":
        return f"sqlite:///{tempfile.mkdtemp()}/trends.db"
    import psycopg

    with psycopg.connect(PG_ADMIN, autocommit=True) as conn:
        conn.execute("DROP DATABASE IF EXISTS vantage_trends_bench")
        conn.execute("CREATE DATABASE vantage_trends_bench")
    return PG_BENCH


Reading = tuple[str, datetime, int]


def city_readings(cameras: int, days: int, every: int) -> list[Reading]:
    """A city's readings: ``cameras`` cameras ``sky-0000``…, one every ``every`` seconds each
    for ``days`` days from 1 May 2026, levels drawn uniformly from 1–10 (seeded)."""
    rng = np.random.default_rng(0)
    t0 = datetime(2026, 5, 1, tzinfo=UTC)
    n = cameras * (days * 86400 // every)
    return [
        (
            f"sky-{k % cameras:04d}",
            t0 + timedelta(seconds=every * (k // cameras)),
            int(rng.integers(1, 11)),
        )
        for k in range(n)
    ]


def city_parser(doc: str, *, cameras: int, days: int, rounds: int) -> argparse.ArgumentParser:
    """The options of the benches over a city's readings (``scratch_city``)."""
    ap = argparse.ArgumentParser(description=doc.splitlines()[0])
    ap.add_argument("--backend", choices=["sqlite", "postgresql"], default="sqlite")
    ap.add_argument("--cameras", type=int, default=cameras)
    ap.add_argument("--days", type=int, default=days)
    ap.add_argument("--every", type=int, default=300, help="seconds between a camera's readings")
    ap.add_argument("--rounds", type=int, default=rounds)
    return ap


def analyze(engine: Engine) -> None:
    """Fresh planner statistics on PostgreSQL (SQLite plans without them)."""
    if engine.dialect.name == "postgresql":
        with engine.connect() as conn:
            conn.exec_driver_sql("ANALYZE")
            conn.commit()


@contextmanager
def scratch_city(args: argparse.Namespace) -> Iterator[tuple[Engine, list[Reading], float]]:
    """A scratch database holding the city's readings (``city_parser``'s options): its engine,
    the readings and the seconds storing them took; dropped afterwards on PostgreSQL."""
    url = database(args.backend)
    migrate(url)
    engine = create_engine(url)
    readings = city_readings(args.cameras, args.days, args.every)
    t = time.perf_counter()
    store(engine, readings)
    stored = time.perf_counter() - t
    analyze(engine)
    try:
        yield engine, readings, stored
    finally:
        engine.dispose()
        if args.backend == "postgresql":
            import psycopg

            with psycopg.connect(PG_ADMIN, autocommit=True) as conn:
                conn.execute("DROP DATABASE IF EXISTS vantage_trends_bench")


def main() -> None:
    args = city_parser(__doc__ or "", cameras=200, days=30, rounds=2).parse_args()
    with scratch_city(args) as (engine, readings, stored):
        print(f"{args.backend}: {len(readings)} readings stored in {stored:.0f} s")
        trends(engine, len(readings), args.rounds)


def trends(engine: Engine, n: int, rounds: int) -> None:
    print("| round | what | buckets | readings counted | time [s] |")
    print("|---|---|---|---|---|")
    with Session(engine) as session:
        for r in range(rounds):
            for zone, bucket in (("UTC", "daily"), ("Asia/Kolkata", "daily"), ("UTC", "hourly")):
                t = time.perf_counter()
                out = sky_readings.aggregate(
                    session,
                    camera_id=None,
                    since=None,
                    until=None,
                    bucket=bucket,
                    tz=ZoneInfo(zone),
                )
                dt = time.perf_counter() - t
                counted = sum(b["n"] for b in out)
                print(
                    f"| {r + 1} | aggregate {bucket} {zone} | {len(out)} | {counted} | {dt:.2f} |"
                )
            for limit in (100_000, n):
                t = time.perf_counter()
                rows = sky_readings.readings(
                    session, camera_id=None, since=None, until=None, limit=limit, offset=0
                )
                dt = time.perf_counter() - t
                print(f"| {r + 1} | readings, newest {limit} rows | | {len(rows)} | {dt:.2f} |")
                del rows
            t = time.perf_counter()
            out = sky_readings.aggregate(
                session,
                camera_id="sky-0007",
                since=None,
                until=None,
                bucket="daily",
                tz=ZoneInfo("UTC"),
            )
            print(
                f"| {r + 1} | aggregate daily, one camera | {len(out)} |"
                f" {sum(b['n'] for b in out)} | {time.perf_counter() - t:.2f} |"
            )


if __name__ == "__main__":
    main()
