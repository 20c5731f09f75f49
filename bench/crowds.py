"""A flood of anonymous kriging maps: what the city's readings and the cameras' uploads see
beside it, with the crowd limits on (the defaults) and off, side by side in one run.

One uvicorn process on SQLite; ``--cameras`` located sky cameras with a reading each and a
calibration. ``--flood`` clients, each its own address (``X-Forwarded-For``, as nginx sets it;
uvicorn trusts it from 127.0.0.1), ask over and over for ``/air/isopleths?method=kriging&
resolution=256`` with a bbox of their own (no cache helps), for ``--seconds``. Meanwhile one
dashboard polls ``GET /air/latest`` and 4 cameras post frames; the same two alone first, as
the reference. The dashboard asks 4 times a second (within its share, 300 a minute); the
flood's clients ask again as soon as they are answered.

    python bench/crowds.py
"""

from __future__ import annotations

import argparse
import http.client
import json
import sys
import tempfile
import threading
import time
from collections import Counter
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from bench.ingest import ADMIN, Server, pct  # noqa: E402
from tests.factories.air import sky_jpeg  # noqa: E402

ON = {  # the settings' defaults
    "VANTAGE_PUBLIC_REQUESTS_PER_MINUTE": "300",
    "VANTAGE_PUBLIC_WORK_PER_MINUTE": "20",
    "VANTAGE_PUBLIC_WORK_QUEUE": "8",
}
OFF = {
    "VANTAGE_PUBLIC_REQUESTS_PER_MINUTE": "0",
    "VANTAGE_PUBLIC_WORK_PER_MINUTE": "0",
    "VANTAGE_PUBLIC_WORK_QUEUE": "100000",
}


def city(server: Server, n: int) -> list[dict[str, str]]:
    """``n`` sky cameras around Milan with a reading each, the calibration they grade by;
    their upload headers."""
    admin = {"Authorization": f"Bearer {ADMIN}"}
    files, levels = [], []
    for level in (1, 3, 5, 7, 10):
        for k in range(8):
            files.append(sky_jpeg(level, seed=100 * level + k))
            levels.append(str(level))
    boundary = "benchboundary"
    parts = [
        f'--{boundary}\r\nContent-Disposition: form-data; name="levels"\r\n\r\n{v}\r\n'.encode()
        for v in levels
    ]
    for i, f in enumerate(files):
        head = (
            f'--{boundary}\r\nContent-Disposition: form-data; name="files"; filename="{i}.jpg"'
            "\r\nContent-Type: image/jpeg\r\n\r\n"
        )
        parts.append(head.encode() + f + b"\r\n")
    body = b"".join(parts) + f"--{boundary}--\r\n".encode()
    status, answer = server.request(
        "POST",
        "/air/calibration?method=clusters&significance=0.01",
        body,
        {**admin, "Content-Type": f"multipart/form-data; boundary={boundary}"},
    )
    assert status == 201, answer
    cameras = []
    for k in range(n):
        cam = {
            "id": f"sky{k}",
            "kind": "sky",
            "lat": 45.40 + 0.1 * ((k * 37) % 101) / 101,
            "lon": 9.10 + 0.2 * ((k * 59) % 103) / 103,
            "roi": [0, 0, 160, 55],
        }
        status, answer = server.request(
            "POST",
            "/cameras",
            json.dumps(cam).encode(),
            {**admin, "Content-Type": "application/json"},
        )
        assert status == 201, answer
        headers = {
            "Authorization": f"Bearer {json.loads(answer)['token']}",
            "Content-Type": "image/jpeg",
        }
        status, answer = server.request(
            "POST", f"/cameras/sky{k}/frames", sky_jpeg(1 + k % 10, seed=k), headers
        )
        assert status == 201, answer
        cameras.append(headers)
    return cameras


def loop(port: int, stop: threading.Event, ask: object, out: list, pause: float = 0.0) -> None:
    """Call ``ask(conn, i)`` → status until ``stop``, ``pause`` seconds apart; (seconds,
    status) go to ``out``."""
    conn = http.client.HTTPConnection("127.0.0.1", port, timeout=600)
    i = 0
    while not stop.is_set():
        t = time.perf_counter()
        try:
            status = ask(conn, i)  # type: ignore[operator]
        except (OSError, http.client.HTTPException):
            conn.close()
            conn = http.client.HTTPConnection("127.0.0.1", port, timeout=600)
            status = 0
        out.append((time.perf_counter() - t, status))
        i += 1
        stop.wait(pause)
    conn.close()


def get(path: str, headers: dict[str, str]) -> object:
    def ask(conn: http.client.HTTPConnection, i: int) -> int:
        conn.request("GET", path, headers=headers)
        r = conn.getresponse()
        r.read()
        return r.status

    return ask


def flood_map(k: int) -> object:
    """Client ``k``'s kriging maps, each over a bbox of its own (0.01° apart: no cache)."""
    headers = {"X-Forwarded-For": f"10.{k // 250}.{k % 250}.1"}

    def ask(conn: http.client.HTTPConnection, i: int) -> int:
        lo = 9.0 + 0.01 * ((k * 97 + i) % 50)
        q = f"method=kriging&resolution=256&bbox={lo:.2f},45.35,{lo + 0.4:.2f},45.55"
        conn.request("GET", f"/air/isopleths?{q}", headers=headers)
        r = conn.getresponse()
        r.read()
        return r.status

    return ask


def post(path: str, headers: dict[str, str], jpeg: bytes) -> object:
    def ask(conn: http.client.HTTPConnection, i: int) -> int:
        conn.request("POST", path, body=jpeg, headers=headers)
        r = conn.getresponse()
        r.read()
        return r.status

    return ask


def measure(port: int, cameras: list[dict[str, str]], seconds: float, flood: int) -> dict:
    stop = threading.Event()
    latest: list = []
    uploads: list = []
    flooded: list = []
    threads = [
        threading.Thread(
            target=loop,
            args=(port, stop, get("/air/latest", {"X-Forwarded-For": "192.0.2.1"}), latest, 0.25),
        )
    ]
    for k, headers in enumerate(cameras[:4]):
        jpeg = sky_jpeg(5, seed=1000 + k)
        threads.append(
            threading.Thread(
                target=loop,
                args=(port, stop, post(f"/cameras/sky{k}/frames", headers, jpeg), uploads),
            )
        )
    for k in range(flood):
        threads.append(threading.Thread(target=loop, args=(port, stop, flood_map(k), flooded)))
    for t in threads:
        t.start()
    time.sleep(seconds)
    stop.set()
    for t in threads:
        t.join()
    return {"latest": latest, "uploads": uploads, "flood": flooded}


def ms(values: list[float], q: float) -> str:
    return f"{pct(values, q) * 1000:.0f}" if values else "—"


def row(label: str, got: dict, seconds: float) -> str:
    lat = [s for s, st in got["latest"] if st == 200]
    up = [s for s, st in got["uploads"] if st == 201]
    statuses = Counter(st for _, st in got["flood"])
    refused = [s for s, st in got["flood"] if st in (429, 503)]
    flood = " ".join(f"{st}: {n}" for st, n in sorted(statuses.items())) or "—"
    at_once = [s for s in refused if s < 0.5]  # the others were held (TARPIT_SECONDS)
    refused_ms = f"{len(at_once)}: {ms(at_once, 50)} / {ms(at_once, 99)}" if refused else "—"
    return (
        f"| {label} | {len(lat) / seconds:.1f} | {ms(lat, 50)} / {ms(lat, 95)} |"
        f" {len(up) / seconds:.1f} | {ms(up, 50)} / {ms(up, 95)} | {flood} | {refused_ms} |"
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cameras", type=int, default=40)
    ap.add_argument("--flood", type=int, default=50)
    ap.add_argument("--seconds", type=float, default=20.0)
    ap.add_argument("--port", type=int, default=8767)
    args = ap.parse_args()
    print(
        "| limits | flood | /air/latest answered [/s] | its p50 / p95 [ms] | uploads [/s] |"
        " their p50 / p95 [ms] | flood's answers | refusals sent at once: n, p50 / p99 [ms] |"
    )
    print("|---|---|---|---|---|---|---|---|")
    for label, env in (("on (defaults)", ON), ("off", OFF)):
        with tempfile.TemporaryDirectory(prefix="bench-crowds-") as tmp:
            env = {**env, "VANTAGE_ISOPLETH_CACHE_SECONDS": "30"}
            server = Server("sqlite", args.port, Path(tmp), env=env)
            try:
                cameras = city(server, args.cameras)
                alone = measure(args.port, cameras, args.seconds / 2, 0)
                print(row(f"{label} | none", alone, args.seconds / 2))
                flooded = measure(args.port, cameras, args.seconds, args.flood)
                print(row(f"{label} | {args.flood} clients", flooded, args.seconds))
            finally:
                server.stop()


if __name__ == "__main__":
    main()
