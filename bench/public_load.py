"""Frame uploads while dashboards ask for the city's daily means, with the public work bound
to one at a time per process (``VANTAGE_PUBLIC_WORK_THREADS=1``, the default) against unbound
(40: every thread FastAPI has, as before), side by side in one run.

One uvicorn process on SQLite (or ``--backend postgresql``); ``--cameras`` sky cameras with
a reading every 5 minutes for ``--days`` days written straight to its database.
``--dashboards`` threads each ask for ``GET /air/readings?aggregate=daily`` with a ``since``
of their own (a dashboard's "the last N days", never twice the same: no cache helps) while 16
client threads post ``--requests`` 640×480 frames; the uploads alone first, as the reference.

    python bench/public_load.py
    python bench/public_load.py --backend postgresql --rounds 2 --dashboards 8 --days 7
"""

from __future__ import annotations

import argparse
import http.client
import statistics
import sys
import tempfile
import threading
import time
from datetime import UTC, datetime, timedelta
from pathlib import Path

from sqlalchemy import create_engine

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from bench.air_trends import city_readings  # noqa: E402
from bench.ingest import PG_BENCH_URL, Server, drive, jpeg_640x480, pct  # noqa: E402
from tests.factories.air import store  # noqa: E402


def dashboards(port: int, n: int, stop: threading.Event, t0: datetime, took: list[float]) -> None:
    """``n`` threads asking for daily means until ``stop``; the seconds each answer took go to
    ``took``."""
    lock = threading.Lock()

    def worker(k: int) -> None:
        conn = http.client.HTTPConnection("127.0.0.1", port, timeout=600)
        i = 0
        while not stop.is_set():
            since = (t0 + timedelta(minutes=7 * k + i)).isoformat().replace("+00:00", "Z")
            t = time.perf_counter()
            conn.request("GET", f"/air/readings?aggregate=daily&limit=1000&since={since}")
            r = conn.getresponse()
            r.read()
            assert r.status == 200, r.status
            with lock:
                took.append(time.perf_counter() - t)
            i += 1
        conn.close()

    threads = [threading.Thread(target=worker, args=(k,)) for k in range(n)]
    for t in threads:
        t.start()
    stop.wait()
    for t in threads:
        t.join()


def run(threads: int, args: argparse.Namespace, port: int, t0: datetime, readings: list) -> dict:
    jpeg = jpeg_640x480()
    args.data_root.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=args.data_root, prefix="bench-") as tmp:
        env = {"VANTAGE_PUBLIC_WORK_THREADS": str(threads), "VANTAGE_ISOPLETH_CACHE_SECONDS": "0"}
        server = Server(args.backend, port, Path(tmp), env=env)
        try:
            url = (
                PG_BENCH_URL
                if args.backend == "postgresql"
                else f"sqlite:///{Path(tmp).resolve() / 'vantage.db'}"
            )
            engine = create_engine(url)
            store(engine, readings)
            if args.backend == "postgresql":
                with engine.connect() as conn:
                    conn.exec_driver_sql("ANALYZE")
                    conn.commit()
            engine.dispose()
            cam = server.rig_camera("bench")
            path = "/cameras/bench/frames"
            drive(port, path, cam, jpeg, 10**9, 200, 16)  # warm-up
            out: dict[str, list[float]] = {}
            n = 10**6
            for _ in range(args.rounds):
                secs, _, err = drive(port, path, cam, jpeg, n, args.requests, 16)
                n += args.requests
                assert err == 0
                out.setdefault("alone", []).append(args.requests / secs)
                stop = threading.Event()
                answers: list[float] = []
                poll = threading.Thread(
                    target=dashboards, args=(port, args.dashboards, stop, t0, answers)
                )
                poll.start()
                time.sleep(2.0)  # the dashboards are at it
                secs, lat, err = drive(port, path, cam, jpeg, n, args.requests, 16)
                n += args.requests
                stop.set()
                poll.join()
                assert err == 0
                out.setdefault("beside", []).append(args.requests / secs)
                out.setdefault("p99_ms", []).append(pct(lat, 99) * 1000)
                out.setdefault("answers", []).append(len(answers))
                out.setdefault("answer_p50_s", []).append(statistics.median(answers))
            return out
        finally:
            server.stop()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--backend", choices=["sqlite", "postgresql"], default="sqlite")
    ap.add_argument("--cameras", type=int, default=200)
    ap.add_argument("--days", type=int, default=7)
    ap.add_argument("--dashboards", type=int, default=8)
    ap.add_argument("--requests", type=int, default=1500)
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--port", type=int, default=8766)
    ap.add_argument(
        "--threads", default="1,40", help="VANTAGE_PUBLIC_WORK_THREADS values to compare"
    )
    ap.add_argument("--data-root", type=Path, default=ROOT / "data")
    args = ap.parse_args()
    t0 = datetime(2026, 5, 1, tzinfo=UTC)
    readings = city_readings(args.cameras, args.days, 300)
    print(f"{len(readings):,} readings of {args.cameras} cameras; {args.dashboards} dashboards")
    print(
        "| public work threads | round | uploads alone [frames/s] | uploads beside the"
        " dashboards [frames/s] | ratio | upload p99 [ms] | daily means answered | their"
        " median [s] |"
    )
    print("|---|---|---|---|---|---|---|---|")
    for threads in (int(t) for t in args.threads.split(",")):
        out = run(threads, args, args.port, t0, readings)
        for r in range(args.rounds):
            print(
                f"| {threads} | {r + 1} | {out['alone'][r]:.0f} | {out['beside'][r]:.0f} |"
                f" {out['beside'][r] / out['alone'][r]:.2f} | {out['p99_ms'][r]:.0f} |"
                f" {out['answers'][r]:.0f} | {out['answer_p50_s'][r]:.2f} |"
            )


if __name__ == "__main__":
    main()
