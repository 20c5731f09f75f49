"""Random (version 4) against time-ordered (version 7) UUID keys on PostgreSQL, side by side.

Inserts ``--rows`` rows into a table keyed like ``frames`` (``varchar(36)`` primary key), by
COPY in transactions of ``--batch`` rows (as the group-commit writer does), with a CHECKPOINT
every ``--checkpoint-every`` rows (as PostgreSQL takes one every ``checkpoint_timeout``), and
reports the time, the WAL written per row and the primary key's size. Alternates the two kinds
twice. Uses a scratch database ``vantage_keys`` on the server at 127.0.0.1:5432.

    python bench/frame_keys.py --rows 300000
"""

from __future__ import annotations

import argparse
import sys
import time
import uuid
from collections.abc import Callable
from pathlib import Path

import psycopg

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from app.platform.db.ids import time_ordered_id  # noqa: E402

ADMIN_URL = "postgresql://postgres@127.0.0.1:5432/postgres"
URL = "postgresql://postgres@127.0.0.1:5432/vantage_keys"


def run(conn: psycopg.Connection, make: Callable[[], str], args: argparse.Namespace) -> str:
    conn.execute("DROP TABLE IF EXISTS keys")
    conn.execute("CREATE TABLE keys (id varchar(36) PRIMARY KEY, n int)")
    conn.commit()
    conn.execute("CHECKPOINT")
    start_lsn = conn.execute("SELECT pg_current_wal_lsn()").fetchone()[0]
    conn.commit()
    t0 = time.perf_counter()
    for i in range(0, args.rows, args.batch):
        with conn.cursor().copy("COPY keys (id, n) FROM STDIN") as copy:
            for k in range(args.batch):
                copy.write_row((make(), k))
        conn.commit()
        if i and i % args.checkpoint_every < args.batch:
            conn.execute("CHECKPOINT")
    seconds = time.perf_counter() - t0
    wal = conn.execute("SELECT pg_wal_lsn_diff(pg_current_wal_lsn(), %s)", (start_lsn,)).fetchone()[
        0
    ]
    size = conn.execute("SELECT pg_relation_size('keys_pkey')").fetchone()[0]
    conn.commit()
    return f"{seconds:.1f} s, WAL {wal / args.rows:.0f} B/row, primary key {size / 2**20:.1f} MiB"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rows", type=int, default=300_000)
    parser.add_argument("--batch", type=int, default=64)
    parser.add_argument("--checkpoint-every", type=int, default=50_000)
    args = parser.parse_args()
    with psycopg.connect(ADMIN_URL, autocommit=True) as admin:
        admin.execute("DROP DATABASE IF EXISTS vantage_keys WITH (FORCE)")
        admin.execute("CREATE DATABASE vantage_keys")
    kinds: dict[str, Callable[[], str]] = {
        "version 4 (random)": lambda: str(uuid.uuid4()),
        "version 7 (time-ordered)": time_ordered_id,
    }
    with psycopg.connect(URL) as conn:
        for _ in range(2):
            for name, make in kinds.items():
                print(f"{name}: {args.rows} rows, {run(conn, make, args)}", flush=True)


if __name__ == "__main__":
    main()
