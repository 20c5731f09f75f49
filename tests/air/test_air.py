"""Air quality end to end over HTTP (sky cameras, calibration, frames, latest, readings,
alerts, the map), and the bad input every air endpoint refuses."""

from __future__ import annotations

from datetime import UTC, datetime, timedelta
from typing import Any

import pytest
from fastapi.testclient import TestClient
from shapely.geometry import shape

from tests.factories.air import calibrate, post, sky_jpeg


def test_end_to_end(client: TestClient, admin: dict[str, str], city: dict[str, Any]) -> None:
    v = post(client, city, "sky0", 10, seed=1)
    assert v["level"] is None
    assert "not calibrated" in v["reason"]

    r = calibrate(client, admin)
    assert r.status_code == 201, r.text
    model = r.json()
    assert [c["level"] for c in model["clusters"]] == [1, 3, 5, 7, 10]
    assert client.get("/air/calibration").json()["id"] == model["id"]  # public

    # every camera reports: level rises with longitude (clean in the east)
    for hour in range(3):
        city["clock"].advance(hours=1)
        for cam, (_, lon) in city["tokens"].items():
            level = 1 if lon < 9.17 else (5 if lon < 9.24 else 10)
            post(client, city, cam, level, seed=hour)
    latest = client.get("/air/cameras/sky0/latest").json()
    assert latest["level"] in (1, 5, 10)
    assert latest["message"] == f"Today's Air Quality is {latest['category']}"
    assert latest["smoothed_level"] is not None

    readings = client.get("/air/readings", params={"camera_id": "sky0"}).json()
    assert len(readings) == 4
    times = [r["captured_at"] for r in readings]
    assert times == sorted(times, reverse=True)
    # since/until without an offset are UTC (they were a 500); out of the calendar in UTC: 422
    first = datetime.fromisoformat(times[-1]).astimezone(UTC).replace(tzinfo=None)
    naive = client.get(
        "/air/readings",
        params={"camera_id": "sky0", "since": (first + timedelta(seconds=1)).isoformat()},
    )
    assert naive.status_code == 200, naive.text
    assert len(naive.json()) == 3
    empty = {"since": times[0], "until": times[0]}  # [t, t) holds nothing: a mistaken range
    for bad in (
        {"since": "0001-01-01T00:00:00+14:00"},
        {"until": "9999-12-31T23:59:59-14:00"},
        empty,
        {**empty, "aggregate": "daily"},
    ):
        r = client.get("/air/readings", params=bad)
        assert r.status_code == 422, r.text
        assert r.headers["content-type"] == "application/problem+json"
    daily = client.get("/air/readings", params={"aggregate": "daily"}).json()
    assert len(daily) == 12  # one bucket per camera and day
    assert all(d["n"] == 3 for d in daily)  # sky0's first frame came before the calibration
    hourly = client.get("/air/readings", params={"aggregate": "hourly", "camera_id": "sky3"}).json()
    assert [h["n"] for h in hourly] == [1, 1, 1]

    gj = client.get("/air/isopleths", params={"window": 7200, "max_distance": 20000})
    assert gj.status_code == 200, gj.text
    assert gj.headers["content-type"].startswith("application/geo+json")
    fc = gj.json()
    assert fc["type"] == "FeatureCollection"
    assert fc["method"] == "idw"
    assert len(fc["cameras"]) == 12
    # what the map shows at each camera, and a warning whenever that is not its own category
    off = [c for c in fc["cameras"] if c["band"] not in (None, c["category"])]
    assert bool(off) == bool(fc["warnings"])
    assert len(fc["cell_m"]) == 2
    names = [f["properties"]["category"] for f in fc["features"]]
    assert len(names) == len(set(names))
    for f in fc["features"]:
        assert shape(f["geometry"]).is_valid
        assert f["geometry"]["type"] in ("Polygon", "MultiPolygon")
    for method in ("kriging", "rbf"):
        assert client.get("/air/isopleths", params={"method": method}).status_code == 200
    png = client.get("/air/isopleths.png")
    assert png.status_code == 200
    assert png.headers["content-type"] == "image/png"


class TestBadInput:
    def test_empty_city_is_an_empty_collection(self, client: TestClient) -> None:
        fc = client.get("/air/isopleths").json()
        assert fc["features"] == []
        assert fc["cameras"] == []

    @pytest.mark.parametrize(
        "bbox", ["10,45,9,46", "9,46,10,45", "a,b,c,d", "1,2,3", "nan,45,10,46"]
    )
    def test_bad_bbox(self, client: TestClient, bbox: str) -> None:
        r = client.get("/air/isopleths", params={"bbox": bbox})
        assert r.status_code == 422
        assert r.headers["content-type"] == "application/problem+json"

    def test_cameras_all_at_one_point(
        self, client: TestClient, admin: dict[str, str], city: dict[str, Any]
    ) -> None:
        calibrate(client, admin)
        for i in range(2):
            tok = client.post(
                "/cameras",
                json={
                    "id": f"same{i}",
                    "kind": "sky",
                    "lat": 45.0,
                    "lon": 9.0,
                    "roi": [0, 0, 160, 55],
                },
                headers=admin,
            ).json()["token"]
            client.post(
                f"/cameras/same{i}/frames",
                content=sky_jpeg(5, i),
                headers={"Authorization": f"Bearer {tok}", "Content-Type": "image/jpeg"},
            )
        r = client.get("/air/isopleths")
        assert r.status_code == 422
        assert "one point" in r.json()["detail"]

    def test_levels_must_match_files(self, client: TestClient, admin: dict[str, str]) -> None:
        files = [("files", ("a.jpg", sky_jpeg(5), "image/jpeg"))]
        r = client.post("/air/calibration", files=files, data={"levels": ["5", "6"]}, headers=admin)
        assert r.status_code == 422
        r = client.post("/air/calibration", files=files, data={"levels": ["11"]}, headers=admin)
        assert r.status_code == 422

    def test_unknown_camera(self, client: TestClient, admin: dict[str, str]) -> None:
        """A misspelt camera id is a 404, not an empty history (a dashboard showed none)."""
        assert client.get("/air/cameras/none/latest").status_code == 404
        rig = {"id": "rig0", "kind": "rig"}
        assert client.post("/cameras", json=rig, headers=admin).status_code == 201
        for camera in ("none", "rig0"):
            for path, params in (
                ("/air/readings", {}),
                ("/air/readings", {"aggregate": "daily"}),
                ("/air/alerts", {}),
            ):
                r = client.get(path, params={"camera_id": camera, **params})
                assert r.status_code == 404, (path, params, r.text)
                assert r.json()["detail"] == f"no sky camera {camera!r}"

    def test_a_level_whose_images_are_all_alike_is_named_not_refused(
        self, client: TestClient, admin: dict[str, str], city: dict[str, Any]
    ) -> None:
        files, levels = [], []
        for level in (2, 5, 8):
            for k in range(5):
                seed = 7 if level == 5 else 10 * level + k  # level 5: one image five times
                files.append(("files", (f"{level}-{k}.jpg", sky_jpeg(level, seed), "image/jpeg")))
                levels.append(str(level))
        r = client.post(
            "/air/calibration",
            files=files,
            data={"levels": levels},
            params={"camera_id": "sky0"},
            headers=admin,
        )
        assert r.status_code == 201, r.text
        assert any(
            w.startswith("level 5: the R, G, B mode is the same in all 5 images") and "1/12" in w
            for w in r.json()["warnings"]
        ), r.json()["warnings"]

    def test_calibration_needs_admin(self, client: TestClient) -> None:
        assert (
            client.post("/air/calibration", json={"frame_ids": ["x"], "levels": [1]}).status_code
            == 401
        )
