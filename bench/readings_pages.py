"""Pages of a city's readings (``GET /air/readings``, public): newest first over every camera,
with and without the index ``ix_frames_captured_at_id``, and deep pages by ``offset`` against
by ``cursor``, in one run on one database.

Readings are written straight to the tables of a scratch database: ``--cameras`` cameras, one
reading every ``--every`` seconds each, for ``--days`` days (as ``bench/air_trends.py``).

    python bench/readings_pages.py                       # SQLite, 200 cameras, 30 days, 5 min
    python bench/readings_pages.py --backend postgresql  # a scratch database on 127.0.0.1:5432
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Callable
from datetime import timedelta
from pathlib import Path
from typing import Any

from sqlalchemy import Engine
from sqlalchemy.orm import Session

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from app.air.services import readings as sky_readings  # noqa: E402
from app.platform.frames.cameras import FrameKey  # noqa: E402
from bench.air_trends import Reading, analyze, city_parser, scratch_city  # noqa: E402


def timed(fn: Callable[[], Any], rounds: int) -> list[float]:
    out = []
    for _ in range(rounds):
        t = time.perf_counter()
        fn()
        out.append((time.perf_counter() - t) * 1000)
    return out


def main() -> None:
    args = city_parser(__doc__ or "", cameras=200, days=30, rounds=3).parse_args()
    with scratch_city(args) as (engine, readings, _):
        pages(engine, readings, args)


def pages(engine: Engine, readings: list[Reading], args: argparse.Namespace) -> None:
    n = len(readings)
    end = readings[-1][1]
    print(f"{args.backend}: {n:,} readings of {args.cameras} cameras; ms per page of 100")
    print("| page | with the index | without |")
    print("|---|---|---|")
    with Session(engine) as session:

        def page(**kw: Any) -> Callable[[], Any]:
            base = {"camera_id": None, "since": None, "until": None, "limit": 100, "offset": 0}
            return lambda: sky_readings.readings(session, **{**base, **kw})

        depth = min(100_000, n // 2)
        deep = sky_readings.readings(
            session, camera_id=None, since=None, until=None, limit=1, offset=depth - 1
        )[0]
        cases = {
            "newest, every camera (the default)": page(),
            "newest of the last hour": page(since=end - timedelta(hours=1)),
            f"{depth:,} deep by offset": page(offset=depth),
            f"{depth:,} deep by cursor": page(cursor=FrameKey(deep.captured_at, deep.id)),
            "one camera, newest": page(camera_id="sky-0007"),
        }
        results: dict[str, list[list[float]]] = {name: [] for name in cases}
        for with_index in (True, False):
            if not with_index:
                session.commit()
                with engine.begin() as conn:
                    conn.exec_driver_sql("DROP INDEX ix_frames_captured_at_id")
                analyze(engine)
            for name, fn in cases.items():
                results[name].append(timed(fn, args.rounds))
        for name, (yes, no) in results.items():
            print(
                f"| {name} | {', '.join(f'{v:.0f}' for v in yes)} |"
                f" {', '.join(f'{v:.0f}' for v in no)} |"
            )


if __name__ == "__main__":
    main()
