"""Migrations that carry data over: rows written before them read as intended after."""

from __future__ import annotations

import json
from pathlib import Path

from sqlalchemy import create_engine, text

from tests.conftest import migrate


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
