"""CPU of the group-commit writer per batch, without HTTP or threads.

Frames prepared up front (decoded, measured, no file), then committed through the writer's
batch path in batches of ``--batch`` frames, one after another on this thread; reports this
thread's CPU per batch (user + system: the driver's round trips included). Run it in two
checkouts, alternating, to compare writer changes side by side:

    python bench/writer_batches.py --batch 2                       # PostgreSQL
    python bench/writer_batches.py --batch 3 --database-url sqlite:///data/writer-bench.db
"""

from __future__ import annotations

import argparse
import inspect
import statistics
import sys
import time
from concurrent.futures import Future
from datetime import UTC, datetime
from functools import partial
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from app.platform.db.models import CameraKind  # noqa: E402
from app.platform.frames import cameras as registry  # noqa: E402
from app.platform.frames import ingest  # noqa: E402
from app.platform.frames.camera_info import CameraInfo  # noqa: E402
from app.platform.frames.writer import GroupCommitWriter, _Job  # noqa: E402
from app.platform.timing import Timing  # noqa: E402
from bench.ingest import PG_BENCH_URL, jpeg_640x480, unique  # noqa: E402
from bench.ingest_parts import bench_database  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--batch", type=int, default=2, help="frames per batch")
    parser.add_argument("--batches", type=int, default=400, help="batches per round")
    parser.add_argument("--rounds", type=int, default=4, help="the first is a warm-up")
    parser.add_argument(
        "--database-url",
        default=PG_BENCH_URL,
        help="PostgreSQL's bench database (dropped and made anew) or a new SQLite file",
    )
    args = parser.parse_args()

    engine, sessions = bench_database(args.database_url)
    # as the service runs it: each batch checks its jobs' camera tokens, and (since) their
    # cameras' views (absent before the writer did, so the script compares with older
    # checkouts too)
    checks = "credential" in _Job.__dataclass_fields__
    views = hasattr(registry, "refusals")
    if views:
        writer = GroupCommitWriter(sessions, check=registry.refusals)
        # the view as this checkout writes it (with the kind since the kind may change)
        from app.platform.frames import camera_info

        kinds = "kind" in inspect.signature(camera_info.view_of).parameters
        view = '["rig",null,null]' if kinds else "[null,null]"
        extra: dict[str, object] = {"credential": ("c", "-", view)}
    elif checks:
        writer = GroupCommitWriter(sessions, revoked=registry.revoked)
        extra = {"credential": ("c", "-")}
    else:
        writer, extra = GroupCommitWriter(sessions), {}
    writer._holding = True  # as on the writer's own thread (a connection kept between batches)
    camera = CameraInfo(id="c", kind=CameraKind.rig, panel_id=None, roi=None)
    timing = Timing()
    jpeg = jpeg_640x480()
    total = args.batch * args.batches * args.rounds
    prepared = iter(
        [
            ingest.prepare(
                None,
                camera=camera,
                data=unique(jpeg, n),
                captured_at=None,
                received_at=datetime.now(UTC),
                max_pixels=10**8,
            )
            for n in range(total)
        ]
    )
    cpu: list[float] = []
    for _ in range(args.rounds):
        t0 = time.thread_time()
        for _ in range(args.batches):
            batch = [
                _Job(
                    partial(ingest.record, prepared=next(prepared), timing=timing),
                    Future(),
                    **extra,
                )
                for _ in range(args.batch)
            ]
            outcomes = writer._write(batch)
            assert all(error is None for _, error in outcomes), outcomes
        cpu.append((time.thread_time() - t0) / args.batches * 1e6)
    release = getattr(writer, "_release", None)  # absent before the writer kept a connection
    if release is not None:
        release()
    engine.dispose()
    print(f"batch of {args.batch}: CPU {statistics.median(cpu[1:]):.0f} µs a batch")


if __name__ == "__main__":
    main()
