"""Ingest throughput against the bare decode-and-histogram ceiling, side by side in one run.

Starts one uvicorn process serving the real service plus ``POST /bare`` (decode + histograms
only, nothing stored), then drives both with the same 640×480 JPEGs from 16 client threads over
keep-alive connections, alternating rounds so that machine noise hits both alike. Every request
carries distinct bytes (a counter in a JPEG comment segment), so every ingested frame is a new
file. Finally posts 10,000 frames and samples the server's RSS.

    python bench/ingest.py                 # SQLite, and PostgreSQL if reachable
    python bench/ingest.py --backends sqlite --rounds 3 --requests 1500
"""

from __future__ import annotations

import argparse
import http.client
import json
import os
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
PG_ADMIN_URL = "postgresql://postgres@127.0.0.1:5432/postgres"
PG_BENCH_URL = "postgresql+psycopg://postgres@127.0.0.1:5432/vantage_bench"
ADMIN = "bench-admin-token-0123456789abcdef"
HTTP = "auto"
"""uvicorn's HTTP implementation (``auto``: httptools when installed, as ``app.serve``)."""


def jpeg_640x480(seed: int = 1) -> bytes:
    """A natural-looking frame: smooth gradients plus noise, quality 90."""
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:480, 0:640]
    base = np.stack([80 + 60 * np.sin(x / 90), 120 + 50 * np.cos(y / 70), 170 + 0.05 * x], axis=2)
    image = np.clip(base + rng.normal(0, 12, base.shape), 0, 255).astype(np.uint8)
    ok, buf = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, 90])
    assert ok
    return buf.tobytes()


def unique(jpeg: bytes, n: int) -> bytes:
    """The same image with a COM segment holding ``n``: distinct bytes, same pixels."""
    return jpeg[:2] + b"\xff\xfe\x00\x0a" + n.to_bytes(8, "big") + jpeg[2:]


def pg_reachable() -> bool:
    try:
        import psycopg

        psycopg.connect(PG_ADMIN_URL, connect_timeout=3).close()
        return True
    except Exception:
        return False


def prepare_pg() -> None:
    import psycopg

    with psycopg.connect(PG_ADMIN_URL, autocommit=True) as conn:
        conn.execute("DROP DATABASE IF EXISTS vantage_bench WITH (FORCE)")
        conn.execute("CREATE DATABASE vantage_bench")


def add_pool_arguments(parser: argparse.ArgumentParser) -> None:
    """``--ingest-threads`` and ``--bare-threads``: the two paths' thread pools."""
    parser.add_argument(
        "--ingest-threads",
        type=int,
        help="the service's preparing threads (VANTAGE_INGEST_THREADS; default: the service's)",
    )
    parser.add_argument(
        "--bare-threads",
        type=int,
        help="threads the bare endpoint decodes on (default: as many as the ingest's; 0: "
        "FastAPI's shared pool of 40)",
    )


def cpu_set(text: str) -> set[int]:
    """``0`` or ``0,1`` or ``0-3``: a set of CPU numbers."""
    cpus: set[int] = set()
    for part in text.split(","):
        first, _, last = part.partition("-")
        cpus.update(range(int(first), int(last or first) + 1))
    return cpus


def add_cpu_arguments(parser: argparse.ArgumentParser) -> None:
    """``--server-cpus`` and ``--client-cpus``: keep the load generator off the server's cores
    (as a camera fleet is), so that the clients' own CPU (~0.2–0.3 ms a frame of Python HTTP)
    and their scheduling do not land on the process measured."""
    parser.add_argument(
        "--server-cpus", type=cpu_set, help="CPUs the server may run on (e.g. 0); default: all"
    )
    parser.add_argument(
        "--client-cpus", type=cpu_set, help="CPUs the client threads run on (e.g. 1); default: all"
    )


def pool_env(args: argparse.Namespace) -> dict[str, str]:
    """The server's environment for ``add_pool_arguments``' options (the bare endpoint's is
    ``bench.ingest_app.BARE_THREADS_ENV``)."""
    env = {}
    if args.ingest_threads is not None:
        env["VANTAGE_INGEST_THREADS"] = str(args.ingest_threads)
    if args.bare_threads is not None:
        env["VANTAGE_BENCH_BARE_THREADS"] = str(args.bare_threads)
    return env


class Server:
    def __init__(
        self,
        backend: str,
        port: int,
        data_dir: Path,
        workers: int = 1,
        rate_limit: bool = False,
        env: dict[str, str] | None = None,
        http: str = HTTP,
        cpus: set[int] | None = None,
    ) -> None:
        env = {
            **os.environ,
            "VANTAGE_DATA_DIR": str(data_dir),
            "VANTAGE_ADMIN_TOKEN": ADMIN,
            **(env or {}),
        }
        env["VANTAGE_LOG_LEVEL"] = "WARNING"
        # the benches' clients are one address asking for everything: no per-client limits
        # unless a bench sets them (bench/crowds.py)
        env.setdefault("VANTAGE_PUBLIC_REQUESTS_PER_MINUTE", "0")
        env.setdefault("VANTAGE_PUBLIC_WORK_PER_MINUTE", "0")
        if not rate_limit:  # one camera posts hundreds of frames a second in bench/ingest.py
            env["VANTAGE_RATE_LIMIT_PER_MINUTE"] = "0"
        if backend == "postgresql":
            prepare_pg()
            env["VANTAGE_DATABASE_URL"] = PG_BENCH_URL
        else:
            env.pop("VANTAGE_DATABASE_URL", None)
        py = sys.executable
        subprocess.run(
            [py, "-m", "alembic", "upgrade", "head"],
            cwd=ROOT,
            env=env,
            check=True,
            capture_output=True,
        )
        self.proc = subprocess.Popen(
            [
                py,
                "-m",
                "uvicorn",
                "bench.ingest_app:create_bench_app",
                "--factory",
                "--port",
                str(port),
                "--log-level",
                "warning",
                "--no-access-log",
                "--http",
                http,
                *(["--workers", str(workers)] if workers > 1 else []),
            ],
            cwd=ROOT,
            env=env,
            preexec_fn=None if cpus is None else lambda: os.sched_setaffinity(0, cpus),
        )
        self.port = port
        for _ in range(100):
            try:
                self.request("GET", "/health", b"", {})
                return
            except OSError:
                time.sleep(0.1)
        raise RuntimeError("server did not start")

    def request(
        self, method: str, path: str, body: bytes, headers: dict[str, str]
    ) -> tuple[int, bytes]:
        conn = http.client.HTTPConnection("127.0.0.1", self.port, timeout=30)
        conn.request(method, path, body=body, headers=headers)
        r = conn.getresponse()
        return r.status, r.read()

    def rig_camera(self, camera_id: str) -> dict[str, str]:
        """Register a rig camera (its verdict adds no classifier); its upload headers."""
        admin = {"Authorization": f"Bearer {ADMIN}", "Content-Type": "application/json"}
        body = json.dumps({"id": camera_id, "kind": "rig"}).encode()
        status, answer = self.request("POST", "/cameras", body, admin)
        assert status == 201, answer
        token = json.loads(answer)["token"]
        return {"Authorization": f"Bearer {token}", "Content-Type": "image/jpeg"}

    def mean_batch(self) -> float | None:
        """Frames per write transaction so far (``vantage_writer_batch_frames``), as the
        process answering /metrics counted them (with several workers, one of them)."""
        from prometheus_client.parser import text_string_to_metric_families

        status, text = self.request("GET", "/metrics", b"", {"Authorization": f"Bearer {ADMIN}"})
        if status != 200:
            return None
        found = {
            s.name: s.value
            for family in text_string_to_metric_families(text.decode())
            if family.name == "vantage_writer_batch_frames"
            for s in family.samples
        }
        count = found.get("vantage_writer_batch_frames_count")
        return round(found["vantage_writer_batch_frames_sum"] / count, 2) if count else None

    def pids(self) -> list[int]:
        """The server process and, with several workers, its worker processes."""
        pid = self.proc.pid
        children = Path(f"/proc/{pid}/task/{pid}/children").read_text().split()
        return [pid, *map(int, children)]

    def rss_mb(self) -> float:
        total = 0.0
        for pid in self.pids():
            for line in Path(f"/proc/{pid}/status").read_text().splitlines():
                if line.startswith("VmRSS:"):
                    total += int(line.split()[1]) / 1024
        return total

    def cpu_seconds(self) -> float:
        total = 0.0
        for pid in self.pids():
            fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
            total += (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
        return total

    def stop(self) -> None:
        self.proc.terminate()
        self.proc.wait(10)


def drive(
    port: int, path: str, headers: dict[str, str], jpeg: bytes, start: int, total: int, clients: int
) -> tuple[float, list[float], int]:
    """Post ``total`` frames from ``clients`` threads; return (seconds, latencies, errors)."""
    counter = iter(range(start, start + total))
    lock = threading.Lock()
    latencies: list[float] = []
    errors = 0

    def worker() -> None:
        nonlocal errors
        conn = http.client.HTTPConnection("127.0.0.1", port, timeout=60)
        mine: list[float] = []
        bad = 0
        while True:
            with lock:
                n = next(counter, None)
            if n is None:
                break
            body = unique(jpeg, n)
            t0 = time.perf_counter()
            conn.request("POST", path, body=body, headers=headers)
            r = conn.getresponse()
            r.read()
            mine.append(time.perf_counter() - t0)
            if r.status not in (200, 201):
                bad += 1
        conn.close()
        with lock:
            latencies.extend(mine)
            errors += bad

    threads = [threading.Thread(target=worker) for _ in range(clients)]
    t0 = time.perf_counter()
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    return time.perf_counter() - t0, latencies, errors


def idle_jiffies() -> tuple[int, int]:
    """The machine's (idle + iowait, total) CPU time so far (/proc/stat), all cores."""
    values = [int(v) for v in Path("/proc/stat").read_text().split("\n", 1)[0].split()[1:]]
    return values[3] + values[4], sum(values)


def pct(values: list[float], q: float) -> float:
    return float(np.percentile(values, q))


def bench_backend(backend: str, args: argparse.Namespace, port: int) -> dict[str, object]:
    jpeg = jpeg_640x480()
    # the service's own default place for data (./data), not /tmp: file creation costs differ
    # by an order of magnitude between the two on some machines
    args.data_root.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=args.data_root, prefix="bench-") as tmp:
        server = Server(
            backend,
            port,
            Path(tmp),
            args.workers,
            env=pool_env(args),
            http=args.http,
            cpus=args.server_cpus,
        )
        try:
            cam = server.rig_camera("bench")
            # warm-up
            drive(port, "/bare", cam, jpeg, 0, 200, args.clients)
            drive(port, "/cameras/bench/frames", cam, jpeg, 10**9, 200, args.clients)
            rows: dict[str, dict[str, list[float]]] = {"bare": {}, "ingest": {}}
            n = 10**6
            for _ in range(args.rounds):
                for name, path in (("bare", "/bare"), ("ingest", "/cameras/bench/frames")):
                    cpu0, (idle0, all0) = server.cpu_seconds(), idle_jiffies()
                    secs, lat, err = drive(port, path, cam, jpeg, n, args.requests, args.clients)
                    cpu = (server.cpu_seconds() - cpu0) / args.requests * 1000
                    idle1, all1 = idle_jiffies()
                    n += args.requests
                    assert err == 0, f"{err} errors on {path}"
                    r = rows[name]
                    r.setdefault("fps", []).append(args.requests / secs)
                    r.setdefault("p50", []).append(pct(lat, 50) * 1000)
                    r.setdefault("p99", []).append(pct(lat, 99) * 1000)
                    r.setdefault("server_cpu_ms_per_frame", []).append(cpu)
                    # the share of the machine's CPU time nobody used: where it grows, threads
                    # wait on one another (the GIL, hand-offs), not on the cores
                    idle = 100 * (idle1 - idle0) / (all1 - all0)
                    r.setdefault("machine_idle_pct", []).append(idle)
            result: dict[str, object] = {
                "backend": backend,
                "workers": args.workers,
                "server_cpus": sorted(args.server_cpus) if args.server_cpus else None,
                "client_cpus": sorted(args.client_cpus) if args.client_cpus else None,
                "ingest_threads": args.ingest_threads,
                "bare_threads": args.bare_threads,
            }
            for name, r in rows.items():
                result[name] = {k: round(statistics.median(v), 2) for k, v in r.items()}
            result["frames_per_write_batch"] = server.mean_batch()
            bare_fps = statistics.median(rows["bare"]["fps"])
            ingest_fps = statistics.median(rows["ingest"]["fps"])
            result["ratio"] = round(ingest_fps / bare_fps, 3)
            result["p99_over_p50"] = round(
                statistics.median(rows["ingest"]["p99"]) / statistics.median(rows["ingest"]["p50"]),
                2,
            )
            # memory over a long run
            rss = [round(server.rss_mb(), 1)]
            step = args.long // 10
            for i in range(10):
                drive(
                    port, "/cameras/bench/frames", cam, jpeg, 10**8 + i * step, step, args.clients
                )
                rss.append(round(server.rss_mb(), 1))
            result["rss_mb_every_10pct"] = rss
            return result
        finally:
            server.stop()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--backends", default="sqlite,postgresql")
    parser.add_argument("--clients", type=int, default=16)
    parser.add_argument("--requests", type=int, default=2000, help="frames per round")
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--long", type=int, default=10_000, help="frames in the RSS run")
    parser.add_argument("--port", type=int, default=8911)
    parser.add_argument("--workers", type=int, default=1, help="uvicorn worker processes")
    parser.add_argument("--http", default=HTTP, help="uvicorn's HTTP implementation")
    add_pool_arguments(parser)
    add_cpu_arguments(parser)
    parser.add_argument("--data-root", type=Path, default=ROOT / "data", help="where frames go")
    args = parser.parse_args()
    if args.client_cpus:
        os.sched_setaffinity(0, args.client_cpus)
    for backend in args.backends.split(","):
        if backend == "postgresql" and not pg_reachable():
            print("postgresql: not reachable, skipped")
            continue
        print(json.dumps(bench_backend(backend, args, args.port)), flush=True)


if __name__ == "__main__":
    main()
