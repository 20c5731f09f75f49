"""CPU of the service per pulled frame, and sources a core can pull at one frame a minute.

One uvicorn process on SQLite pulls ``--sources`` sources every second for ``--seconds``
seconds: 640×480 JPEG snapshots from a threaded HTTP server in this process, then the same
number of RTSP/H.264 640×480 streams from GStreamer's RTSP server (one shared test pattern;
its own CPU is not the service's). Each frame is stored and judged as a sky camera's. The
service's CPU (user + system, from /proc) over the frames it stored gives the CPU per frame;
60 s over that is the sources one core keeps at a frame a minute.

    python bench/sources.py
    python bench/sources.py --sources 20 --seconds 30
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from bench.ingest import ADMIN, Server, jpeg_640x480  # noqa: E402
from tests import servers  # noqa: E402

TICKS = os.sysconf("SC_CLK_TCK")


def cpu_seconds(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / TICKS


def frames_stored(server: Server, n: int) -> int:
    admin = {"Authorization": f"Bearer {ADMIN}"}
    total = 0
    for k in range(n):
        status, body = server.request("GET", f"/cameras/c{k:03d}/frames?limit=1000", b"", admin)
        assert status == 200, body
        total += len(json.loads(body))
    return total


def run(kind: str, urls: list[str], seconds: float, port: int) -> tuple[float, int, list[str]]:
    """The service's CPU seconds and the frames stored while pulling ``urls`` every second;
    the sources' states at the end."""
    admin = {"Authorization": f"Bearer {ADMIN}", "Content-Type": "application/json"}
    with tempfile.TemporaryDirectory() as tmp:
        env = {
            "VANTAGE_PULL_THREADS": "16",
            "VANTAGE_SOURCE_ALLOWED_NETWORKS": "127.0.0.0/8",  # the cameras served here
        }
        server = Server("sqlite", port, Path(tmp), env=env)
        try:
            for k, url in enumerate(urls):
                body = {
                    "id": f"c{k:03d}",
                    "kind": "sky",
                    "source": {"url": url, "every_seconds": 1},
                }
                status, answer = server.request(
                    "POST", "/cameras", json.dumps(body).encode(), admin
                )
                assert status == 201, answer
            time.sleep(2)  # the first pulls: connections, FFmpeg's probing
            cpu0, n0 = cpu_seconds(server.proc.pid), frames_stored(server, len(urls))
            time.sleep(seconds)
            cpu1, n1 = cpu_seconds(server.proc.pid), frames_stored(server, len(urls))
            states = []
            for k in range(len(urls)):
                _, camera = server.request("GET", f"/cameras/c{k:03d}", b"", admin)
                states.append(json.loads(camera)["source"]["state"])
            return cpu1 - cpu0, n1 - n0, states
        finally:
            server.stop()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sources", type=int, default=10)
    ap.add_argument("--seconds", type=float, default=20.0)
    args = ap.parse_args()
    snapshot = jpeg_640x480()
    servers.JPEG = snapshot  # what the camera server answers
    cameras = servers.CameraServer()
    rtsp = subprocess.Popen(
        ["/usr/bin/python3", str(ROOT / "tests" / "platform" / "rtsp_server.py"), "640", "480"],
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        assert rtsp.stdout is not None
        rtsp_url = f"rtsp://127.0.0.1:{int(rtsp.stdout.readline())}/test"
        print(f"{args.sources} sources, each a frame a second, for {args.seconds:g} s; 640×480")
        for kind, urls in (
            (
                "snapshot JPEG over HTTP",
                [cameras.url(f"/snapshot.jpg?c={k}") for k in range(args.sources)],
            ),
            ("RTSP H.264 (FFmpeg)", [rtsp_url] * args.sources),
        ):
            cpu, frames, states = run(kind, urls, args.seconds, 8771)
            per = cpu / max(frames, 1)
            print(
                f"{kind:26s} {frames:5d} frames  CPU {1000 * per:6.1f} ms a frame  "
                f"→ {60 / per:6.0f} sources a core at a frame a minute   "
                f"states {sorted(set(states))}"
            )
    finally:
        cameras.stop()
        rtsp.terminate()
        rtsp.wait(10)


if __name__ == "__main__":
    main()
