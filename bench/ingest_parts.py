"""What the ingest path adds to a bare decode, part by part, without HTTP, side by side in one run.

16 threads (as many as the HTTP bench's clients) push the same 640×480 frames (distinct bytes)
through, in alternating rounds:
- ``bare``: decode + channel histograms (what ``POST /bare`` does);
- ``prepare``: ``ingest.prepare`` without the store (checks, decode, statistics, quality gate,
  SHA-256, the frame row in memory);
- ``+ store``: and the file written to the frame store;
- ``+ database``: and the rows committed through the group-commit writer (no file);
- ``full``: everything the ingest endpoint does below HTTP.
Reported: process CPU per frame (every thread) and frames/s, medians over the rounds.

    python bench/ingest_parts.py [--data-root data] [--rounds 3] [--frames 2000]
    python bench/ingest_parts.py --database-url postgresql+psycopg://postgres@127.0.0.1:5432/vantage_bench
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from datetime import UTC, datetime
from functools import partial
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from sqlalchemy import Engine  # noqa: E402
from sqlalchemy.orm import Session, sessionmaker  # noqa: E402

from app.platform.db.models import Camera, CameraKind  # noqa: E402
from app.platform.db.session import make_engine, make_sessionmaker  # noqa: E402
from app.platform.frames import ingest  # noqa: E402
from app.platform.frames.camera_info import CameraInfo  # noqa: E402
from app.platform.frames.jpeg import decode_rgb  # noqa: E402
from app.platform.frames.stats import channel_stats  # noqa: E402
from app.platform.frames.storage import DiskFrameStore  # noqa: E402
from app.platform.frames.writer import GroupCommitWriter  # noqa: E402
from app.platform.timing import Timing  # noqa: E402
from bench.ingest import jpeg_640x480, prepare_pg, unique  # noqa: E402

MAX_PIXELS = 40_000_000


def bench_database(url: str) -> tuple[Engine, sessionmaker[Session]]:
    """The database at ``url`` migrated (PostgreSQL's bench database dropped and made anew
    first), with the rig camera ``c`` registered."""
    if url.startswith("postgresql"):
        prepare_pg()
    subprocess.run(
        [sys.executable, "-m", "alembic", "upgrade", "head"],
        cwd=ROOT,
        env={**os.environ, "VANTAGE_DATABASE_URL": url},
        check=True,
        capture_output=True,
    )
    engine = make_engine(url)
    sessions = make_sessionmaker(engine)
    with sessions() as session:
        session.add(Camera(id="c", kind=CameraKind.rig, token_hash="-"))
        session.commit()
    return engine, sessions


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data-root", type=Path, default=ROOT / "data")
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--frames", type=int, default=2000, help="frames per case and round")
    parser.add_argument("--threads", type=int, default=16)
    parser.add_argument(
        "--database-url",
        help="e.g. postgresql+psycopg://postgres@127.0.0.1:5432/vantage_bench (emptied first); "
        "default: SQLite in a temporary directory",
    )
    args = parser.parse_args()

    args.data_root.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=args.data_root, prefix="parts-") as tmp:
        engine, sessions = bench_database(args.database_url or f"sqlite:///{tmp}/vantage.db")
        writer = GroupCommitWriter(sessions)
        writer.start()
        store = DiskFrameStore(Path(tmp))
        timing = Timing()
        camera = CameraInfo(id="c", kind=CameraKind.rig, panel_id=None, roi=None)
        jpeg = jpeg_640x480()
        counter = iter(range(10**9))

        def bare(data: bytes) -> object:
            _, image = decode_rgb(data, max_pixels=MAX_PIXELS)
            return channel_stats(image).modes

        def ingest_(data: bytes, *, use_store: bool, use_db: bool) -> object:
            prepared = ingest.prepare(
                store if use_store else None,
                camera=camera,
                data=data,
                captured_at=None,
                received_at=datetime.now(UTC),
                max_pixels=MAX_PIXELS,
            )
            if not use_db:
                return prepared
            return writer.run(partial(ingest.record, prepared=prepared, timing=timing))

        cases: dict[str, Callable[[bytes], object]] = {
            "bare": bare,
            "prepare": partial(ingest_, use_store=False, use_db=False),
            "prepare + store": partial(ingest_, use_store=True, use_db=False),
            "prepare + database": partial(ingest_, use_store=False, use_db=True),
            "full": partial(ingest_, use_store=True, use_db=True),
        }
        results: dict[str, list[tuple[float, float]]] = {name: [] for name in cases}
        with ThreadPoolExecutor(args.threads) as pool:
            for _ in range(args.rounds):
                for name, fn in cases.items():
                    bodies = [unique(jpeg, next(counter)) for _ in range(args.frames)]
                    cpu0, wall0 = time.process_time(), time.perf_counter()
                    list(pool.map(fn, bodies))
                    cpu = (time.process_time() - cpu0) / args.frames * 1000
                    results[name].append((cpu, args.frames / (time.perf_counter() - wall0)))
        writer.stop()
        engine.dispose()

    base = statistics.median(c for c, _ in results["bare"])
    print(f"{'case':20s} {'CPU ms/frame':>12s} {'vs bare':>8s} {'frames/s':>9s}")
    for name, rows in results.items():
        cpu = statistics.median(c for c, _ in rows)
        fps = statistics.median(f for _, f in rows)
        print(f"{name:20s} {cpu:12.2f} {cpu - base:+8.2f} {fps:9.0f}")


if __name__ == "__main__":
    main()
