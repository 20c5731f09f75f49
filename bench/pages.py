"""The pages in headless Chromium: the city map with ``--cameras`` sky cameras, and the screen
below a camera's own requests.

One uvicorn process on SQLite; the cameras registered and one reading each posted through the
API (a calibration first), spread over a city 40 km across (seeded). The map is timed from
navigation to every camera's label placed and the bands drawn (``document.body.dataset.maps``
set by ``map.js`` after its first map), ``--rounds`` times in new pages; the base map's tiles are
answered by the browser with a blank tile (no network here). The display page's requests — the
HTML, its script and stylesheet, and ``/air/cameras/{id}/latest`` — are timed over HTTP.

    python bench/pages.py
    python bench/pages.py --cameras 200 --rounds 3
"""

from __future__ import annotations

import argparse
import http.client
import json
import shutil
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from bench.ingest import ADMIN, Server, pct  # noqa: E402
from tests.factories.air import sky_jpeg  # noqa: E402


def populate(server: Server, cameras: int) -> None:
    admin = {"Authorization": f"Bearer {ADMIN}"}
    rng = np.random.default_rng(0)
    boundary = "vantage-bench"
    parts = []
    for level in (1, 3, 5, 7, 10):
        for k in range(8):
            parts.append(
                f'--{boundary}\r\nContent-Disposition: form-data; name="files"; '
                f'filename="{level}-{k}.jpg"\r\nContent-Type: image/jpeg\r\n\r\n'.encode()
                + sky_jpeg(level, seed=100 * level + k)
                + b"\r\n"
            )
            parts.append(
                f'--{boundary}\r\nContent-Disposition: form-data; name="levels"\r\n\r\n'
                f"{level}\r\n".encode()
            )
    body = b"".join(parts) + f"--{boundary}--\r\n".encode()
    status, answer = server.request(
        "POST",
        "/air/calibration",
        body,
        {**admin, "Content-Type": f"multipart/form-data; boundary={boundary}"},
    )
    assert status == 201, answer
    # the calibration's own levels: a frame between two is "outside calibration", ungraded
    frames = [sky_jpeg(level, seed=level) for level in (1, 3, 5, 7, 10)]
    for k in range(cameras):
        camera = {
            "id": f"sky-{k:04d}",
            "kind": "sky",
            "name": f"Camera {k}",
            "lat": 45.3 + 0.36 * rng.random(),
            "lon": 9.0 + 0.5 * rng.random(),
            "roi": [0, 0, 160, 55],
        }
        status, answer = server.request(
            "POST", "/cameras", json.dumps(camera).encode(),
            {**admin, "Content-Type": "application/json"},
        )  # fmt: skip
        assert status == 201, answer
        token = json.loads(answer)["token"]
        status, answer = server.request(
            "POST",
            f"/cameras/sky-{k:04d}/frames",
            frames[int(rng.integers(0, len(frames)))],
            {"Authorization": f"Bearer {token}", "Content-Type": "image/jpeg"},
        )
        assert status == 201, answer


def time_map(port: int, cameras: int, rounds: int) -> list[float]:
    from playwright.sync_api import sync_playwright

    chromium = shutil.which("chromium")
    if chromium is None:
        raise SystemExit("needs Chromium (apt install chromium)")
    tile = (ROOT / "app" / "web" / "static" / "pages.css").read_bytes()[:0]
    took = []
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=chromium, args=["--no-sandbox"])
        for _ in range(rounds):
            page = browser.new_page(viewport={"width": 1600, "height": 1000})
            page.route(
                "https://tile.openstreetmap.org/**",
                lambda route: route.fulfill(status=200, body=tile, content_type="image/png"),
            )
            t = time.perf_counter()
            page.goto(f"http://127.0.0.1:{port}/map")
            page.wait_for_function(
                f"document.querySelectorAll('.cam-label').length === {cameras}"
                " && Number(document.body.dataset.maps) >= 1",
                timeout=60_000,
            )
            took.append(time.perf_counter() - t)
            page.close()
        browser.close()
    return took


def time_display(port: int, n: int) -> dict[str, list[float]]:
    paths = {
        "GET /display/{id}": "/display/sky-0001",
        "GET /static/display.js": "/static/display.js",
        "GET /static/pages.css": "/static/pages.css",
        "GET /air/cameras/{id}/latest": "/air/cameras/sky-0001/latest",
    }
    out: dict[str, list[float]] = {name: [] for name in paths}
    conn = http.client.HTTPConnection("127.0.0.1", port, timeout=30)
    for _ in range(n):
        for name, path in paths.items():
            t = time.perf_counter()
            conn.request("GET", path)
            r = conn.getresponse()
            r.read()
            assert r.status == 200, (path, r.status)
            out[name].append(time.perf_counter() - t)
    conn.close()
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cameras", type=int, default=1000)
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--requests", type=int, default=200)
    ap.add_argument("--port", type=int, default=8763)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        server = Server("sqlite", args.port, Path(tmp))
        try:
            t = time.perf_counter()
            populate(server, args.cameras)
            print(
                f"{args.cameras} sky cameras with a reading each in {time.perf_counter() - t:.0f} s"
            )
            took = time_map(args.port, args.cameras, args.rounds)
            print(
                f"/map, {args.cameras} cameras labelled and the bands drawn: median "
                f"{statistics.median(took):.2f} s, max {max(took):.2f} s over {len(took)} pages"
            )
            for name, times in time_display(args.port, args.requests).items():
                ms = [1000 * v for v in times]
                print(
                    f"{name:32s} median {statistics.median(ms):6.1f} ms   "
                    f"p95 {pct(ms, 95):6.1f} ms   max {max(ms):6.1f} ms"
                )
        finally:
            server.stop()


if __name__ == "__main__":
    main()
