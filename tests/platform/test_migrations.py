"""Migrations that carry data over (rows written before them read as intended after), and
the history walked down and up again with data in the tables."""

from __future__ import annotations

import json
from collections.abc import Iterator
from dataclasses import replace
from pathlib import Path

import pytest
from alembic import command
from alembic.script import ScriptDirectory
from fastapi.testclient import TestClient
from sqlalchemy import create_engine, text

from app.main import create_app
from app.platform.settings import Settings
from tests import factories
from tests.factories import ADMIN_TOKEN, alembic_config, migrate, postgres_database, table_counts
from tests.factories import air as air_cases
from tests.factories import cells as cell_cases
from tests.factories import solar as solar_cases


def test_verdicts_baselines_and_calibrations_take_their_cameras_region(tmp_path: Path) -> None:
    """Before a4aaa009e2ad and 83094b1d8bb0 no row said which region it was measured in: each
    verdict, and each air calibration made for a camera, takes its camera's; each baseline that
    of its panel's first camera in service."""
    url = f"sqlite:///{tmp_path / 'old.db'}"
    migrate(url, "362c29eee263")
    t = "2026-06-01 08:00:00.000000"
    engine = create_engine(url)
    with engine.begin() as conn:
        for panel in ("p1", "p2"):
            conn.execute(
                text(
                    "INSERT INTO panels (id, created_at, dirty_streak, ineffective) "
                    "VALUES (:p, :t, 0, 0)"
                ),
                {"p": panel, "t": t},
            )
        cameras = [  # id, panel, roi, retired
            ("a", "p1", [1, 2, 30, 40], t),  # retired: not the panel's camera in service
            ("b", "p1", [[0, 0], [9, 0], [0, 9]], None),
            ("c", "p2", None, None),
        ]
        for cid, panel, roi, retired in cameras:
            conn.execute(
                text(
                    "INSERT INTO cameras (id, kind, panel_id, roi, token_hash, created_at, "
                    "retired_at) VALUES (:id, 'panel', :p, :roi, :h, :t, :r)"
                ),
                {
                    "id": cid,
                    "p": panel,
                    "roi": json.dumps(roi),
                    "h": cid * 64,
                    "t": t,
                    "r": retired,
                },
            )
            conn.execute(
                text(
                    "INSERT INTO frames (id, camera_id, captured_at, received_at, width, height, "
                    "size_bytes, sha256) VALUES (:id, :id2, :t, :t, 64, 48, 1, :id)"
                ),
                {"id": f"f{cid}", "id2": cid, "t": t},
            )
            conn.execute(
                text(
                    "INSERT INTO verdicts (frame_id, kind, camera_id, mode_r, mode_g, mode_b, "
                    "mean_r, mean_g, mean_b) VALUES (:f, 'rig', :c, 1, 2, 3, 1, 2, 3)"
                ),
                {"f": f"f{cid}", "c": cid},
            )
        for bid, panel in (("b1", "p1"), ("b2", "p2")):
            conn.execute(
                text(
                    "INSERT INTO baselines (id, panel_id, created_at, n, mean_modes, covariance, "
                    "significance, f_critical, condition_number, shrinkage) VALUES "
                    "(:id, :p, :t, 5, '[1, 2, 3]', '[[1, 0, 0], [0, 1, 0], [0, 0, 1]]', 0.05, "
                    "9.0, 1.0, 0.0)"
                ),
                {"id": bid, "p": panel, "t": t},
            )
        conn.execute(
            text(
                "INSERT INTO air_calibrations (id, created_at, clusters, warnings, n_images, "
                "city_wide) VALUES ('k', :t, '[]', '[]', 5, 0)"
            ),
            {"t": t},
        )
        conn.execute(
            text(
                "INSERT INTO air_calibration_cameras (calibration_id, camera_id) "
                "VALUES ('k', 'a'), ('k', 'c')"
            )
        )

    migrate(url)
    with engine.connect() as conn:
        verdicts = dict(conn.execute(text("SELECT camera_id, roi FROM verdicts")).all())
        baselines = dict(conn.execute(text("SELECT panel_id, roi FROM baselines")).all())
        links = dict(conn.execute(text("SELECT camera_id, roi FROM air_calibration_cameras")).all())
    engine.dispose()
    assert {c: json.loads(r) for c, r in verdicts.items()} == {
        "a": [1, 2, 30, 40],
        "b": [[0, 0], [9, 0], [0, 9]],
        "c": None,
    }
    assert {p: json.loads(r) for p, r in baselines.items()} == {
        "p1": [[0, 0], [9, 0], [0, 9]],
        "p2": None,
    }
    assert {c: json.loads(r) for c, r in links.items()} == {"a": [1, 2, 30, 40], "c": None}


def test_verdicts_the_quality_gate_refused_are_marked_unusable(tmp_path: Path) -> None:
    """Before 5b7e2c9d41f3 only the reason said a frame was unusable: the quality gate's
    reasons mark it so; other reasons (no baseline yet) and none leave it usable."""
    url = f"sqlite:///{tmp_path / 'old.db'}"
    migrate(url, "83094b1d8bb0")
    t = "2026-06-01 08:00:00.000000"
    reasons = {
        "dark": "too dark to judge (night?): 95% of pixels below level 31",
        "blank": "blank frame: no detail in any channel (lens covered or camera fault?)",
        "glare": "glare: 41% of the region is saturated",
        "grey": "greyscale frame (camera in night mode?)",
        "occluded": "occluded: 73% of the region is black",
        "waiting": "no baseline: train one (POST /panels/{id}/baseline) or a fleet model",
        "judged": None,
    }
    engine = create_engine(url)
    with engine.begin() as conn:
        conn.execute(
            text(
                "INSERT INTO cameras (id, kind, token_hash, created_at) VALUES ('c', 'rig', :h, :t)"
            ),
            {"h": "c" * 64, "t": t},
        )
        for fid, reason in reasons.items():
            conn.execute(
                text(
                    "INSERT INTO frames (id, camera_id, captured_at, received_at, width, height, "
                    "size_bytes, sha256) VALUES (:id, 'c', :t, :t, 64, 48, 1, :id)"
                ),
                {"id": fid, "t": t},
            )
            conn.execute(
                text(
                    "INSERT INTO verdicts (frame_id, kind, camera_id, mode_r, mode_g, mode_b, "
                    "mean_r, mean_g, mean_b, reason) VALUES (:f, 'rig', 'c', 1, 2, 3, 1, 2, 3, :r)"
                ),
                {"f": fid, "r": reason},
            )

    migrate(url)
    with engine.connect() as conn:
        usable = dict(conn.execute(text("SELECT frame_id, usable FROM verdicts")).all())
    engine.dispose()
    assert {f: bool(u) for f, u in usable.items()} == {
        "dark": False,
        "blank": False,
        "glare": False,
        "grey": False,
        "occluded": False,
        "waiting": True,
        "judged": True,
    }


@pytest.fixture(params=["sqlite", "postgresql"])
def empty_database(request: pytest.FixtureRequest, tmp_path: Path) -> Iterator[str]:
    """A database of its own: a SQLite file, or a new database beside the tests' PostgreSQL."""
    if request.param == "sqlite":
        yield f"sqlite:///{tmp_path / 'vantage.db'}"
        return
    with postgres_database("rollback") as url:
        yield url


@pytest.mark.slow  # a real server or camera process, seconds of waiting
def test_a_deploy_rolled_back_step_by_step_with_data_and_upgraded_again(
    tmp_path: Path, empty_database: str
) -> None:
    """An operator rolling back a release runs ``alembic downgrade`` on a database in use. A
    database the service filled through its API (a panel with a baseline, frames and a
    cleaning task claimed by a robot; a sky camera calibrated, graded and alerting; a cross
    rig; a camera calibration) goes down one revision at a time to the first, then up again
    to head, and the service starts on it and serves."""
    url = empty_database
    migrate(url)
    settings = Settings(
        env="test",
        data_dir=tmp_path / "data",
        database_url=url,
        admin_token=ADMIN_TOKEN,  # type: ignore[arg-type]
        rate_limit_per_minute=0,
    )
    admin = {"Authorization": f"Bearer {ADMIN_TOKEN}"}
    app = create_app(settings)
    clock = factories.Clock()
    app.state.timing = replace(app.state.timing, clock=clock)
    with TestClient(app) as client:
        assert client.post("/panels", json={"id": "p1"}, headers=admin).status_code == 201
        camera = {"id": "c1", "kind": "panel", "panel_id": "p1"}
        token = client.post("/cameras", json=camera, headers=admin).json()["token"]
        robot = client.post("/robots", json={"id": "r1"}, headers=admin).json()["token"]
        farm = {"camera": token, "clock": clock}
        solar_cases.dirty_with_a_task(client, admin, farm)
        claimed = client.post("/cleaning/claim", headers=factories.bearer(robot))
        assert claimed.status_code == 200, claimed.text

        sky = {"id": "sky0", "kind": "sky", "lat": 45.4, "lon": 9.1, "roi": [0, 0, 160, 55]}
        sky_token = client.post("/cameras", json=sky, headers=admin).json()["token"]
        assert air_cases.calibrate(client, admin).status_code == 201
        city = {"tokens": {"sky0": (sky_token, sky["lon"])}, "clock": clock}
        for k, level in enumerate((10, 1, 1, 1)):
            clock.advance(minutes=20)
            air_cases.post(client, city, "sky0", level, seed=k)
        assert client.get("/air/alerts").json()

        rig = {"id": "cell-1", "kind": "cross", "f_px": 800, "ax": 0.3, "ay": 0.2}
        assert client.post("/rigs", json=rig, headers=admin).status_code == 201
        views = cell_cases.rendered_views(4)
        status, _ = cell_cases.upload(client, admin, [(f"{i}.jpg", v) for i, v in enumerate(views)])
        assert status == 201
    engine = create_engine(url)
    filled = table_counts(engine)
    for table in ("frames", "baselines", "cleaning_tasks", "air_alerts", "rigs", "calibrations"):
        assert filled[table] > 0, table

    config = alembic_config(url)
    revisions = len(list(ScriptDirectory.from_config(config).walk_revisions()))
    version = text("SELECT version_num FROM alembic_version")
    with engine.connect() as conn:
        head = conn.scalar(version)
    for _ in range(revisions):
        command.downgrade(config, "-1")
    with engine.connect() as conn:
        assert conn.scalar(version) is None  # at the start of the history
    migrate(url)
    with engine.connect() as conn:
        assert conn.scalar(version) == head
    engine.dispose()
    with TestClient(create_app(settings)) as client:
        assert client.get("/health").json()["status"] == "ok"
        assert client.post("/panels", json={"id": "p2"}, headers=admin).status_code == 201
