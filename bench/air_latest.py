"""A dashboard's list of a city's cameras: each camera's latest reading asked for one camera at a
time (``GET /air/cameras/{id}/latest`` per camera, as before ``GET /air/latest``) against one
request for every camera (``GET /air/latest``), timed side by side on one database, at the
service layer (the HTTP of 1,000 requests against one comes on top).

Readings are written straight to the tables of a scratch database: ``--cameras`` cameras, one
reading every ``--every`` seconds each, for ``--days`` days (as ``bench/air_trends.py``).

    python bench/air_latest.py                       # SQLite, 1,000 cameras, 2 days, 5 min
    python bench/air_latest.py --backend postgresql  # a scratch database on 127.0.0.1:5432
"""

from __future__ import annotations

import sys
from pathlib import Path

from sqlalchemy.orm import Session

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from app.air.services import readings as sky_readings  # noqa: E402
from bench.air_trends import city_parser, scratch_city  # noqa: E402
from bench.readings_pages import timed  # noqa: E402


def main() -> None:
    args = city_parser(__doc__ or "", cameras=1000, days=2, rounds=3).parse_args()
    with scratch_city(args) as (engine, readings, _), Session(engine) as session:
        ids = sorted({cam for cam, _, _ in readings})
        one_by_one: list[float] = []
        every: list[float] = []
        for _ in range(args.rounds):  # alternating, so that both see the machine alike
            one_by_one += timed(lambda: [sky_readings.latest_of(session, cid) for cid in ids], 1)
            every += timed(
                lambda: sky_readings.latest_of_every(session, limit=len(ids), offset=0), 1
            )
        singles = [sky_readings.latest_of(session, cid) for cid in ids]  # the same answers
        bulk = sky_readings.latest_of_every(session, limit=len(ids), offset=0)
        assert [found for _, found in singles] == [found for _, found in bulk]
    print(
        f"{args.backend}: {len(readings):,} readings of {len(ids)} cameras; ms for every camera"
        f" (the two cases alternate, round by round)\n"
        f"| one request per camera | {', '.join(f'{v:.0f}' for v in one_by_one)} |\n"
        f"| one request for all | {', '.join(f'{v:.0f}' for v in every)} |"
    )


if __name__ == "__main__":
    main()
