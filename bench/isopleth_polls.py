"""Dashboards polling the public map: ``GET /air/isopleths`` with the map cache on (the
default, 30 s) against off, in one process, through the HTTP layer (an in-process client).

``--cameras`` located sky cameras with one reading each are written straight to a scratch
SQLite database; each poll asks for the same map. With the cache, the first poll computes it
and the others are served from memory; without, every poll reads the stations and
interpolates and contours again. With the cache on, the polls are made twice: asking for the
body as it is, and gzipped (``Accept-Encoding: gzip``, as a browser asks).

    python bench/isopleth_polls.py                        # 1,000 cameras, kriging, 256 cells
    python bench/isopleth_polls.py --method idw --cameras 200
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from datetime import UTC, datetime, timedelta
from pathlib import Path

import numpy as np
from fastapi.testclient import TestClient
from sqlalchemy import create_engine, insert

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from app.air.models import SkyVerdict  # noqa: E402
from app.main import create_app  # noqa: E402
from app.platform.db.models import Camera, CameraKind, Frame, Verdict  # noqa: E402
from app.platform.settings import Settings  # noqa: E402
from tests.factories import migrate  # noqa: E402


def seed(url: str, cameras: int, now: datetime) -> None:
    rng = np.random.default_rng(0)
    lon = 9.10 + 0.3 * rng.random(cameras)
    lat = 45.40 + 0.2 * rng.random(cameras)
    level = np.clip(np.round(5.5 + 3 * np.sin(lon * 20) * np.cos(lat * 25)), 1, 10)
    engine = create_engine(url)
    with engine.begin() as conn:
        conn.execute(
            insert(Camera),
            [
                {"id": f"sky{i}", "kind": CameraKind.sky, "token_hash": f"h{i}",
                 "lon": float(lon[i]), "lat": float(lat[i]), "created_at": now}
                for i in range(cameras)
            ],
        )  # fmt: skip
        at = now - timedelta(minutes=5)
        conn.execute(
            insert(Frame.__table__),
            [
                {"id": f"f{i:07d}", "camera_id": f"sky{i}", "captured_at": at,
                 "received_at": at, "width": 1, "height": 1, "size_bytes": 1,
                 "sha256": f"{i:064x}"}
                for i in range(cameras)
            ],
        )  # fmt: skip
        conn.execute(
            insert(Verdict.__table__),
            [
                {"frame_id": f"f{i:07d}", "kind": CameraKind.sky, "camera_id": f"sky{i}",
                 "mode_r": 0, "mode_g": 0, "mode_b": 0, "mean_r": 0.0, "mean_g": 0.0,
                 "mean_b": 0.0}
                for i in range(cameras)
            ],
        )  # fmt: skip
        conn.execute(
            insert(SkyVerdict.__table__),
            [
                {"frame_id": f"f{i:07d}", "level": int(level[i]), "smoothed_level": float(level[i])}
                for i in range(cameras)
            ],
        )
    engine.dispose()


def polls(
    settings: Settings, params: dict[str, object], n: int, encoding: str = "identity"
) -> list[float]:
    """Seconds of each of ``n`` polls of the same map, asked with ``Accept-Encoding:
    encoding`` (``gzip``: sent compressed, and decoded by the client, as a browser's)."""
    out = []
    with TestClient(create_app(settings)) as client:
        for _ in range(n):
            t = time.perf_counter()
            r = client.get("/air/isopleths", params=params, headers={"Accept-Encoding": encoding})
            out.append(time.perf_counter() - t)
            assert r.status_code == 200, r.text
            assert r.headers.get("content-encoding", "identity") == encoding
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cameras", type=int, default=1000)
    ap.add_argument("--method", default="kriging")
    ap.add_argument("--resolution", type=int, default=256)
    ap.add_argument("--polls", type=int, default=10)
    args = ap.parse_args()

    data = Path(tempfile.mkdtemp())
    url = f"sqlite:///{data / 'polls.db'}"
    migrate(url)
    seed(url, args.cameras, datetime.now(UTC))
    params = {"method": args.method, "resolution": args.resolution, "max_distance": 20000}
    base = Settings(data_dir=data, database_url=url, admin_token="x" * 32)  # type: ignore[arg-type]
    off = polls(base.model_copy(update={"isopleth_cache_seconds": 0}), params, args.polls)
    cached = base.model_copy(update={"isopleth_cache_seconds": 30})
    on = polls(cached, params, args.polls)
    zipped = polls(cached, params, args.polls, "gzip")
    print(
        f"{args.cameras} cameras, {args.method}, {args.resolution} cells a side, "
        f"{args.polls} polls each:\n"
        f"  cache off: median {statistics.median(off) * 1000:.1f} ms a poll "
        f"(first {off[0] * 1000:.1f}), total {sum(off):.2f} s\n"
        f"  cache on:  first {on[0] * 1000:.1f} ms, then median "
        f"{statistics.median(on[1:]) * 1000:.2f} ms a poll, total {sum(on):.2f} s\n"
        f"  cache on, gzip: first {zipped[0] * 1000:.1f} ms, then median "
        f"{statistics.median(zipped[1:]) * 1000:.2f} ms a poll, total {sum(zipped):.2f} s"
    )


if __name__ == "__main__":
    main()
