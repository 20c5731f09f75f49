"""Load: 200 simulated cameras posting 640×480 frames for 60 s against 2 server processes on
PostgreSQL, beside the bare decode-and-histogram ceiling measured the same way in the same run.

Each camera is a client thread with its own token and keep-alive connection, posting distinct
frames back to back (the per-camera rate limit stays on at its default). Reported per phase:
throughput, p50/p95/p99 latency, errors, and the server processes' RSS at the end.

    python bench/load.py [--cameras 200] [--seconds 60] [--workers 2] [--backend postgresql]
"""

from __future__ import annotations

import argparse
import http.client
import json
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.ingest import (  # noqa: E402
    ROOT,
    Server,
    add_pool_arguments,
    jpeg_640x480,
    pg_reachable,
    pool_env,
    unique,
)


def phase(
    port: int, path_for: list[str], headers: list[dict[str, str]], jpeg: bytes, seconds: float
) -> dict[str, object]:
    latencies: list[float] = []
    errors = 0
    statuses: dict[int, int] = {}
    lock = threading.Lock()
    deadline = time.monotonic() + seconds

    def camera(k: int) -> None:
        nonlocal errors
        conn = http.client.HTTPConnection("127.0.0.1", port, timeout=60)
        mine, bad, n = [], 0, 0
        seen: dict[int, int] = {}
        while time.monotonic() < deadline:
            n += 1
            body = unique(jpeg, k * 10_000_000 + n)
            t0 = time.perf_counter()
            try:
                conn.request("POST", path_for[k], body=body, headers=headers[k])
                r = conn.getresponse()
                r.read()
            except OSError:
                bad += 1
                conn.close()
                conn = http.client.HTTPConnection("127.0.0.1", port, timeout=60)
                continue
            mine.append(time.perf_counter() - t0)
            seen[r.status] = seen.get(r.status, 0) + 1
            if r.status not in (200, 201):
                bad += 1
        conn.close()
        with lock:
            latencies.extend(mine)
            errors += bad
            for s, c in seen.items():
                statuses[s] = statuses.get(s, 0) + c

    threads = [threading.Thread(target=camera, args=(k,)) for k in range(len(path_for))]
    t0 = time.perf_counter()
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    elapsed = time.perf_counter() - t0
    ok = sum(c for s, c in statuses.items() if s in (200, 201))
    return {
        "fps": round(ok / elapsed, 1),
        "p50_ms": round(float(np.percentile(latencies, 50)) * 1000, 1),
        "p95_ms": round(float(np.percentile(latencies, 95)) * 1000, 1),
        "p99_ms": round(float(np.percentile(latencies, 99)) * 1000, 1),
        "errors": errors,
        "statuses": statuses,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cameras", type=int, default=200)
    parser.add_argument("--seconds", type=float, default=60)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--backend", default="postgresql")
    parser.add_argument("--port", type=int, default=8921)
    parser.add_argument(
        "--no-rate-limit", action="store_true", help="turn the per-camera rate limit off"
    )
    add_pool_arguments(parser)
    args = parser.parse_args()
    if args.backend == "postgresql" and not pg_reachable():
        sys.exit("PostgreSQL not reachable")
    jpeg = jpeg_640x480()
    (ROOT / "data").mkdir(exist_ok=True)
    with tempfile.TemporaryDirectory(dir=ROOT / "data", prefix="load-") as tmp:
        server = Server(
            args.backend,
            args.port,
            Path(tmp),
            args.workers,
            rate_limit=not args.no_rate_limit,
            env=pool_env(args),
        )
        try:
            paths = [f"/cameras/cam{k}/frames" for k in range(args.cameras)]
            headers = [server.rig_camera(f"cam{k}") for k in range(args.cameras)]
            bare = phase(args.port, ["/bare"] * args.cameras, headers, jpeg, args.seconds)
            ingest = phase(args.port, paths, headers, jpeg, args.seconds)
            out = {
                "backend": args.backend,
                "workers": args.workers,
                "cameras": args.cameras,
                "seconds": args.seconds,
                "ingest_threads": args.ingest_threads,
                "bare_threads": args.bare_threads,
                "bare": bare,
                "ingest": ingest,
                "ratio": round(float(ingest["fps"]) / float(bare["fps"]), 3),  # type: ignore[arg-type]
                "rss_mb_end": round(server.rss_mb(), 1),
            }
            print(json.dumps(out))
        finally:
            server.stop()


if __name__ == "__main__":
    main()
