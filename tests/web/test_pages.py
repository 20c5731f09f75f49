"""The pages as HTTP answers: each page, its libraries, the public sky picture."""

from __future__ import annotations

from typing import Any

import cv2
import numpy as np
from fastapi.testclient import TestClient

from tests.factories.air import calibrate, post, sky_jpeg


def test_every_page_answers_with_its_frame(client: TestClient) -> None:
    for path, marker in (
        ("/", 'href="/map"'),
        ("/map", 'id="map"'),
        ("/farm", 'id="signin"'),
        ("/cells", 'id="outline-form"'),
    ):
        r = client.get(path)
        assert r.status_code == 200, path
        assert r.headers["content-type"].startswith("text/html")
        assert marker in r.text, path
    for path in (
        "/static/vendor/leaflet/leaflet.js",
        "/static/vendor/leaflet/leaflet.css",
        "/static/vendor/chart.js/chart.umd.min.js",
        "/static/map.js",
    ):
        assert client.get(path).status_code == 200, path


def test_the_map_page_takes_its_tiles_from_the_settings(client: TestClient, app: Any) -> None:
    """``VANTAGE_MAP_TILES`` and its attribution reach the page's configuration."""
    tiles = app.state.settings.map_tiles
    assert tiles == "https://tile.openstreetmap.org/{z}/{x}/{y}.png"
    page = client.get("/map").text
    assert '"tiles": "https://tile.openstreetmap.org/{z}/{x}/{y}.png"' in page
    assert "OpenStreetMap" in page


def test_a_display_of_no_camera_is_a_page_saying_so(
    client: TestClient, admin: dict[str, str], city: dict[str, Any]
) -> None:
    missing = client.get("/display/nowhere")
    assert missing.status_code == 404
    assert "There is no sky camera &#39;nowhere&#39;" in missing.text
    panel = client.post("/cameras", json={"id": "roof", "kind": "panel"}, headers=admin)
    assert panel.status_code == 201, panel.text
    assert client.get("/display/roof").status_code == 404  # not a sky camera
    page = client.get("/display/sky1")
    assert page.status_code == 200
    assert '"camera_id": "sky1"' in page.text


def test_the_sky_picture_is_the_region_of_the_latest_reading(
    client: TestClient, admin: dict[str, str], city: dict[str, Any]
) -> None:
    """Public: the map's popup shows it. Only the camera's region (160 × 55 of its 160 × 100
    frame), never the street below; 404 before any frame."""
    assert client.get("/air/cameras/sky1/sky.jpg").status_code == 404
    calibrate(client, admin)
    post(client, city, "sky1", 7, seed=1)
    r = client.get("/air/cameras/sky1/sky.jpg")
    assert r.status_code == 200
    assert r.headers["content-type"] == "image/jpeg"
    image = cv2.imdecode(np.frombuffer(r.content, np.uint8), cv2.IMREAD_COLOR)
    assert image.shape[:2] == (55, 160)
    whole = cv2.imdecode(np.frombuffer(sky_jpeg(7, seed=1), np.uint8), cv2.IMREAD_COLOR)
    assert abs(float(image.mean()) - float(whole[:55].mean())) < 3  # the sky, not the street
    assert client.get("/air/cameras/nowhere/sky.jpg").status_code == 404
    # a camera measuring its whole view publishes no picture of it (its street)
    assert client.patch("/cameras/sky2", json={"roi": None}, headers=admin).status_code == 200
    post(client, city, "sky2", 7, seed=2)
    whole = client.get("/air/cameras/sky2/sky.jpg")
    assert whole.status_code == 404
    assert "no roi" in whole.json()["detail"]
