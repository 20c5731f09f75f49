"""Frame retention with a controllable clock, and the orphan-file sweep."""

from __future__ import annotations

import os
from datetime import UTC, datetime
from typing import Any

from fastapi.testclient import TestClient
from sqlalchemy import Engine, text

from app.platform.frames import retention
from app.platform.frames.storage import DiskFrameStore, digest, pack_of, relative_path
from tests.factories import Clock, table_counts
from tests.factories.solar import CLEAN_RGB, clean_set, panel_jpeg


def test_old_frames_go_frames_in_use_stay(
    client: TestClient, admin: dict[str, str], app: Any, engine: Engine, settings: Any
) -> None:
    from dataclasses import replace

    clock = Clock()
    app.state.timing = replace(app.state.timing, clock=clock)
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
    assert r.json() == {"frames": 2, "files": 1, "images": 0}  # the seven's pack, its hour
    kept = {f["frame_id"] for f in client.get("/cameras/c/frames", headers=admin).json()}
    assert kept == {*ids[:5], fresh.json()["frame_id"]}
    assert table_counts(engine)["verdicts"] == 6
    # the baseline's frames were moved into the current hour's pack, bytes intact
    assert [p.split("/")[1] for p in store.packs()] == ["2026-07-11T08"]
    for frame_id, body in zip(ids[:5], clean_set(7), strict=False):
        image = client.get(f"/frames/{frame_id}/image", headers=admin)
        assert image.status_code == 200
        assert image.content == body
    again = client.post("/admin/retention/sweep", headers=admin).json()
    assert again == {"frames": 0, "files": 0, "images": 0}
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


def test_packs_no_row_refers_to_are_swept(
    client: TestClient, admin: dict[str, str], app: Any, engine: Engine
) -> None:
    """Packs left by a process killed before any of their frames' rows was committed go; a
    pack a live process writes to stays, and so does one whose last frame alone has a row."""
    cam = client.post("/cameras", json={"id": "c", "kind": "rig"}, headers=admin).json()
    headers = {"Authorization": f"Bearer {cam['token']}", "Content-Type": "image/jpeg"}
    posted = [
        client.post("/cameras/c/frames", content=panel_jpeg(CLEAN_RGB, seed=k), headers=headers)
        for k in range(2)
    ]
    assert [r.status_code for r in posted] == [201, 201]
    store = app.state.frame_store
    (live,) = store.packs()
    now = datetime.now(UTC)

    def dead_process_pack(bodies: list[bytes]) -> tuple[str, list[str]]:
        other = DiskFrameStore(store.root)  # another process's store, then that process gone
        locators = [other.put(b, digest(b), now) for b in bodies]
        other.close()
        return str(pack_of(locators[0])), locators

    orphan, _ = dead_process_pack([b"\xff\xd8 one", b"\xff\xd8 two"])
    cut, _ = dead_process_pack([b"\xff\xd8 cut short"])
    with open(store.path(cut), "r+b") as f:
        f.truncate(10)
    # the rows of all but its last frame were not committed: found past the first chunk
    many = [b"\xff\xd8 %d" % k for k in range(retention.PACK_CHUNK + 5)]
    partial, locators = dead_process_pack(many)
    referenced = locators[-1]
    with engine.begin() as conn:
        conn.execute(
            text("UPDATE frames SET stored_path = :p WHERE id = :id"),
            {"p": referenced, "id": posted[1].json()["frame_id"]},
        )
    assert retention.sweep_orphans(app.state.sessionmaker, store) == 0  # too young: in flight?
    for pack in store.packs():
        os.utime(store.path(pack), (10_000, 10_000))
    assert retention.sweep_orphans(app.state.sessionmaker, store) == 2
    assert store.packs() == sorted([live, partial])
    store.close()  # the live pack is retired, but a row refers to its frame: it stays
    assert retention.sweep_orphans(app.state.sessionmaker, store, min_age_s=0) == 0
    assert store.packs() == sorted([live, partial])
    first = client.get(f"/frames/{posted[0].json()['frame_id']}/image", headers=admin)
    assert first.content == posted[0].request.content
    second = client.get(f"/frames/{posted[1].json()['frame_id']}/image", headers=admin)
    assert second.content == many[-1]
