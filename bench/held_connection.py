"""How long a request that needs only the database (``GET /cameras``) waits while other
requests wait for something else: a robot uploading its laser images slowly, a calibration
decoding its photos, an alert webhook whose receiver never answers.

One uvicorn process on SQLite, whose pool is the one connection every request shares: a
request holding it while it waits holds the whole service. ``--checkout`` runs the service of
another checkout (a worktree of an earlier commit) for the figures before.

    python bench/held_connection.py
    git worktree add /tmp/before <commit> && ln -s $PWD/.venv /tmp/before/.venv
    python bench/held_connection.py --checkout /tmp/before
"""

from __future__ import annotations

import argparse
import http.client
import os
import socket
import statistics
import subprocess
import sys
import tempfile
import threading
import time
import uuid
from collections.abc import Iterator
from datetime import UTC, datetime
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
ADMIN = "bench-admin-token"
HEADERS = {"Authorization": f"Bearer {ADMIN}"}


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def silent_receiver() -> int:
    """A port that takes connections and never answers (a receiver hung, or a firewall)."""
    server = socket.socket()
    server.bind(("127.0.0.1", 0))
    server.listen(100)
    held: list[socket.socket] = []

    def accept() -> None:
        while True:
            held.append(server.accept()[0])

    threading.Thread(target=accept, daemon=True).start()
    return int(server.getsockname()[1])


def start(checkout: Path, data: Path, port: int, hook_port: int) -> subprocess.Popen[bytes]:
    env = {
        **os.environ,
        "VANTAGE_DATA_DIR": str(data),
        "VANTAGE_ADMIN_TOKEN": ADMIN,
        "VANTAGE_LOG_LEVEL": "WARNING",
        "VANTAGE_ALERT_WEBHOOK_URL": f"http://127.0.0.1:{hook_port}/alerts",
        "VANTAGE_ALERT_POLL_SECONDS": "1",
    }
    env.pop("VANTAGE_DATABASE_URL", None)
    py = sys.executable
    subprocess.run(
        [py, "-m", "alembic", "upgrade", "head"], cwd=checkout, env=env, check=True,
        capture_output=True,
    )  # fmt: skip
    proc = subprocess.Popen(
        [py, "-m", "uvicorn", "app.main:create_app", "--factory", "--port", str(port)],
        cwd=checkout,
        env=env,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    for _ in range(200):
        try:
            if request(port, "GET", "/health")[0] == 200:
                return proc
        except OSError:
            time.sleep(0.1)
    proc.kill()
    raise SystemExit("the service did not start")


def request(
    port: int, method: str, path: str, body: bytes | Iterator[bytes] | None = None, **headers: str
) -> tuple[int, float]:
    """Status and seconds of one request (its answer printed when it is an error)."""
    t0 = time.perf_counter()
    c = http.client.HTTPConnection("127.0.0.1", port, timeout=120)
    chunked = body is not None and not isinstance(body, bytes)
    c.request(method, path, body=body, headers={**HEADERS, **headers}, encode_chunked=chunked)
    r = c.getresponse()
    answer = r.read()
    c.close()
    if r.status >= 400 and "laser" not in path:  # the laser images hold no dot: 422
        print(f"    {method} {path}: {r.status} {answer[:300]!r}")
    return r.status, time.perf_counter() - t0


def registry_waits(port: int, busy: threading.Thread, every: float = 0.3) -> list[float]:
    """Seconds each ``GET /cameras`` took, one after another, while ``busy`` runs."""
    waits = []
    while busy.is_alive():
        waits.append(request(port, "GET", "/cameras")[1])
        time.sleep(every)
    return waits


def multipart(parts: list[tuple[str, str, bytes]]) -> tuple[bytes, str]:
    boundary = uuid.uuid4().hex
    out = bytearray()
    for field, name, data in parts:
        out += f'--{boundary}\r\nContent-Disposition: form-data; name="{field}"'.encode()
        if name:
            out += f'; filename="{name}"\r\nContent-Type: image/jpeg'.encode()
        out += b"\r\n\r\n" + data + b"\r\n"
    out += f"--{boundary}--\r\n".encode()
    return bytes(out), f"multipart/form-data; boundary={boundary}"


def sky(level: int, k: int) -> bytes:
    rng = np.random.default_rng(100 * level + k)
    image = np.empty((1080, 1920, 3), np.float32)
    image[:] = np.array((120 + 10 * level, 150 + 8 * level, 200 - 3 * level)) + rng.normal(0, 3, 3)
    image += rng.normal(0, 6, image.shape).astype(np.float32)
    ok, buf = cv2.imencode(".jpg", np.clip(image, 0, 255).astype(np.uint8))
    assert ok
    return buf.tobytes()


def slow_upload(port: int, rate: int) -> None:
    """Four 750 kB laser images to a cross rig at ``rate`` bytes/s."""
    rng = np.random.default_rng(0)
    images = [rng.integers(0, 255, 750_000, dtype=np.uint8).tobytes() for _ in range(4)]
    body, kind = multipart([("files", f"{i}.jpg", b) for i, b in enumerate(images)])

    def trickle() -> Iterator[bytes]:
        for i in range(0, len(body), rate // 10):
            yield body[i : i + rate // 10]
            time.sleep(0.1)

    request(port, "POST", "/rigs/cell/laser/dot", trickle(), **{"Content-Type": kind})


def calibration(port: int, photos: int) -> None:
    """An air calibration from ``photos`` 1920×1080 sky photos."""
    parts = []
    for k in range(photos):
        level = (1, 3, 5, 7, 10)[k % 5]
        parts += [("files", f"{k}.jpg", sky(level, k)), ("levels", "", str(level).encode())]
    body, kind = multipart(parts)
    status, took = request(port, "POST", "/air/calibration", body, **{"Content-Type": kind})
    print(f"    (the calibration: {status} in {took:.1f} s)")


def seed_alerts(data: Path, n: int) -> None:
    from sqlalchemy import create_engine

    sys.path.insert(0, str(ROOT))
    from tests.factories.air import seed_alerts as seed

    seed(create_engine(f"sqlite:///{data / 'vantage.db'}"), n, taken=datetime.now(UTC))


def report(name: str, waits: list[float]) -> None:
    ms = sorted(1000 * w for w in waits)
    print(
        f"{name}: GET /cameras ×{len(ms)}, median {statistics.median(ms):.1f} ms, "
        f"max {ms[-1]:.1f} ms"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--checkout", type=Path, default=ROOT)
    parser.add_argument("--rate", type=int, default=500_000, help="upload bytes/s")
    parser.add_argument("--photos", type=int, default=160)
    parser.add_argument("--alerts", type=int, default=4)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        data, port = Path(tmp), free_port()
        proc = start(args.checkout.resolve(), data, port, silent_receiver())
        try:
            rig = b'{"id": "cell", "kind": "cross", "f_px": 800, "ax": 0.3, "ay": 0.2}'
            request(port, "POST", "/rigs", rig, **{"Content-Type": "application/json"})
            for name, work in (
                ("slow laser upload", lambda: slow_upload(port, args.rate)),
                ("air calibration", lambda: calibration(port, args.photos)),
            ):
                busy = threading.Thread(target=work)
                busy.start()
                time.sleep(0.5)
                report(name, registry_waits(port, busy))
                busy.join()
            seed_alerts(data, args.alerts)
            sweeping = threading.Thread(target=time.sleep, args=(5.0 * args.alerts + 3,))
            sweeping.start()
            report(f"{args.alerts} alerts to a silent receiver", registry_waits(port, sweeping))
        finally:
            proc.terminate()
            proc.wait(30)


if __name__ == "__main__":
    main()
