"""Frame retention with a controllable clock, and the orphan-file sweep."""

from __future__ import annotations

import os
from typing import Any

from fastapi.testclient import TestClient
from sqlalchemy import Engine

from app.services import retention
from app.services.storage import digest
from tests.api.test_solar import CLEAN_RGB, Clock, clean_set, panel_jpeg
from tests.conftest import table_counts


def test_old_frames_go_frames_in_use_stay(
    client: TestClient, admin: dict[str, str], app: Any, engine: Engine, settings: Any
) -> None:
    from dataclasses import replace

    clock = Clock()
    app.state.policy = replace(app.state.policy, clock=clock)
    client.post("/panels", json={"id": "p"}, headers=admin)
    cam = client.post(
        "/cameras", json={"id": "c", "kind": "panel", "panel_id": "p"}, headers=admin
    ).json()
    headers = {"Authorization": f"Bearer {cam['token']}", "Content-Type": "image/jpeg"}
    ids = []
    for i, body in enumerate(clean_set(7)):
        clock.advance(minutes=1)
        ids.append(
            client.post("/cameras/c/frames", content=body, headers=headers).json()["frame_id"]
        )
        assert i < 7
    # the baseline is trained from the first five: they must outlive the retention
    assert (
        client.post("/panels/p/baseline", json={"frame_ids": ids[:5]}, headers=admin).status_code
        == 201
    )
    clock.advance(days=40)
    fresh = client.post(
        "/cameras/c/frames", content=panel_jpeg(CLEAN_RGB, seed=99), headers=headers
    )
    files_before = len(list((settings.data_dir / "frames").rglob("*.jpg")))
    assert files_before == 8

    r = client.post("/admin/retention/sweep", headers=admin)  # retention: 30 days
    assert r.status_code == 200
    assert r.json() == {"frames": 2, "files": 2}
    kept = {f["frame_id"] for f in client.get("/cameras/c/frames", headers=admin).json()}
    assert kept == {*ids[:5], fresh.json()["frame_id"]}
    assert table_counts(engine)["verdicts"] == 6
    assert len(list((settings.data_dir / "frames").rglob("*.jpg"))) == 6
    assert client.post("/admin/retention/sweep", headers=admin).json() == {"frames": 0, "files": 0}
    assert client.post("/admin/retention/sweep").status_code == 401


def test_orphan_files_are_swept(
    client: TestClient, admin: dict[str, str], app: Any, settings: Any
) -> None:
    cam = client.post("/cameras", json={"id": "c", "kind": "rig"}, headers=admin).json()
    r = client.post(
        "/cameras/c/frames",
        content=panel_jpeg(CLEAN_RGB),
        headers={"Authorization": f"Bearer {cam['token']}", "Content-Type": "image/jpeg"},
    )
    assert r.status_code == 201
    store = app.state.frame_store
    orphan_bytes = panel_jpeg(CLEAN_RGB, seed=7)
    orphan = store.put(orphan_bytes, digest(orphan_bytes))  # as if killed before the commit
    old = 10_000
    for path in store.files():
        os.utime(store.path(path), (old, old))
    assert retention.sweep_orphans(app.state.sessionmaker, store) == 1
    assert store.files() == [f"frames/{r.json()['sha256'][:2]}/{r.json()['sha256']}.jpg"]
    assert orphan not in store.files()
