"""Panels over HTTP: verdicts, changes to a panel, the farm at a glance, snow."""

from __future__ import annotations

import itertools
from typing import Any

import numpy as np
import pytest
from fastapi.testclient import TestClient

from tests.factories import Clock, bearer, table_counts
from tests.factories.solar import (
    CLEAN_RGB,
    DUST,
    SAND,
    TASK_FACTS,
    clean_set,
    dirty_with_a_task,
    panel_jpeg,
    post_frame,
    status,
    store_farm,
    train,
)


class TestVerdicts:
    def test_clean_and_dirty(self, client: TestClient, admin: dict[str, str], farm: Any) -> None:
        train(client, admin, clean_set(10))
        v = post_frame(client, farm, CLEAN_RGB)
        assert v["clean"] is True
        assert v["method"] == "baseline"
        assert v["f_stat"] < v["threshold"]
        assert v["p_value"] > 0.05
        d = post_frame(client, farm, CLEAN_RGB + DUST)
        assert d["clean"] is False
        assert d["f_stat"] > d["threshold"]
        assert d["t2"] > 0
        assert d["state"] == "clean"  # one dirty frame: debounce

    def test_no_baseline(self, client: TestClient, farm: Any) -> None:
        v = post_frame(client, farm, CLEAN_RGB)
        assert v["clean"] is None
        assert "no baseline" in v["reason"]
        assert v["state"] == "no_baseline"

    def test_night_frame_is_not_judged(
        self, client: TestClient, admin: dict[str, str], farm: Any
    ) -> None:
        train(client, admin, clean_set(10))
        post_frame(client, farm, CLEAN_RGB + DUST)
        v = post_frame(client, farm, CLEAN_RGB, gain=0.1)
        assert v["clean"] is None
        assert "dark" in v["reason"]
        assert status(client, admin)["dirty_streak"] == 1


class TestPanelChanges:
    def test_a_retired_panel_sends_no_robot_and_takes_no_camera(
        self, client: TestClient, admin: dict[str, str], farm: Any, engine: Any
    ) -> None:
        """A panel removed from the farm with a cleaning task open. Before, panels could not be
        retired: its task stayed pending, and robots went on being sent to it."""
        r1 = bearer(farm["robots"]["r1"])
        dirty_with_a_task(client, admin, farm)
        task_id = client.post("/cleaning/claim", headers=r1).json()["task_id"]

        before = table_counts(engine)
        r = client.delete("/panels/p1", headers=admin)  # camera c1 still watches it
        assert r.status_code == 409, r.text
        assert r.json()["code"] == "panel_in_use"
        assert "c1" in r.json()["detail"]
        assert table_counts(engine) == before
        assert status(client, admin)["state"] == "cleaning"

        assert client.post("/panels", json={"id": "p2"}, headers=admin).status_code == 201
        moved = client.patch("/cameras/c1", json={"panel_id": "p2"}, headers=admin)
        assert moved.status_code == 200, moved.text
        assert client.delete("/panels/p1", headers=admin).status_code == 204

        task = client.get(f"/cleaning/tasks/{task_id}", headers=admin).json()
        assert (task["status"], task["outcome"]) == ("cancelled", "panel_retired")
        assert client.post(f"/cleaning/tasks/{task_id}/complete", headers=r1).status_code == 409
        assert client.post("/cleaning/claim", headers=r1).status_code == 204
        trigger = client.get("/panels/p1/trigger", headers=r1).json()
        assert trigger == {"panel_id": "p1", "clean_now": False, "task_id": None}
        shown = status(client, admin)
        assert shown["retired_at"] is not None
        assert shown["open_task"] is None

        assert [p["id"] for p in client.get("/panels", headers=admin).json()] == ["p2"]
        every = client.get("/panels", params={"retired": True}, headers=admin).json()
        assert [(p["id"], p["retired_at"] is None) for p in every] == [("p1", False), ("p2", True)]

        before = table_counts(engine)
        for r in (
            client.post("/panels", json={"id": "p1"}, headers=admin),
            client.post(
                "/cameras", json={"id": "c9", "kind": "panel", "panel_id": "p1"}, headers=admin
            ),
            client.patch("/cameras/c1", json={"panel_id": "p1"}, headers=admin),
            train(client, admin, clean_set(6)),
            client.patch("/panels/p1", json={"name": "gone"}, headers=admin),
        ):
            assert r.status_code == 409, r.text
            assert r.json()["code"] == "panel_retired"
        assert table_counts(engine) == before
        # and each of those routes says in the schema that it may answer 409
        paths = client.get("/openapi.json").json()["paths"]
        for path, method in (
            ("/panels", "post"),
            ("/cameras", "post"),
            ("/cameras/{camera_id}", "patch"),
            ("/panels/{panel_id}/baseline", "post"),
            ("/panels/{panel_id}", "patch"),
        ):
            assert "409" in paths[path][method]["responses"], (method, path)
        again = client.get("/panels", params={"retired": True}, headers=admin).json()[0]
        assert client.delete("/panels/p1", headers=admin).status_code == 204
        assert client.get("/panels", params={"retired": True}, headers=admin).json()[0] == again

    def test_a_frame_judged_from_a_stale_camera_view_does_not_revive_it(
        self, client: TestClient, admin: dict[str, str], farm: Any, engine: Any
    ) -> None:
        """Another process may take camera c1 to watch p1 for up to its cache's 10 s after c1
        was moved: its frames are judged again for the panel c1 watches now, and open no task
        for the retired one."""
        from sqlalchemy import text

        dirty_with_a_task(client, admin, farm)  # c1 is in this process's cache now
        assert client.post("/panels", json={"id": "p2"}, headers=admin).status_code == 201
        with engine.begin() as conn:  # moved by another process: this one's cache is stale
            conn.execute(text("UPDATE cameras SET panel_id = 'p2' WHERE id = 'c1'"))
        assert client.delete("/panels/p1", headers=admin).status_code == 204
        for _ in range(3):
            v = post_frame(client, farm, CLEAN_RGB + DUST)
            assert v["panel_id"] == "p2"
            assert v["clean"] is None  # p2 has no baseline of its own
        tasks = client.get(
            "/cleaning/tasks", params={"panel_id": "p1", "status": "open"}, headers=admin
        ).json()
        assert tasks == []

    def test_a_panel_is_renamed_and_moved(self, client: TestClient, admin: dict[str, str]) -> None:
        body = {"id": "p", "name": "row 3", "lat": 45.0, "lon": 9.0}
        assert client.post("/panels", json=body, headers=admin).status_code == 201
        half = client.patch("/panels/p", json={"name": "row 4", "lat": None}, headers=admin)
        assert half.status_code == 422  # a longitude alone is no place
        assert half.json()["code"] == "half_a_place"
        assert client.get("/panels/p", headers=admin).json()["name"] == "row 3"
        r = client.patch("/panels/p", json={"name": "row 4", "lat": 45.5}, headers=admin)
        assert r.status_code == 200, r.text
        assert {k: r.json()[k] for k in body} == {
            "id": "p",
            "name": "row 4",
            "lat": 45.5,
            "lon": 9.0,
        }
        unplaced = client.patch("/panels/p", json={"lat": None, "lon": None}, headers=admin)
        assert (unplaced.json()["lat"], unplaced.json()["lon"]) == (None, None)
        lone = client.post("/panels", json={"id": "q", "lon": 9.0}, headers=admin)
        assert lone.status_code == 422
        assert lone.json()["detail"] == "lon without lat: a place needs both (or neither)"
        assert client.get("/panels/p", headers=admin).json()["name"] == "row 4"
        for bad in ('{"lat": 91}', '{"lon": NaN}', '{"id": "q"}', '{"colour": "blue"}'):
            r = client.patch(
                "/panels/p", content=bad, headers={**admin, "Content-Type": "application/json"}
            )
            assert r.status_code == 422, bad
        assert client.patch("/panels/nope", json={}, headers=admin).status_code == 404
        assert client.delete("/panels/nope", headers=admin).status_code == 404


class TestTheFarmAtAGlance:
    """Every panel's state in one query (``panels.state_column``), against the state its own
    status reads (``panel_state.state_of`` over its facts), for every combination of facts."""

    @pytest.mark.parametrize("fleet", [False, True])
    def test_every_panels_state_as_its_status_reads_it(
        self,
        client: TestClient,
        admin: dict[str, str],
        engine: Any,
        clock: Clock,
        fleet: bool,
    ) -> None:
        every = itertools.product(
            (False, True), (0, 2, 3), (None, True, False), (False, True), TASK_FACTS
        )  # the debounce is 3
        ids = store_farm(engine, clock(), list(every), fleet=fleet)
        assert len(ids) == 180
        status = {
            pid: client.get(f"/panels/{pid}/status", headers=admin).json()["state"] for pid in ids
        }
        listed = client.get("/panels", params={"limit": 1000}, headers=admin).json()
        assert {p["id"]: p["state"] for p in listed} == status
        assert {
            pid: client.get(f"/panels/{pid}", headers=admin).json()["state"] for pid in ids[:30]
        } == {pid: status[pid] for pid in ids[:30]}
        # every state occurs, so the comparison above covers each branch
        wanted = {"clean", "needs_cleaning", "cleaning", "no_baseline" if not fleet else "unknown"}
        assert wanted <= set(status.values())
        counts = client.get("/panel-states", headers=admin).json()
        assert counts["total"] == 180
        assert counts["states"] == {
            s: sum(v == s for v in status.values())
            for s in ("no_baseline", "unknown", "clean", "needs_cleaning", "cleaning")
        }
        for s in ("needs_cleaning", "cleaning"):
            page = client.get("/panels", params={"state": s, "limit": 1000}, headers=admin).json()
            assert [p["id"] for p in page] == sorted(k for k, v in status.items() if v == s)
        both = client.get(
            "/panels",
            params=[("state", "needs_cleaning"), ("state", "cleaning"), ("limit", "7")],
            headers=admin,
        ).json()
        assert [p["id"] for p in both] == sorted(
            k for k, v in status.items() if v in ("needs_cleaning", "cleaning")
        )[:7]

    def test_states_follow_the_robot_loop_and_bad_states_are_422(
        self, client: TestClient, admin: dict[str, str], farm: Any
    ) -> None:
        counts = client.get("/panel-states", headers=admin).json()["states"]
        assert counts["no_baseline"] == 1
        assert client.get("/panels", headers=admin).json()[0]["state"] == "no_baseline"
        r = client.get("/panels", params={"state": "dusty"}, headers=admin)
        assert r.status_code == 422
        robot = bearer(farm["robots"]["r1"])
        assert client.get("/panel-states", headers=robot).status_code == 403
        assert client.get("/panel-states").status_code == 401


SNOW = np.array([210.0, 213.0, 218.0])


class TestSnow:
    def test_a_snowed_panel_is_reported_as_such_and_opens_no_task(
        self, client: TestClient, admin: dict[str, str], farm: Any
    ) -> None:
        rng = np.random.default_rng(8)
        files, labels = [], []
        for i in range(8):
            c = CLEAN_RGB + rng.normal(0, 6, 3)
            for name, rgb in (("clean", c), ("dust", 0.5 * c + 0.5 * SAND), ("snow", SNOW)):
                photo = panel_jpeg(rgb + rng.normal(0, 4, 3), seed=100 * i + len(files))
                files.append(("files", (f"{name}{i}.jpg", photo, "image/jpeg")))
                labels.append(name)
        r = client.post("/fleet/model", files=files, data={"labels": labels}, headers=admin)
        assert r.status_code == 201, r.text
        assert (r.json()["n_snow"], r.json()["n_dirty"], r.json()["n_clean"]) == (8, 8, 8)
        v = post_frame(client, farm, SNOW, seed=5)
        assert (v["method"], v["condition"], v["clean"]) == ("fleet", "snow", None), v
        assert "snow" in v["reason"]
        v = post_frame(client, farm, SNOW, seed=6)
        assert status(client, admin)["open_task"] is None
        v = post_frame(client, farm, 0.5 * CLEAN_RGB + 0.5 * SAND, seed=7)
        assert (v["condition"], v["clean"]) == ("dust", False)

    def test_labels_outside_the_set_are_refused_and_nothing_stored(
        self, client: TestClient, admin: dict[str, str]
    ) -> None:
        files = [
            ("files", (f"{i}.jpg", panel_jpeg(CLEAN_RGB, seed=i), "image/jpeg")) for i in range(2)
        ]
        r = client.post(
            "/fleet/model", files=files, data={"labels": ["clean", "muddy"]}, headers=admin
        )
        assert r.status_code == 422
        assert r.json()["code"] == "unknown_label"
        assert "muddy" in r.json()["detail"]
        assert client.get("/fleet/model", headers=admin).status_code == 404
