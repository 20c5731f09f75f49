"""Baselines over HTTP: trained from photos or frames, measured in a camera's region, one
per view, their power; the soiling trend and the two-sample evaluation."""

from __future__ import annotations

from typing import Any

import cv2
import numpy as np
import pytest
from fastapi.testclient import TestClient
from scipy import stats

from tests.factories import bearer
from tests.factories.solar import (
    CLEAN_RGB,
    DUST,
    SAND,
    clean_set,
    panel_jpeg,
    post_frame,
    status,
    train,
    train_fleet,
)


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


PANEL_PART, WALL_PART = [0, 0, 60, 120], [100, 0, 60, 120]


SIDE_RGB = np.array([70.0, 78.0, 118.0])
"""The same clean cells seen from the side: more of the sky's blue in their reflection."""


def beside_a_wall(rgb: np.ndarray, seed: int) -> bytes:
    """A panel photo whose right half (x ≥ 80 of 160) is a blue wall."""
    photo = panel_jpeg(rgb, seed=seed)
    image = cv2.imdecode(np.frombuffer(photo, np.uint8), cv2.IMREAD_COLOR)
    rng = np.random.default_rng(seed)
    image[:, 80:] = np.clip(rng.normal((60, 90, 170), 6, (120, 80, 3)), 0, 255)
    return cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, 95])[1].tobytes()


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
