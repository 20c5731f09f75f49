"""Panels and cleaning over HTTP: baselines, verdicts, the robot loop, leases, fleet model."""

from __future__ import annotations

import itertools
from collections.abc import Callable
from datetime import timedelta
from typing import Any

import cv2
import numpy as np
import pytest
from fastapi.testclient import TestClient
from scipy import stats

from tests.factories import (
    CLEAN_RGB,
    DUST,
    SAND,
    TASK_FACTS,
    Clock,
    bearer,
    clean_set,
    dirty_with_a_task,
    panel_jpeg,
    post_frame,
    store_farm,
    table_counts,
    train,
    train_fleet,
)


@pytest.fixture
def farm(client: TestClient, admin: dict[str, str], clock: Clock) -> dict[str, Any]:
    assert client.post("/panels", json={"id": "p1"}, headers=admin).status_code == 201
    cam = client.post(
        "/cameras", json={"id": "c1", "kind": "panel", "panel_id": "p1"}, headers=admin
    ).json()
    robots = {
        rid: client.post("/robots", json={"id": rid}, headers=admin).json()["token"]
        for rid in ("r1", "r2")
    }
    return {"camera": cam["token"], "robots": robots, "clock": clock}


def status(client: TestClient, admin: dict[str, str]) -> Any:
    r = client.get("/panels/p1/status", headers=admin)
    assert r.status_code == 200, r.text
    return r.json()


class TestBaseline:
    def test_from_files(self, client: TestClient, admin: dict[str, str], farm: Any) -> None:
        r = train(client, admin, clean_set(8), significance=0.01)
        assert r.status_code == 201, r.text
        b = r.json()
        assert b["n"] == 8
        np.testing.assert_allclose(b["mean_modes"], CLEAN_RGB, atol=4)
        assert b["f_critical"] == pytest.approx(stats.f.ppf(0.99, 3, 5), rel=1e-12)
        assert status(client, admin)["state"] == "clean"
        assert client.get("/panels/p1/baseline", headers=admin).json()["id"] == b["id"]

    def test_too_few_images(self, client: TestClient, admin: dict[str, str], farm: Any) -> None:
        r = train(client, admin, clean_set(3))
        assert r.status_code == 422
        assert "at least 4" in r.json()["detail"]
        assert status(client, admin)["state"] == "no_baseline"

    @pytest.mark.parametrize("significance", [0, 1e-300, 0.2])
    def test_a_significance_out_of_range_is_422(
        self, client: TestClient, admin: dict[str, str], farm: Any, significance: float
    ) -> None:
        # 1e-300 made the critical F infinite, which no JSON can carry: a 500 before
        r = train(client, admin, clean_set(8), significance=significance)
        assert r.status_code == 422, r.text
        assert r.headers["content-type"] == "application/problem+json"
        assert status(client, admin)["state"] == "no_baseline"

    @pytest.mark.parametrize("shape", [(1, 4000), (4000, 1)], ids=str)
    def test_a_frame_one_pixel_thin_is_judged_not_a_500(
        self, client: TestClient, admin: dict[str, str], farm: Any, shape: tuple[int, int]
    ) -> None:
        image = np.full((*shape, 3), 120, np.uint8)
        r = client.post(
            "/cameras/c1/frames",
            content=cv2.imencode(".jpg", image)[1].tobytes(),
            headers={**bearer(farm["camera"]), "Content-Type": "image/jpeg"},
        )
        assert r.status_code == 201, r.text
        assert r.json()["verdict"]["clean"] is None  # blank, and no baseline yet

    def test_identical_images_then_shrinkage(
        self, client: TestClient, admin: dict[str, str], farm: Any
    ) -> None:
        same = [panel_jpeg(CLEAN_RGB, seed=1)] * 5
        r = train(client, admin, same)
        assert r.status_code == 422
        assert "singular" in r.json()["detail"]
        r = train(client, admin, same, shrinkage=1 / 12)
        assert r.status_code == 201

    def test_unusable_image_is_named(
        self, client: TestClient, admin: dict[str, str], farm: Any
    ) -> None:
        files = [*clean_set(4), panel_jpeg(CLEAN_RGB, gain=0.1)]
        r = train(client, admin, files)
        assert r.status_code == 422
        assert "clean4.jpg" in r.json()["detail"]

    def test_from_stored_frames(self, client: TestClient, admin: dict[str, str], farm: Any) -> None:
        ids = []
        for i, f in enumerate(clean_set(6)):
            r = client.post(
                "/cameras/c1/frames",
                content=f,
                headers={**bearer(farm["camera"]), "Content-Type": "image/jpeg"},
                params={"captured_at": f"2026-05-2{i + 1}T12:00:00Z"},
            )
            assert r.json()["verdict"]["reason"].startswith("no baseline")
            ids.append(r.json()["frame_id"])
        r = client.post("/panels/p1/baseline", json={"frame_ids": ids}, headers=admin)
        assert r.status_code == 201, r.text
        assert r.json()["frame_ids"] == ids
        r = client.post("/panels/p1/baseline", json={"frame_ids": ["nope"]}, headers=admin)
        assert r.status_code == 422

    def test_not_from_stored_frames_the_quality_gate_found_unusable(
        self, client: TestClient, admin: dict[str, str], farm: Any
    ) -> None:
        """Five clean frames and one taken at dusk (gain 0.1: too dark to judge). Uploaded, the
        dark image is refused by name; stored, it was taken into the baseline as clean, and its
        modes (a tenth of the others) stretched the clean class toward black."""
        ids = []
        for i, f in enumerate([*clean_set(5), panel_jpeg(CLEAN_RGB, gain=0.1)]):
            r = client.post(
                "/cameras/c1/frames",
                content=f,
                headers={**bearer(farm["camera"]), "Content-Type": "image/jpeg"},
                params={"captured_at": f"2026-05-2{i + 1}T12:00:00Z"},
            )
            assert r.status_code == 201, r.text
            ids.append(r.json()["frame_id"])
        assert r.json()["verdict"]["reason"].startswith("too dark to judge")
        r = client.post("/panels/p1/baseline", json={"frame_ids": ids}, headers=admin)
        assert r.status_code == 422, r.text
        assert r.headers["content-type"] == "application/problem+json"
        assert (r.json()["code"], r.json()["unusable"]) == ("unusable_frames", ids[5:])
        assert f"{ids[5]}: too dark to judge" in r.json()["detail"]
        assert client.get("/panels/p1/baseline", headers=admin).status_code == 404
        r = client.post("/panels/p1/baseline", json={"frame_ids": ids[:5]}, headers=admin)
        assert r.status_code == 201, r.text

    def test_uploads_are_measured_in_the_region_the_panels_cameras_share(
        self, client: TestClient, admin: dict[str, str], farm: Any
    ) -> None:
        """Two cameras watch p1 through the same region (the left 60 px of 160); the uploads
        are their full frames, mostly a wall. Measured in that region, as the frames will be,
        the baseline is the panel's; measured whole it was the wall's, and clean frames were
        judged dirty."""
        region = [0, 0, 60, 120]
        r = client.patch("/cameras/c1", json={"roi": region}, headers=admin)
        assert r.status_code == 200, r.text
        c2 = {"id": "c2", "kind": "panel", "panel_id": "p1", "roi": region}
        assert client.post("/cameras", json=c2, headers=admin).status_code == 201

        def beside_a_wall(photo: bytes, seed: int) -> bytes:
            image = cv2.imdecode(np.frombuffer(photo, np.uint8), cv2.IMREAD_COLOR)
            rng = np.random.default_rng(seed)
            image[:, 60:] = np.clip(rng.normal((60, 90, 170), 6, (120, 100, 3)), 0, 255)
            return cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, 95])[1].tobytes()

        photos = [beside_a_wall(f, seed=i) for i, f in enumerate(clean_set(8))]
        r = train(client, admin, photos)
        assert r.status_code == 201, r.text
        np.testing.assert_allclose(r.json()["mean_modes"], CLEAN_RGB, atol=4)
        farm["clock"].advance(minutes=10)
        r = client.post(
            "/cameras/c1/frames",
            content=beside_a_wall(panel_jpeg(CLEAN_RGB, seed=50), seed=50),
            headers={**bearer(farm["camera"]), "Content-Type": "image/jpeg"},
        )
        assert r.status_code == 201, r.text
        assert r.json()["verdict"]["clean"] is True


def beside_a_wall(rgb: np.ndarray, seed: int) -> bytes:
    """A panel photo whose right half (x ≥ 80 of 160) is a blue wall."""
    photo = panel_jpeg(rgb, seed=seed)
    image = cv2.imdecode(np.frombuffer(photo, np.uint8), cv2.IMREAD_COLOR)
    rng = np.random.default_rng(seed)
    image[:, 80:] = np.clip(rng.normal((60, 90, 170), 6, (120, 80, 3)), 0, 255)
    return cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, 95])[1].tobytes()


PANEL_PART, WALL_PART = [0, 0, 60, 120], [100, 0, 60, 120]


class TestRegionOfInterest:
    """A baseline describes the modes of one region of the view. Frames measured in another
    (the camera's roi changed since) are not judged by it: a wall compared with a panel's
    clean baseline was called dirty, and three such frames sent a robot."""

    def post(self, client: TestClient, farm: dict[str, Any], seed: int) -> Any:
        farm["clock"].advance(minutes=10)
        r = client.post(
            "/cameras/c1/frames",
            content=beside_a_wall(CLEAN_RGB, seed=seed),
            headers={**bearer(farm["camera"]), "Content-Type": "image/jpeg"},
        )
        assert r.status_code == 201, r.text
        return r.json()

    def roi(self, client: TestClient, admin: dict[str, str], region: list[int]) -> None:
        r = client.patch("/cameras/c1", json={"roi": region}, headers=admin)
        assert r.status_code == 200, r.text

    def test_a_new_region_is_not_judged_by_the_old_baseline(
        self, client: TestClient, admin: dict[str, str], farm: Any
    ) -> None:
        self.roi(client, admin, PANEL_PART)
        r = train(client, admin, [beside_a_wall(CLEAN_RGB, seed=i) for i in range(8)])
        assert r.status_code == 201, r.text
        assert r.json()["roi"] == PANEL_PART
        v = self.post(client, farm, seed=20)["verdict"]
        assert (v["clean"], v["roi"]) == (True, PANEL_PART)

        self.roi(client, admin, WALL_PART)
        for seed in range(21, 25):
            v = self.post(client, farm, seed=seed)["verdict"]
            assert v["clean"] is None, v
            assert v["roi"] == WALL_PART
            assert "no baseline of this panel was measured in" in v["reason"]
            assert "camera's roi [100, 0, 60, 120]" in v["reason"]
            assert "train one from its frames (POST /panels/p1/baseline)" in v["reason"]
        s = status(client, admin)
        assert (s["state"], s["open_task"], s["dirty_streak"]) == ("clean", None, 0)
        assert (
            client.post("/cleaning/claim", headers=bearer(farm["robots"]["r1"])).status_code == 204
        )

        self.roi(client, admin, PANEL_PART)  # back where the baseline was measured
        assert self.post(client, farm, seed=25)["verdict"]["clean"] is True

    def test_a_baseline_is_trained_from_frames_of_the_region_in_use(
        self, client: TestClient, admin: dict[str, str], farm: Any
    ) -> None:
        self.roi(client, admin, PANEL_PART)
        panel = [self.post(client, farm, seed=i)["frame_id"] for i in range(6)]
        self.roi(client, admin, WALL_PART)
        r = client.post("/panels/p1/baseline", json={"frame_ids": panel}, headers=admin)
        assert r.status_code == 422, r.text
        assert r.json()["code"] == "region_not_in_use"
        assert "c1: roi [100, 0, 60, 120]" in r.json()["detail"]

        wall = [self.post(client, farm, seed=i)["frame_id"] for i in range(6, 12)]
        r = client.post("/panels/p1/baseline", json={"frame_ids": wall + panel}, headers=admin)
        assert r.status_code == 422, r.text
        assert r.json()["code"] == "mixed_regions"
        assert client.get("/panels/p1/baseline", headers=admin).status_code == 404

        r = client.post("/panels/p1/baseline", json={"frame_ids": wall}, headers=admin)
        assert r.status_code == 201, r.text
        assert r.json()["roi"] == WALL_PART
        assert self.post(client, farm, seed=12)["verdict"]["clean"] is True


SIDE_RGB = np.array([70.0, 78.0, 118.0])
"""The same clean cells seen from the side: more of the sky's blue in their reflection."""


def test_a_panel_watched_from_two_views_is_judged_in_each_by_its_own_baseline(
    client: TestClient, admin: dict[str, str], farm: Any
) -> None:
    """c1 watches p1 from the front (roi [0, 0, 60, 120]) and c2 from the side (roi
    [10, 10, 50, 100]), where the clean cells look bluer. A baseline per view: c2's, trained
    after c1's, made every frame of c1 unjudged (`clean: null`, "retrain it"), and retraining
    c1's did the same to c2; only one camera could ever be judged."""
    c2 = {"id": "c2", "kind": "panel", "panel_id": "p1", "roi": [10, 10, 50, 100]}
    r = client.post("/cameras", json=c2, headers=admin)
    assert r.status_code == 201, r.text
    side = {**bearer(r.json()["token"]), "Content-Type": "image/jpeg"}
    front = {**bearer(farm["camera"]), "Content-Type": "image/jpeg"}
    assert client.patch("/cameras/c1", json={"roi": PANEL_PART}, headers=admin).status_code == 200
    rng = np.random.default_rng(7)

    def post(headers: dict[str, str], rgb: np.ndarray, seed: int) -> Any:
        farm["clock"].advance(minutes=10)
        camera = "c1" if headers is front else "c2"
        r = client.post(
            f"/cameras/{camera}/frames", content=panel_jpeg(rgb, seed=seed), headers=headers
        )
        assert r.status_code == 201, r.text
        return r.json()

    ids = {
        name: [post(h, rgb + rng.normal(0, 2.0, 3).round(), seed=i)["frame_id"] for i in range(8)]
        for name, h, rgb in (("c1", front, CLEAN_RGB), ("c2", side, SIDE_RGB))
    }
    trained = {}
    for name in ("c1", "c2"):
        r = client.post("/panels/p1/baseline", json={"frame_ids": ids[name]}, headers=admin)
        assert r.status_code == 201, r.text
        trained[name] = r.json()["id"]
    for name in ("c1", "c2"):
        r = client.get("/panels/p1/baseline", params={"camera_id": name}, headers=admin)
        assert (r.status_code, r.json()["id"]) == (200, trained[name]), r.text
    assert client.get("/panels/p1/baseline", headers=admin).json()["id"] == trained["c2"]
    r = client.get("/panels/p1/baseline", params={"camera_id": "nope"}, headers=admin)
    assert r.status_code == 404, r.text

    for seed in (40, 41):
        v = post(front, CLEAN_RGB, seed)["verdict"]
        assert (v["clean"], v["baseline_id"]) == (True, trained["c1"]), v
        v = post(side, SIDE_RGB, seed)["verdict"]
        assert (v["clean"], v["baseline_id"]) == (True, trained["c2"]), v
    v = post(front, CLEAN_RGB + DUST, 42)["verdict"]
    assert (v["clean"], v["baseline_id"]) == (False, trained["c1"]), v
    # the side's clean colour, seen from the front, is not the front's clean
    v = post(front, SIDE_RGB, 43)["verdict"]
    assert v["clean"] is False, v

    # the status gives each view its baseline and the trend of its own verdicts (the panel's
    # `trend` is its newest baseline's: the side's)
    s = status(client, admin)
    assert s["baseline_id"] == trained["c2"]
    assert [(v["camera_id"], v["baseline_id"], v["trend"]["points"]) for v in s["views"]] == [
        ("c1", trained["c1"], 4),
        ("c2", trained["c2"], 2),
    ]
    assert s["trend"]["points"] == 2


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


class TestTrend:
    def test_rising_dust_forecasts_the_crossing(
        self, client: TestClient, admin: dict[str, str], farm: Any
    ) -> None:
        train(client, admin, clean_set(12))
        for day in range(8):
            farm["clock"].advance(days=1)
            post_frame(client, farm, CLEAN_RGB + DUST * day / 40, seed=day)
        trend = status(client, admin)["trend"]
        assert trend["points"] == 8
        assert trend["slope_per_day"] > 0
        assert trend["crossing_at"] is not None
        assert trend["threshold"] > 0

    def test_a_burst_of_frames_is_no_trend(
        self, client: TestClient, admin: dict[str, str], farm: Any
    ) -> None:
        """Frames ten minutes apart (``post_frame``): no slope and no forecast until they span
        an hour."""
        train(client, admin, clean_set(12))
        for k in range(6):
            post_frame(client, farm, CLEAN_RGB + DUST * k / 5, seed=k)
        trend = status(client, admin)["trend"]
        assert trend["points"] == 6
        assert trend["slope_per_day"] is None
        assert trend["crossing_at"] is None
        post_frame(client, farm, CLEAN_RGB + DUST, seed=6)  # 60 minutes after the first
        trend = status(client, admin)["trend"]
        assert trend["slope_per_day"] > 0
        assert trend["crossing_at"] is not None


class TestEvaluate:
    def test_two_sample_and_rates(self, client: TestClient, admin: dict[str, str]) -> None:
        clean = clean_set(12, seed=1)
        rng = np.random.default_rng(2)
        dirty = [
            panel_jpeg(CLEAN_RGB + DUST + rng.normal(0, 2, 3).round(), seed=i) for i in range(6)
        ]
        files = [("clean", (f"c{i}.jpg", f, "image/jpeg")) for i, f in enumerate(clean)]
        files += [("dirty", (f"d{i}.jpg", f, "image/jpeg")) for i, f in enumerate(dirty)]
        r = client.post("/panels/evaluate", files=files, headers=admin)
        assert r.status_code == 200, r.text
        out = r.json()
        assert out["hotelling"]["p_value"] < 1e-6
        assert (out["hotelling"]["df1"], out["hotelling"]["df2"]) == (3, 14)
        assert out["dirty_called_clean"] == 0.0
        assert out["n_clean"] == 12


class TestFleetModel:
    def test_train_and_judge_a_panel_without_baseline(
        self, client: TestClient, admin: dict[str, str], farm: Any
    ) -> None:
        r = train_fleet(client, admin)
        assert r.json()["cv_balanced_accuracy"] == 1.0
        assert status(client, admin)["state"] == "unknown"
        v = post_frame(client, farm, CLEAN_RGB)
        assert (v["method"], v["clean"]) == ("fleet", True)
        v = post_frame(client, farm, 0.5 * CLEAN_RGB + 0.5 * SAND)
        assert (v["method"], v["clean"]) == ("fleet", False)
        assert v["p_dirty"] > 0.5

    def test_a_view_without_a_baseline_is_judged_by_the_fleet_model(
        self, client: TestClient, admin: dict[str, str], farm: Any
    ) -> None:
        """c1's view of p1 has a baseline; c2, added later with another view, has none yet. Its
        frames got `clean: null` though a fleet model could judge them, as it judges panels
        with no baseline at all."""
        train_fleet(client, admin)
        assert train(client, admin, clean_set(8)).status_code == 201  # c1's view: the whole frame
        # most of the frame: features like those of the fleet's whole-frame photos
        c2 = {"id": "c2", "kind": "panel", "panel_id": "p1", "roi": [0, 0, 160, 112]}
        r = client.post("/cameras", json=c2, headers=admin)
        assert r.status_code == 201, r.text
        side = {**bearer(r.json()["token"]), "Content-Type": "image/jpeg"}

        v = post_frame(client, farm, CLEAN_RGB)  # c1: its view's baseline
        assert (v["method"], v["clean"]) == ("baseline", True), v
        for rgb, clean in ((CLEAN_RGB, True), (0.5 * CLEAN_RGB + 0.5 * SAND, False)):
            farm["clock"].advance(minutes=10)
            r = client.post("/cameras/c2/frames", content=panel_jpeg(rgb, seed=7), headers=side)
            assert r.status_code == 201, r.text
            v = r.json()["verdict"]
            assert (v["method"], v["clean"], v["baseline_id"]) == ("fleet", clean, None), v

    def test_a_view_unlike_the_fleets_photos_gets_no_verdict(
        self, client: TestClient, admin: dict[str, str], farm: Any
    ) -> None:
        """A small part of the frame (grid lines 16 px apart in a 100×80 crop) is unlike the
        whole-frame photos the model learnt from: no verdict and no task, the reason given,
        however sure its probability looks."""
        train_fleet(client, admin)
        c2 = {"id": "c2", "kind": "panel", "panel_id": "p1", "roi": [10, 10, 100, 80]}
        r = client.post("/cameras", json=c2, headers=admin)
        assert r.status_code == 201, r.text
        side = {**bearer(r.json()["token"]), "Content-Type": "image/jpeg"}
        for _ in range(4):  # past the debounce, had the frames been judged dirty
            farm["clock"].advance(minutes=10)
            dusty = panel_jpeg(0.5 * CLEAN_RGB + 0.5 * SAND, seed=7)
            r = client.post("/cameras/c2/frames", content=dusty, headers=side)
            assert r.status_code == 201, r.text
            v = r.json()["verdict"]
            assert (v["method"], v["clean"], v["condition"]) == ("fleet", None, None), v
            assert v["reason"].startswith("unlike every photo the fleet model learnt from")
        s = status(client, admin)
        assert s["state"] == "unknown", s
        assert client.get("/cleaning/tasks", headers=admin).json() == []

    def farm_photos(self, panels: int) -> tuple[list[Any], list[str], list[str]]:
        """Each panel photographed clean and half covered in sand (seeded)."""
        rng = np.random.default_rng(6)
        files, labels, groups = [], [], []
        for i in range(panels):
            c = CLEAN_RGB + rng.normal(0, 6, 3)
            for name, rgb in (("clean", c), ("dust", 0.5 * c + 0.5 * SAND)):
                photo = panel_jpeg(rgb, seed=10 * i + len(files))
                files.append(("files", (f"{name}{i}.jpg", photo, "image/jpeg")))
                labels.append(name)
                groups.append(f" row-A-{i} ")  # as cut from a CSV: stripped
        return files, labels, groups

    def test_photos_grouped_by_panel(self, client: TestClient, admin: dict[str, str]) -> None:
        files, labels, groups = self.farm_photos(8)
        data = {"labels": labels, "groups": groups}
        r = client.post("/fleet/model", files=files, data=data, headers=admin)
        assert r.status_code == 201, r.text
        assert r.json()["n_groups"] == 8
        assert r.json()["cv_balanced_accuracy"] == 1.0
        r = client.post("/fleet/model", files=files, data={"labels": labels}, headers=admin)
        assert r.status_code == 201, r.text
        assert r.json()["n_groups"] is None

    @pytest.mark.parametrize(
        ("regroup", "code"),
        [
            (lambda g: g[1:], "groups_mismatch"),
            (lambda g: [f"row-{i % 4}" for i in range(len(g))], "too_few_groups"),
            (lambda g: [*g[:3], " ", *g[4:]], "empty_group"),
        ],
    )
    def test_groups_that_cannot_fold_are_refused_and_nothing_stored(
        self,
        client: TestClient,
        admin: dict[str, str],
        regroup: Callable[[list[str]], list[str]],
        code: str,
    ) -> None:
        files, labels, groups = self.farm_photos(8)
        data = {"labels": labels, "groups": regroup(groups)}
        r = client.post("/fleet/model", files=files, data=data, headers=admin)
        assert r.status_code == 422, r.text
        assert r.json()["code"] == code
        assert client.get("/fleet/model", headers=admin).status_code == 404

    def test_labels_must_match_files(self, client: TestClient, admin: dict[str, str]) -> None:
        files = [("files", ("a.jpg", panel_jpeg(CLEAN_RGB), "image/jpeg"))]
        r = client.post("/fleet/model", files=files, data={"labels": "shiny"}, headers=admin)
        assert r.status_code == 422
        assert client.get("/fleet/model", headers=admin).status_code == 404


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


class TestBaselinePower:
    """A baseline says what it can detect, and refuses to judge when that is nothing useful."""

    def test_a_baseline_of_one_panel_knows_its_veil(
        self, client: TestClient, admin: dict[str, str], farm: Any
    ) -> None:
        b = train(client, admin, clean_set(8)).json()
        assert 0 < b["detectable_veil"] < 0.3
        assert b["warnings"] == []
        assert status(client, admin)["warnings"] == []

    def test_photos_of_different_panels_are_too_broad_and_the_fleet_judges(
        self, client: TestClient, admin: dict[str, str], farm: Any
    ) -> None:
        colours = [(56, 60, 84), (120, 110, 90), (30, 40, 140), (90, 140, 70), (200, 60, 60)]
        photos = [panel_jpeg(np.array(c, float), seed=i) for i, c in enumerate(colours)]
        r = train(client, admin, photos)
        assert r.status_code == 201, r.text
        [warning] = r.json()["warnings"]
        assert warning["code"] == "baseline_too_broad"
        assert "different panels" in warning["detail"]
        assert [w["code"] for w in status(client, admin)["warnings"]] == ["baseline_too_broad"]
        v = post_frame(client, farm, CLEAN_RGB)
        assert v["clean"] is None
        assert "too broad" in v["reason"]
        train_fleet(client, admin)
        v = post_frame(client, farm, 0.5 * CLEAN_RGB + 0.5 * SAND, seed=3)
        assert (v["method"], v["clean"]) == ("fleet", False)
        assert "too broad" in v["reason"]
        assert status(client, admin)["state"] != "no_baseline"


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
