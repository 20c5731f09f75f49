"""Robots and the cleaning queue over HTTP: the loop from a dirty verdict to a confirmed
cleaning, leases, changes to robots, many robots at once."""

from __future__ import annotations

from datetime import timedelta
from typing import Any

from fastapi.testclient import TestClient

from tests.factories import Clock, bearer
from tests.factories.solar import (
    CLEAN_RGB,
    DUST,
    clean_set,
    dirty_with_a_task,
    panel_jpeg,
    post_frame,
    status,
    train,
)


class TestRobotLoop:
    def test_end_to_end(self, client: TestClient, admin: dict[str, str], farm: Any) -> None:
        robot = bearer(farm["robots"]["r1"])
        assert train(client, admin, clean_set(10)).status_code == 201
        assert client.post("/cleaning/claim", headers=robot).status_code == 204
        for _ in range(2):
            post_frame(client, farm, CLEAN_RGB + DUST)
        assert client.get("/panels/p1/trigger", headers=robot).json()["clean_now"] is False
        v = post_frame(client, farm, CLEAN_RGB + DUST)
        assert v["state"] == "needs_cleaning"
        trig = client.get("/panels/p1/trigger", headers=robot).json()
        assert trig["clean_now"] is True
        task_id = trig["task_id"]
        # more dirty frames never open a second task
        post_frame(client, farm, CLEAN_RGB + DUST)
        assert len(client.get("/cleaning/tasks", headers=admin).json()) == 1

        claim = client.post("/cleaning/claim", headers=robot)
        assert claim.status_code == 200
        assert claim.json()["task_id"] == task_id
        assert status(client, admin)["state"] == "cleaning"
        done = client.post(f"/cleaning/tasks/{task_id}/complete", headers=robot)
        assert done.status_code == 200
        assert done.json()["status"] == "completed"
        assert client.post(f"/cleaning/tasks/{task_id}/complete", headers=robot).status_code == 200
        assert status(client, admin)["state"] == "cleaning"

        v = post_frame(client, farm, CLEAN_RGB)
        assert v["clean"] is True
        assert v["state"] == "clean"
        s = status(client, admin)
        assert s["open_task"] is None
        assert s["ineffective"] is False
        task = client.get(f"/cleaning/tasks/{task_id}", headers=admin).json()
        assert (task["status"], task["outcome"]) == ("closed", "effective")
        assert client.get("/panels/p1/trigger", headers=robot).json() == {
            "panel_id": "p1",
            "clean_now": False,
            "task_id": None,
        }

    def test_frames_taken_before_the_cleaning_do_not_confirm_it(
        self, client: TestClient, admin: dict[str, str], farm: Any
    ) -> None:
        """A camera uploads its backlog after the robot finished: a clean frame taken before
        the dust, then one taken after the dust but before the cleaning. Judged, marked late,
        and the task waits for a frame taken after the cleaning."""
        robot = bearer(farm["robots"]["r1"])
        dirty_with_a_task(client, admin, farm)
        task_id = client.post("/cleaning/claim", headers=robot).json()["task_id"]
        assert client.post(f"/cleaning/tasks/{task_id}/complete", headers=robot).status_code == 200
        clock = farm["clock"]

        def backlog(minutes_ago: int) -> Any:
            taken = clock.now - timedelta(minutes=minutes_ago)
            r = client.post(
                "/cameras/c1/frames",
                content=panel_jpeg(CLEAN_RGB, seed=minutes_ago),
                headers={**bearer(farm["camera"]), "Content-Type": "image/jpeg"},
                params={"captured_at": taken.isoformat()},
            )
            assert r.status_code == 201, r.text
            return r.json()["verdict"]

        for minutes_ago in (60, 5):  # before the dusty frames; after them, before the cleaning
            clock.advance(minutes=1)
            v = backlog(minutes_ago)
            assert v["clean"] is True
            assert v["late"] is True
            assert v["state"] == "cleaning"
        task = client.get(f"/cleaning/tasks/{task_id}", headers=admin).json()
        assert task["status"] == "completed"
        v = post_frame(client, farm, CLEAN_RGB)  # taken now, after the cleaning
        assert v["late"] is False
        assert v["state"] == "clean"
        task = client.get(f"/cleaning/tasks/{task_id}", headers=admin).json()
        assert (task["status"], task["outcome"]) == ("closed", "effective")

    def test_a_backlog_of_dirty_frames_does_not_open_a_task(
        self, client: TestClient, admin: dict[str, str], farm: Any
    ) -> None:
        """Three dusty frames from yesterday arrive after today's clean one: the panel was
        cleaned since; the debounce counts frames in the order they were taken."""
        train(client, admin, clean_set(10))
        assert post_frame(client, farm, CLEAN_RGB)["late"] is False
        for hours_ago in (26, 25, 24):
            taken = farm["clock"].now - timedelta(hours=hours_ago)
            r = client.post(
                "/cameras/c1/frames",
                content=panel_jpeg(CLEAN_RGB + DUST, seed=hours_ago),
                headers={**bearer(farm["camera"]), "Content-Type": "image/jpeg"},
                params={"captured_at": taken.isoformat()},
            )
            v = r.json()["verdict"]
            assert v["clean"] is False
            assert v["late"] is True
            assert v["state"] == "clean"
        s = status(client, admin)
        assert s["open_task"] is None
        assert s["dirty_streak"] == 0

    def test_ineffective_cleaning(
        self, client: TestClient, admin: dict[str, str], farm: Any
    ) -> None:
        robot = bearer(farm["robots"]["r1"])
        dirty_with_a_task(client, admin, farm)
        task_id = client.post("/cleaning/claim", headers=robot).json()["task_id"]
        client.post(f"/cleaning/tasks/{task_id}/complete", headers=robot)
        v = post_frame(client, farm, CLEAN_RGB + DUST)
        assert v["state"] == "needs_cleaning"
        s = status(client, admin)
        assert s["ineffective"] is True
        assert s["open_task"] is None
        assert (
            client.get(f"/cleaning/tasks/{task_id}", headers=admin).json()["outcome"]
            == "ineffective"
        )
        post_frame(client, farm, CLEAN_RGB + DUST)
        assert status(client, admin)["open_task"] is None
        post_frame(client, farm, CLEAN_RGB + DUST)  # the debounce again: a new task
        assert status(client, admin)["open_task"]["status"] == "pending"

    def test_lease_expiry_and_ownership(
        self, client: TestClient, admin: dict[str, str], farm: Any
    ) -> None:
        r1, r2 = bearer(farm["robots"]["r1"]), bearer(farm["robots"]["r2"])
        dirty_with_a_task(client, admin, farm)
        first = client.post("/cleaning/claim", headers=r1).json()
        assert client.post("/cleaning/claim", headers=r2).status_code == 204
        task_id = first["task_id"]
        assert client.post(f"/cleaning/tasks/{task_id}/claim", headers=r2).status_code == 409
        farm["clock"].advance(minutes=11)  # the 10-minute lease runs out
        assert status(client, admin)["state"] == "needs_cleaning"
        second = client.post("/cleaning/claim", headers=r2)
        assert second.status_code == 200
        assert second.json()["task_id"] == task_id
        assert client.post(f"/cleaning/tasks/{task_id}/complete", headers=r1).status_code == 409
        assert client.post(f"/cleaning/tasks/{task_id}/complete", headers=r2).status_code == 200
        assert client.post(f"/cleaning/tasks/{task_id}/complete", headers=r1).status_code == 409
        assert client.post(f"/cleaning/tasks/{task_id}/fail", headers=r2).status_code == 409

    def test_tasks_listed_by_status_as_they_read_and_by_robot(
        self, client: TestClient, admin: dict[str, str], farm: Any
    ) -> None:
        """A failed task, then a second one claimed by r2 whose lease runs out: it reads
        pending, and is listed so, not as claimed."""
        r1, r2 = bearer(farm["robots"]["r1"]), bearer(farm["robots"]["r2"])
        dirty_with_a_task(client, admin, farm)
        failed = client.post("/cleaning/claim", headers=r1).json()["task_id"]
        assert client.post(f"/cleaning/tasks/{failed}/fail", headers=r1).status_code == 200
        post_frame(client, farm, CLEAN_RGB + DUST)
        second = client.post("/cleaning/claim", headers=r2).json()["task_id"]

        def listed(**params: Any) -> list[tuple[str, str]]:
            r = client.get("/cleaning/tasks", params=params, headers=admin)
            assert r.status_code == 200, r.text
            return [(t["task_id"], t["status"]) for t in r.json()]

        assert listed(status="claimed") == [(second, "claimed")]
        assert listed(status="pending") == []
        assert listed(status=["open", "failed"]) == [(second, "claimed"), (failed, "failed")]
        assert listed(robot_id="r1") == [(failed, "failed")]
        farm["clock"].advance(minutes=11)  # r2's lease runs out
        assert listed(status="claimed") == []
        assert listed(status="pending") == [(second, "pending")]
        assert listed(status="open", robot_id="r2") == [(second, "pending")]
        assert listed(status="closed") == []
        r = client.get("/cleaning/tasks", params={"status": "lost"}, headers=admin)
        assert r.status_code == 422
        # a mistyped panel or robot is not one without tasks
        for key in ("panel_id", "robot_id"):
            r = client.get("/cleaning/tasks", params={key: "p9"}, headers=admin)
            assert r.status_code == 404, r.text
            assert "p9" in r.json()["detail"]

    def test_fail_is_idempotent_and_a_new_task_follows(
        self, client: TestClient, admin: dict[str, str], farm: Any
    ) -> None:
        robot = bearer(farm["robots"]["r1"])
        dirty_with_a_task(client, admin, farm)
        task_id = client.post("/cleaning/claim", headers=robot).json()["task_id"]
        for _ in range(2):
            r = client.post(
                f"/cleaning/tasks/{task_id}/fail", json={"reason": "brush"}, headers=robot
            )
            assert r.status_code == 200
            assert r.json()["status"] == "failed"
        assert status(client, admin)["state"] == "needs_cleaning"
        post_frame(client, farm, CLEAN_RGB + DUST)
        new = status(client, admin)["open_task"]
        assert new["status"] == "pending"
        assert new["task_id"] != task_id

    def test_panel_comes_clean_on_its_own(
        self, client: TestClient, admin: dict[str, str], farm: Any
    ) -> None:
        dirty_with_a_task(client, admin, farm)
        task_id = status(client, admin)["open_task"]["task_id"]
        post_frame(client, farm, CLEAN_RGB)
        assert status(client, admin)["state"] == "clean"
        task = client.get(f"/cleaning/tasks/{task_id}", headers=admin).json()
        assert (task["status"], task["outcome"]) == ("cancelled", "not_needed")

    def test_roles(self, client: TestClient, admin: dict[str, str], farm: Any) -> None:
        camera = bearer(farm["camera"])
        assert client.post("/cleaning/claim", headers=camera).status_code == 403
        assert client.post("/cleaning/claim", headers=admin).status_code == 403
        assert client.get("/panels/p1/status", headers=camera).status_code == 403
        assert (
            client.get("/panels/p1/status", headers=bearer(farm["robots"]["r1"])).status_code == 200
        )
        assert client.post("/cleaning/claim").status_code == 401
        assert (
            client.post(
                "/cleaning/tasks/nope/complete", headers=bearer(farm["robots"]["r1"])
            ).status_code
            == 404
        )


class TestRobotChanges:
    def test_a_retired_robot_is_shut_out_and_its_task_goes_to_another_at_once(
        self, client: TestClient, admin: dict[str, str], farm: Any
    ) -> None:
        r1, r2 = bearer(farm["robots"]["r1"]), bearer(farm["robots"]["r2"])
        dirty_with_a_task(client, admin, farm)
        task_id = client.post("/cleaning/claim", headers=r1).json()["task_id"]
        assert client.post("/cleaning/claim", headers=r2).status_code == 204
        assert status(client, admin)["state"] == "cleaning"

        assert client.delete("/robots/r1", headers=admin).status_code == 204
        # well inside the 10-minute lease r1 held
        assert status(client, admin)["state"] == "needs_cleaning"
        assert client.post("/cleaning/claim", headers=r1).status_code == 401
        assert client.post(f"/cleaning/tasks/{task_id}/complete", headers=r1).status_code == 401
        taken = client.post("/cleaning/claim", headers=r2)
        assert taken.status_code == 200, taken.text
        assert taken.json()["task_id"] == task_id
        assert client.post(f"/cleaning/tasks/{task_id}/complete", headers=r2).status_code == 200

        listed = client.get("/robots", headers=admin).json()
        assert [r["id"] for r in listed] == ["r2"]
        every = client.get("/robots", params={"retired": True}, headers=admin).json()
        assert [(r["id"], r["retired_at"] is None) for r in every] == [
            ("r1", False),
            ("r2", True),
        ]

    def test_retiring_again_changes_nothing_and_a_retired_robot_gets_no_token(
        self, client: TestClient, admin: dict[str, str], farm: Any
    ) -> None:
        assert client.delete("/robots/r1", headers=admin).status_code == 204
        when = client.get("/robots", params={"retired": True}, headers=admin).json()[0]
        assert client.delete("/robots/r1", headers=admin).status_code == 204
        again = client.get("/robots", params={"retired": True}, headers=admin).json()[0]
        assert again == when
        r = client.post("/robots/r1/token", headers=admin)
        assert r.status_code == 409, r.text
        assert r.json()["code"] == "robot_retired"
        r = client.post("/robots", json={"id": "r1"}, headers=admin)
        assert (r.status_code, r.json()["code"]) == (409, "robot_retired"), r.text

    def test_a_new_token_shuts_out_the_old_one_at_once(
        self, client: TestClient, admin: dict[str, str], farm: Any
    ) -> None:
        old = bearer(farm["robots"]["r1"])
        assert client.post("/cleaning/claim", headers=old).status_code == 204
        r = client.post("/robots/r1/token", headers=admin)
        assert r.status_code == 200, r.text
        assert r.json()["id"] == "r1"
        new = r.json()["token"]
        assert new.startswith("vr_")
        assert client.post("/cleaning/claim", headers=old).status_code == 401
        assert client.post("/cleaning/claim", headers=bearer(new)).status_code == 204

    def test_unknown_robot_is_404_and_only_the_admin_may_change_robots(
        self, client: TestClient, admin: dict[str, str], farm: Any
    ) -> None:
        robot = bearer(farm["robots"]["r1"])
        assert client.delete("/robots/ghost", headers=admin).status_code == 404
        assert client.post("/robots/ghost/token", headers=admin).status_code == 404
        for r in (
            client.delete("/robots/r2", headers=robot),
            client.post("/robots/r2/token", headers=robot),
        ):
            assert r.status_code == 403
        assert client.delete("/robots/r2").status_code == 401
        assert (
            client.post("/cleaning/claim", headers=bearer(farm["robots"]["r2"])).status_code == 204
        )


def test_twenty_robots_twenty_tasks(
    client: TestClient, admin: dict[str, str], clock: Clock
) -> None:
    """Concurrent claims in one process: each task to exactly one robot."""
    from concurrent.futures import ThreadPoolExecutor

    tokens = []
    for i in range(20):
        client.post("/panels", json={"id": f"p{i}"}, headers=admin)
        cam = client.post(
            "/cameras", json={"id": f"c{i}", "kind": "panel", "panel_id": f"p{i}"}, headers=admin
        ).json()
        files = [
            ("files", (f"{j}.jpg", f, "image/jpeg")) for j, f in enumerate(clean_set(5, seed=i))
        ]
        assert client.post(f"/panels/p{i}/baseline", files=files, headers=admin).status_code == 201
        for k in range(3):
            clock.advance(minutes=1)
            client.post(
                f"/cameras/c{i}/frames",
                content=panel_jpeg(CLEAN_RGB + DUST, seed=k),
                headers={**bearer(cam["token"]), "Content-Type": "image/jpeg"},
            )
        tokens.append(client.post("/robots", json={"id": f"r{i}"}, headers=admin).json()["token"])
    with ThreadPoolExecutor(20) as pool:
        results = list(
            pool.map(lambda t: client.post("/cleaning/claim", headers=bearer(t)), tokens)
        )
    assert all(r.status_code == 200 for r in results)
    assert len({r.json()["task_id"] for r in results}) == 20
