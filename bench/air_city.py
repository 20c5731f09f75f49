"""A city's trial of the fixed Milan webcam, through the API, as a city would run it.

An in-process service (SQLite in a temporary directory, frames kept 1,000 days: the series is
from 2025) gets one sky camera at Milan per breakpoint table, and one calibrated without naming
a table (the default for its place), with the ROI of the webcam's sky
(``[0, 32, 1920, 298]``). The frames of the earlier two thirds of the days in
``milan_series`` are posted with their capture times and calibrated (``method=regression``)
from the stored frames with the station's PM2.5; then the later days' frames are posted and
their verdicts read. Printed,
per table: Spearman's ρ of the verdicts' levels against −PM2.5 and of their estimates against
PM2.5, the share of frames with a level and of uncertain frames, and how often the frames the
service is sure of are in the right category. ``bench/airquality_eval.py`` computes the same
split from the features directly; the two must agree.

    python bench/air_city.py [--data ../shared/data/sky/milan_series]
"""

from __future__ import annotations

import argparse
import csv
import sys
import tempfile
from datetime import datetime
from pathlib import Path
from typing import Any

import numpy as np
from fastapi.testclient import TestClient
from scipy.stats import spearmanr

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from app.air.core import airquality, breakpoints  # noqa: E402
from app.main import create_app  # noqa: E402
from app.platform.settings import Settings  # noqa: E402
from bench.airquality_eval import earlier_days, milan_times  # noqa: E402
from tests.factories import migrate  # noqa: E402

TOKEN = "bench-admin-token-0123456789abcdef"
ADMIN = {"Authorization": f"Bearer {TOKEN}"}
ROI = [0, 32, 1920, 298]
"""The webcam's sky at 1920×1080: below the top overlay ribbon, above the skyline."""


def post(client: TestClient, camera: str, token: str, jpeg: bytes, taken: datetime) -> Any:
    r = client.post(
        f"/cameras/{camera}/frames",
        content=jpeg,
        headers={"Authorization": f"Bearer {token}", "Content-Type": "image/jpeg"},
        params={"captured_at": taken.isoformat()},
    )
    assert r.status_code == 201, r.text
    return r.json()


def trial(client: TestClient, root: Path, rows: list[dict[str, str]], given: str | None) -> None:
    """Calibrate a new Milan camera by the breakpoint table ``given`` (None: the service's
    default for the camera's place) and grade its later days."""
    camera = f"milan-{given or 'default'}"
    r = client.post(
        "/cameras",
        json={"id": camera, "kind": "sky", "lat": 45.46, "lon": 9.19, "roi": ROI},
        headers=ADMIN,
    )
    assert r.status_code == 201, r.text
    token = r.json()["token"]
    times = milan_times(rows)
    days = sorted({r["date"] for r in rows})
    k = earlier_days(days)
    cut = days[k]
    earlier = [i for i, r in enumerate(rows) if r["date"] < cut]
    later = [i for i, r in enumerate(rows) if r["date"] >= cut]
    frames = [
        post(client, camera, token, (root / rows[i]["file"]).read_bytes(), times[i])["frame_id"]
        for i in earlier
    ]
    r = client.post(
        "/air/calibration",
        json={"frame_ids": frames, "pm25": [float(rows[i]["pm25_ugm3"]) for i in earlier]},
        params={
            "method": "regression",
            "applies_to": camera,
            **({"breakpoints": given} if given else {}),
        },
        headers=ADMIN,
    )
    assert r.status_code == 201, r.text
    table = r.json()["regression"]["breakpoints"]
    verdicts = [
        post(client, camera, token, (root / rows[i]["file"]).read_bytes(), times[i])["verdict"]
        for i in later
    ]
    pm = np.array([float(rows[i]["pm25_ugm3"]) for i in later])
    level = np.array([np.nan if v["level"] is None else v["level"] for v in verdicts])
    estimate = np.array([v["estimate"]["value"] for v in verdicts])
    uncertain = np.array([bool(v["uncertain"]) for v in verdicts])
    levelled = np.isfinite(level)
    truth = [airquality.category(breakpoints.level_of_pm25(p, table)) for p in pm]
    sure_right = [v["category"] == t for v, t in zip(verdicts, truth, strict=True) if v["category"]]
    how = "given" if given else "the default for the camera's place"
    print(
        f"{breakpoints.TABLES[table]} ({how}): {len(earlier)} frames of {k} days "
        f"calibrate, {len(later)} frames of the later {len(days) - k} graded"
    )
    print(
        f"  level ρ = {spearmanr(level[levelled], -pm[levelled])[0]:+.3f} "
        f"({levelled.mean():.0%} of frames have a level)"
    )
    print(f"  estimate ρ = {spearmanr(estimate, pm)[0]:+.3f}")
    print(
        f"  uncertain {uncertain.mean():.0%}; the sure frames' category right in "
        f"{np.mean(sure_right) if sure_right else float('nan'):.0%} of {len(sure_right)}"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--data", type=Path, default=ROOT.parent / "shared" / "data" / "sky" / "milan_series"
    )
    args = parser.parse_args()
    with open(args.data / "labels.csv") as f:
        rows = list(csv.DictReader(f))
    with tempfile.TemporaryDirectory() as tmp:
        settings = Settings(
            data_dir=Path(tmp),
            admin_token=TOKEN,  # type: ignore[arg-type]
            frame_retention_days=1000.0,
            log_level="WARNING",
        )
        migrate(settings.effective_database_url)
        with TestClient(create_app(settings)) as client:
            for given in (None, *breakpoints.TABLES):
                trial(client, args.data, rows, given)


if __name__ == "__main__":
    main()
