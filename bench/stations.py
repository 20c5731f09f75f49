"""Reference stations: importing their readings, and a rolling calibration of many cameras.

An in-process service on a scratch data directory (SQLite, or a scratch PostgreSQL database):
- 10,000 readings of one station imported in one request, as JSON and as CSV, and the same
  10,000 sent again (each time replaced: an import repeated);
- ``--cameras`` sky cameras (default 1,000) each 1 km from its own station, with 60 stored
  frames over 10 days written straight to the tables (their sky features drawn as a fixed
  camera's vary, their station's PM2.5 following them), calibrated from their stations by a
  first pass (the method chosen on days left out), then a second pass timed: the rolling
  calibration's steady state (each camera by the method that grades it).

    python bench/stations.py [--cameras 1000] [--backend postgresql]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from datetime import UTC, datetime, timedelta
from pathlib import Path

import numpy as np
from fastapi.testclient import TestClient
from sqlalchemy import create_engine, insert, text

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from app.air.core import airquality  # noqa: E402
from app.air.models import AirStation, SkyVerdict, StationReading  # noqa: E402
from app.air.services import rolling  # noqa: E402
from app.main import create_app  # noqa: E402
from app.platform.db.models import Camera, CameraKind, Frame, Verdict  # noqa: E402
from app.platform.settings import Settings  # noqa: E402
from app.platform.timing import Timing  # noqa: E402
from tests.factories import migrate  # noqa: E402

ADMIN = "bench-admin-token-0123456789abcdef"
T0 = datetime(2026, 11, 1, 8, tzinfo=UTC)
FRAMES = 60
DAYS = 10


def app_of(data: Path, url: str | None) -> tuple[object, str]:
    settings = Settings(
        data_dir=data,
        database_url=url,
        admin_token=ADMIN,  # type: ignore[arg-type]
        public_requests_per_minute=0,
        public_work_per_minute=0,
        rate_limit_per_minute=0,
        log_level="WARNING",
    )
    migrate(settings.effective_database_url)
    return create_app(settings), settings.effective_database_url


def imports(client: TestClient) -> None:
    headers = {"Authorization": f"Bearer {ADMIN}"}
    client.post("/air/stations", json={"id": "s", "lat": 45.46, "lon": 9.19}, headers=headers)
    rows = [
        {"at": (T0 + timedelta(minutes=k)).isoformat(), "pm25": float(5 + k % 40)}
        for k in range(10_000)
    ]
    csv_body = "at,pm25\n" + "".join(f"{r['at']},{r['pm25']}\n" for r in rows)
    for name, kw in (
        ("JSON, new", {"json": rows}),
        ("JSON, again (replaced)", {"json": rows}),
        ("CSV, again (replaced)", {"content": csv_body, "headers": {"Content-Type": "text/csv"}}),
    ):
        extra = kw.pop("headers", {})
        t = time.perf_counter()
        r = client.post("/air/stations/s/readings", headers={**headers, **extra}, **kw)
        dt = time.perf_counter() - t
        assert r.status_code == 200, r.text
        print(f"  10,000 readings, {name:24s} {dt:6.2f} s  ({r.json()['stored']} stored)")


def cameras(url: str, n: int) -> None:
    """``n`` cameras, each with its station 1 km north and ``FRAMES`` frames over ``DAYS``
    days, written straight to the tables."""
    rng = np.random.default_rng(0)
    k = len(airquality.SKY_FEATURES)
    coef = rng.normal(0, 0.3, k)
    engine = create_engine(url)
    cams, stations, frames, verdicts, skies, readings = [], [], [], [], [], []
    for c in range(n):
        lat, lon = 45.0 + c * 0.01, 9.0
        cams.append({"id": f"c{c}", "kind": CameraKind.sky, "token_hash": f"h{c}", "lat": lat,
                     "lon": lon, "created_at": T0})  # fmt: skip
        stations.append({"id": f"s{c}", "lat": lat + 0.009, "lon": lon, "created_at": T0})
        for f in range(FRAMES):
            at = T0 + timedelta(days=f % DAYS, hours=f // DAYS)
            x = rng.normal(0, 1, k)
            pm = float(np.expm1(2.7 + x @ coef + rng.normal(0, 0.2)))
            fid = f"c{c}-{f}"
            frames.append({"id": fid, "camera_id": f"c{c}", "captured_at": at,
                           "received_at": at, "width": 1, "height": 1, "size_bytes": 1,
                           "sha256": f"{c}-{f}"})  # fmt: skip
            verdicts.append({"frame_id": fid, "kind": CameraKind.sky, "camera_id": f"c{c}",
                             "mode_r": int(100 + 10 * x[0]), "mode_g": int(120 + 10 * x[1]),
                             "mode_b": int(160 + 10 * x[2]), "mean_r": 0.0, "mean_g": 0.0,
                             "mean_b": 0.0, "usable": True})  # fmt: skip
            skies.append({"frame_id": fid, "details": {"features": x.tolist()}})
            readings.append({"station_id": f"s{c}", "at": at, "pm25": pm})
    with engine.begin() as conn:
        for table, rows in (
            (Camera, cams), (AirStation, stations), (Frame, frames), (Verdict, verdicts),
            (SkyVerdict, skies), (StationReading, readings),
        ):  # fmt: skip
            for start in range(0, len(rows), 20_000):
                conn.execute(insert(table.__table__), rows[start : start + 20_000])
    engine.dispose()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cameras", type=int, default=1000)
    parser.add_argument("--backend", choices=["sqlite", "postgresql"], default="sqlite")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        url = None
        if args.backend == "postgresql":
            url = "postgresql+psycopg://postgres@127.0.0.1:5432/bench_stations"
            admin = create_engine("postgresql+psycopg://postgres@127.0.0.1:5432/test",
                                  isolation_level="AUTOCOMMIT")  # fmt: skip
            with admin.connect() as conn:
                conn.execute(text("DROP DATABASE IF EXISTS bench_stations"))
                conn.execute(text("CREATE DATABASE bench_stations"))
            admin.dispose()
        app, db = app_of(Path(tmp), url)
        print(f"{args.backend}:")
        with TestClient(app) as client:  # type: ignore[arg-type]
            imports(client)
            t = time.perf_counter()
            cameras(db, args.cameras)
            print(f"  {args.cameras} cameras' {args.cameras * FRAMES} frames written in "
                  f"{time.perf_counter() - t:.1f} s")  # fmt: skip
            state = client.app.state  # type: ignore[attr-defined]
            timing = Timing()
            for name in ("first pass (methods chosen)", "second pass (rolling)"):
                t = time.perf_counter()
                done = rolling.recalibrate_all(state.sessionmaker, timing, days=30_000, max_km=10.0)
                dt = time.perf_counter() - t
                print(f"  rolling calibration, {name}: {len(done.recalibrated)} cameras in "
                      f"{dt:.1f} s ({1000 * dt / max(len(done.recalibrated), 1):.0f} ms each); "
                      f"skipped {len(done.skipped)}")  # fmt: skip


if __name__ == "__main__":
    main()
