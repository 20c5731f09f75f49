"""Frame retention with a controllable clock, and the orphan-file sweep."""

from __future__ import annotations

import os
from typing import Any

from fastapi.testclient import TestClient
from sqlalchemy import Engine, text

from app.services import retention
from app.services.storage import digest, relative_path
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
    store = app.state.frame_store
    # the hour of the seven, and the fresh frame's hour
    assert [p.split("/")[1] for p in store.packs()] == ["2026-06-01T08", "2026-07-11T08"]

    r = client.post("/admin/retention/sweep", headers=admin)  # retention: 30 days
    assert r.status_code == 200
    assert r.json() == {"frames": 2, "files": 1}  # the seven's pack, its hour expired
    kept = {f["frame_id"] for f in client.get("/cameras/c/frames", headers=admin).json()}
    assert kept == {*ids[:5], fresh.json()["frame_id"]}
    assert table_counts(engine)["verdicts"] == 6
    # the baseline's frames were moved into the current hour's pack, bytes intact
    assert [p.split("/")[1] for p in store.packs()] == ["2026-07-11T08"]
    for frame_id, body in zip(ids[:5], clean_set(7), strict=False):
        image = client.get(f"/frames/{frame_id}/image", headers=admin)
        assert image.status_code == 200
        assert image.content == body
    assert client.post("/admin/retention/sweep", headers=admin).json() == {"frames": 0, "files": 0}
    assert client.post("/admin/retention/sweep").status_code == 401


def test_orphan_files_are_swept(
    client: TestClient, admin: dict[str, str], app: Any, engine: Engine
) -> None:
    """Frames stored as files of their own (as earlier versions did) are still served, and
    swept when no row refers to them: a process killed between the file and its row."""
    cam = client.post("/cameras", json={"id": "c", "kind": "rig"}, headers=admin).json()
    body = panel_jpeg(CLEAN_RGB)
    r = client.post(
        "/cameras/c/frames",
        content=body,
        headers={"Authorization": f"Bearer {cam['token']}", "Content-Type": "image/jpeg"},
    )
    assert r.status_code == 201
    store = app.state.frame_store
    legacy = relative_path(r.json()["sha256"])
    store.path(legacy).parent.mkdir(parents=True)
    store.path(legacy).write_bytes(body)
    with engine.begin() as conn:
        conn.execute(
            text("UPDATE frames SET stored_path = :p WHERE id = :id"),
            {"p": legacy, "id": r.json()["frame_id"]},
        )
    orphan_bytes = panel_jpeg(CLEAN_RGB, seed=7)
    orphan = relative_path(digest(orphan_bytes))
    store.path(orphan).parent.mkdir(parents=True, exist_ok=True)
    store.path(orphan).write_bytes(orphan_bytes)
    assert retention.sweep_orphans(app.state.sessionmaker, store) == 0  # too young: in flight?
    old = 10_000
    for path in store.files():
        os.utime(store.path(path), (old, old))
    assert retention.sweep_orphans(app.state.sessionmaker, store) == 1
    assert store.files() == [legacy]
    image = client.get(f"/frames/{r.json()['frame_id']}/image", headers=admin)
    assert image.content == body
