"""A solar farm at a glance: how many panels are in each state, and the page of those that need
cleaning, in one query each (``GET /panel-states``, ``GET /panels?state=``), against reading
every panel's state one panel at a time (its status, the only way before), timed side by side
on one database at the service layer (HTTP would add one request per panel to the second).

Panels are written straight to the tables of a scratch database with random facts (seeded): a
baseline for 90 %, a dirty streak of 0–4, the last verdict clean, dirty or none, an open task
for 10 % (pending, claimed, its lease expired, or completed).

    python bench/panel_states.py                       # SQLite, 20,000 panels
    python bench/panel_states.py --backend postgresql  # a scratch database on 127.0.0.1:5432
"""

from __future__ import annotations

import argparse
import sys
from collections import Counter
from datetime import UTC, datetime
from pathlib import Path

import numpy as np
from sqlalchemy import create_engine
from sqlalchemy.orm import Session

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from app.platform.timing import Timing  # noqa: E402
from app.solar.core.panel_state import PanelState  # noqa: E402
from app.solar.services import panels  # noqa: E402
from bench.air_trends import PG_ADMIN, analyze, database  # noqa: E402
from bench.readings_pages import timed  # noqa: E402
from tests.factories import migrate  # noqa: E402
from tests.factories.solar import TASK_FACTS, Facts, store_farm  # noqa: E402

NOW = datetime(2026, 6, 1, 12, tzinfo=UTC)


def random_facts(n: int) -> list[Facts]:
    rng = np.random.default_rng(0)
    out: list[Facts] = []
    for _ in range(n):
        last = [None, True, False][int(rng.choice(3, p=[0.05, 0.75, 0.2]))]
        task = TASK_FACTS[int(rng.choice(5, p=[0.9, 0.04, 0.03, 0.01, 0.02]))]
        out.append(
            (
                bool(rng.random() < 0.9),
                int(rng.integers(0, 5)),
                last,
                bool(rng.random() < 0.02),
                task,
            )
        )
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    ap.add_argument("--backend", choices=["sqlite", "postgresql"], default="sqlite")
    ap.add_argument("--panels", type=int, default=20_000)
    ap.add_argument("--one-by-one", type=int, default=1_000, help="panels read one at a time")
    ap.add_argument("--rounds", type=int, default=3)
    args = ap.parse_args()
    url = database(args.backend)
    migrate(url)
    engine = create_engine(url)
    timing = Timing(clock=lambda: NOW)
    try:
        ids = store_farm(engine, NOW, random_facts(args.panels), fleet=False)
        analyze(engine)
        some = ids[: args.one_by_one]
        with Session(engine) as session:
            singles = {p: panels.panel_status(session, p, timing).state for p in some}
            listed = panels.listed_with_state(
                session, timing, states=[], retired=False, limit=len(some), offset=0
            )
            assert {p.id: s for p, s in listed} == singles  # the same answers
            one_by_one, counts, page = [], [], []
            for _ in range(args.rounds):  # alternating, so that all see the machine alike
                one_by_one += timed(
                    lambda: [panels.panel_status(session, p, timing) for p in some], 1
                )
                counts += timed(lambda: panels.state_counts(session, timing), 1)
                page += timed(
                    lambda: panels.listed_with_state(
                        session,
                        timing,
                        states=[PanelState.needs_cleaning],
                        retired=False,
                        limit=100,
                        offset=0,
                    ),
                    1,
                )
            tally = panels.state_counts(session, timing)
    finally:
        engine.dispose()
        if args.backend == "postgresql":
            import psycopg

            with psycopg.connect(PG_ADMIN, autocommit=True) as conn:
                conn.execute("DROP DATABASE IF EXISTS vantage_trends_bench")
    states = Counter(s.value for s in singles.values())
    shares = ", ".join(f"{s}: {n}" for s, n in tally.items())
    print(
        f"{args.backend}: {args.panels:,} panels ({shares});"
        f" ms, the three cases alternating round by round\n"
        f"| every state of {len(some):,} panels, one status at a time | "
        f"{', '.join(f'{v:.0f}' for v in one_by_one)} |\n"
        f"| the counts of all {args.panels:,} (`GET /panel-states`) | "
        f"{', '.join(f'{v:.1f}' for v in counts)} |\n"
        f"| the first 100 needing cleaning (`GET /panels?state=needs_cleaning`) | "
        f"{', '.join(f'{v:.1f}' for v in page)} |\n"
        f"(states of the {len(some):,} read one at a time: {dict(states)})"
    )


if __name__ == "__main__":
    main()
