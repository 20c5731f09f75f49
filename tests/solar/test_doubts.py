"""The farm teaches the fleet model: the frames it doubted are listed for an operator, who
labels them (clean, dust, bird_drop, snow); labelled frames are kept past retention."""

from __future__ import annotations

from typing import Any

import pytest
from fastapi.testclient import TestClient
from sqlalchemy import select

from app.solar.kind import HANDLER
from app.solar.models import FrameLabel
from tests.factories import Clock, bearer
from tests.factories.air import sky_jpeg
from tests.factories.solar import (
    CLEAN_RGB,
    DUST,
    clean_set,
    fleet_photos,
    post_frame,
    train,
    train_fleet,
)


@pytest.fixture
def doubted(client: TestClient, admin: dict[str, str], clock: Clock) -> dict[str, Any]:
    """A fleet model, and three frames of a camera that sees a street under the sky, no
    panel: doubted."""
    assert client.post("/panels", json={"id": "p1"}, headers=admin).status_code == 201
    train_fleet(client, admin)
    cam = {"id": "c2", "kind": "panel", "panel_id": "p1"}
    token = client.post("/cameras", json=cam, headers=admin).json()["token"]
    frames = []
    for k in range(3):
        clock.advance(minutes=10)
        r = client.post(
            "/cameras/c2/frames",
            content=sky_jpeg(6.0, seed=k),
            headers={**bearer(token), "Content-Type": "image/jpeg"},
        )
        assert r.status_code == 201, r.text
        assert r.json()["verdict"]["clean"] is None
        frames.append(r.json()["frame_id"])
    viewer = client.post("/viewers", json={"name": "board"}, headers=admin).json()["token"]
    return {"frames": frames, "viewer": bearer(viewer), "camera": bearer(token)}


def test_doubted_frames_are_listed_newest_first(
    client: TestClient, admin: dict[str, str], doubted: dict[str, Any]
) -> None:
    listed = client.get("/fleet/doubts", headers=doubted["viewer"])
    assert listed.status_code == 200, listed.text
    rows = listed.json()
    assert [d["frame_id"] for d in rows] == doubted["frames"][::-1]
    assert all(d["reason"].startswith("unlike the panel photos") for d in rows)
    assert all(d["label"] is None for d in rows)
    image = client.get(rows[0]["image"], headers=doubted["viewer"])
    assert image.status_code == 200
    assert image.headers["content-type"] == "image/jpeg"
    assert client.get("/fleet/doubts", headers=doubted["camera"]).status_code == 403


def test_an_operator_labels_them(
    client: TestClient, admin: dict[str, str], doubted: dict[str, Any]
) -> None:
    first, second, _ = doubted["frames"]
    r = client.put(f"/fleet/labels/{first}", json={"label": "dust"}, headers=admin)
    assert r.status_code == 200, r.text
    assert (r.json()["label"], r.json()["source"]) == ("dust", "operator")
    client.put(f"/fleet/labels/{second}", json={"label": "clean"}, headers=admin)
    client.put(f"/fleet/labels/{second}", json={"label": "bird_drop"}, headers=admin)  # replaced
    left = client.get("/fleet/doubts", headers=admin).json()
    assert [d["frame_id"] for d in left] == [doubted["frames"][2]]
    every = client.get("/fleet/doubts", params={"unlabelled": False}, headers=admin).json()
    assert {d["frame_id"]: d["label"] for d in every}[first] == "dust"
    counts = client.get("/fleet/labels", headers=doubted["viewer"]).json()
    assert counts == {"counts": {"clean": 0, "dust": 1, "bird_drop": 1, "snow": 0}, "total": 2}
    # what the farm labelled is kept past retention: training data
    with client.app.state.sessionmaker() as session:
        assert {first, second} <= set(HANDLER.kept_frames(session))
    assert client.delete(f"/fleet/labels/{first}", headers=admin).status_code == 204
    assert client.delete(f"/fleet/labels/{first}", headers=admin).status_code == 404


def test_bad_labels_are_refused_and_change_nothing(
    client: TestClient, admin: dict[str, str], doubted: dict[str, Any]
) -> None:
    first = doubted["frames"][0]
    viewer = client.put(f"/fleet/labels/{first}", json={"label": "dust"}, headers=doubted["viewer"])
    assert viewer.status_code == 403
    shiny = client.put(f"/fleet/labels/{first}", json={"label": "shiny"}, headers=admin)
    assert shiny.status_code == 422
    assert "label" in shiny.json()["detail"]
    missing = client.put("/fleet/labels/no-such-frame", json={"label": "dust"}, headers=admin)
    assert missing.status_code == 422
    assert "no-such-frame" in missing.json()["detail"]
    sky = client.post("/cameras", json={"id": "s1", "kind": "sky"}, headers=admin).json()
    up = client.post(
        "/cameras/s1/frames",
        content=sky_jpeg(5),
        headers={**bearer(sky["token"]), "Content-Type": "image/jpeg"},
    )
    other = client.put(
        f"/fleet/labels/{up.json()['frame_id']}", json={"label": "clean"}, headers=admin
    )
    assert other.status_code == 422
    assert "sky camera's, not a panel's" in other.json()["detail"]
    assert client.get("/fleet/labels", headers=admin).json()["total"] == 0


def test_the_model_learns_from_the_farms_labels(
    client: TestClient, admin: dict[str, str], doubted: dict[str, Any]
) -> None:
    """The doubted frames, labelled dust, join the uploaded photos: the model counts them,
    each measured in its camera's region, and says what its figure would have been without
    them; unlabelled frames are refused by name."""
    before = client.get("/fleet/model", headers=admin).json()
    for frame in doubted["frames"]:
        client.put(f"/fleet/labels/{frame}", json={"label": "dust"}, headers=admin)
    files, labels = fleet_photos()
    data = {"labels": labels, "frame_ids": doubted["frames"]}
    r = client.post("/fleet/model", files=files, data=data, headers=admin)
    assert r.status_code == 201, r.text
    assert r.json()["n_dirty"] == before["n_dirty"] + 3
    model = r.json()
    assert model["cv_low"] <= model["cv_balanced_accuracy"] <= model["cv_high"] <= 1.0
    assert (before["n_farm"], before["cv_without_farm"]) == (0, None)
    assert model["n_farm"] == 3
    assert 0.0 <= model["cv_without_farm"] <= 1.0
    assert r.json()["n_clean"] == before["n_clean"]
    # on their own, three frames of one panel are too few to learn from: said, not a 500
    alone = client.post("/fleet/model", json={"frame_ids": doubted["frames"]}, headers=admin)
    assert alone.status_code == 422, alone.text
    client.delete(f"/fleet/labels/{doubted['frames'][0]}", headers=admin)
    unlabelled = client.post("/fleet/model", files=files, data=data, headers=admin)
    assert unlabelled.status_code == 422
    assert doubted["frames"][0] in unlabelled.json()["detail"]
    assert client.get("/fleet/model", headers=admin).json()["n_dirty"] == before["n_dirty"] + 3


def test_a_robots_cleaning_labels_the_frames_around_it(
    client: TestClient, admin: dict[str, str], clock: Clock
) -> None:
    """p1 judged dirty three times, cleaned by its robot, then seen clean: the last dirty
    frame before the cleaning is labelled dust, the frame that confirmed it clean, both by
    the robot; an operator's label is not overwritten."""
    assert client.post("/panels", json={"id": "p1"}, headers=admin).status_code == 201
    cam = client.post(
        "/cameras", json={"id": "c1", "kind": "panel", "panel_id": "p1"}, headers=admin
    ).json()
    robot = bearer(client.post("/robots", json={"id": "r1"}, headers=admin).json()["token"])
    farm = {"camera": cam["token"], "clock": clock}
    assert train(client, admin, clean_set(10)).status_code == 201
    dirty = []
    for k in range(3):
        post_frame(client, farm, CLEAN_RGB + DUST, seed=k)
        dirty.append(client.get("/cameras/c1/frames", headers=admin).json()[0]["frame_id"])
    task = client.post("/cleaning/claim", headers=robot).json()["task_id"]
    clock.advance(minutes=5)
    assert client.post(f"/cleaning/tasks/{task}/complete", headers=robot).status_code == 200
    post_frame(client, farm, CLEAN_RGB, seed=9)
    after = client.get("/cameras/c1/frames", headers=admin).json()[0]["frame_id"]
    assert client.get(f"/cleaning/tasks/{task}", headers=admin).json()["outcome"] == "effective"
    every = client.get("/fleet/labels", headers=admin).json()
    assert every == {"counts": {"clean": 1, "dust": 1, "bird_drop": 0, "snow": 0}, "total": 2}
    with client.app.state.sessionmaker() as session:
        got = {r.frame_id: (r.label, r.source) for r in session.scalars(select(FrameLabel))}
    assert got == {dirty[-1]: ("dust", "robot"), after: ("clean", "robot")}


def test_a_panel_whose_latest_frame_was_doubted_says_so(
    client: TestClient, admin: dict[str, str], doubted: dict[str, Any]
) -> None:
    [p1] = client.get("/panels", headers=admin).json()
    assert p1["doubted"] is True
    assert client.get("/panels/p1", headers=admin).json()["doubted"] is True
