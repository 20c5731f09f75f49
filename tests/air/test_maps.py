"""The city's map over HTTP: bands, islands, the past, the uncertainty layer, the PNG, the
cache."""

from __future__ import annotations

from datetime import UTC, datetime, timedelta
from typing import Any

import cv2
import numpy as np
import pytest
from fastapi.testclient import TestClient
from mpl_toolkits.axes_grid1.anchored_artists import AnchoredSizeBar
from shapely.geometry import shape

from app.air.core import isopleths
from app.air.services import map_picture
from app.air.services.map_cache import MapCache
from app.air.services.maps import Station
from tests.factories.air import calibrate, post, post_bytes


def test_a_retired_camera_leaves_the_map_and_keeps_its_readings(
    client: TestClient, admin: dict[str, str], city: dict[str, Any]
) -> None:
    calibrate(client, admin)
    for cam in ("sky1", "sky2", "sky3"):
        post(client, city, cam, 7, seed=1)
    fc = client.get("/air/isopleths").json()
    assert [c["camera_id"] for c in fc["cameras"]] == ["sky1", "sky2", "sky3"]

    assert client.delete("/cameras/sky2", headers=admin).status_code == 204
    fc = client.get("/air/isopleths").json()
    assert [c["camera_id"] for c in fc["cameras"]] == ["sky1", "sky3"]
    assert client.get("/air/cameras/sky2/latest").json()["level"] == 7
    assert len(client.get("/air/readings", params={"camera_id": "sky2"}).json()) == 1


def test_the_map_as_it_was_at_an_earlier_time(
    client: TestClient, admin: dict[str, str], city: dict[str, Any]
) -> None:
    """A dashboard replays the morning: ``at`` maps each camera's latest reading in the window
    before that time, as smoothed then, with the cameras that were in service then (sky2,
    retired since, included); now's map shows the air since. A time ahead is refused."""
    calibrate(client, admin)
    clock = city["clock"]
    morning = clock.now + timedelta(minutes=30)
    for cam in ("sky1", "sky2", "sky3"):
        clock.advance(minutes=10)
        post(client, city, cam, 10, seed=1)
    clock.advance(hours=13)  # beyond the morning's NowCast hours
    for cam in ("sky1", "sky3"):
        clock.advance(minutes=10)
        post(client, city, cam, 1, seed=2)
    assert client.delete("/cameras/sky2", headers=admin).status_code == 204

    now = client.get("/air/isopleths").json()
    assert now["at"] == now["computed_at"] == clock.now.isoformat()
    assert {c["camera_id"]: c["level"] for c in now["cameras"]} == {"sky1": 1.0, "sky3": 1.0}
    then = client.get("/air/isopleths", params={"at": morning.isoformat()}).json()
    assert then["at"] == morning.isoformat()
    assert then["computed_at"] == clock.now.isoformat()
    assert {c["camera_id"]: c["level"] for c in then["cameras"]} == {
        "sky1": 10.0,
        "sky2": 10.0,
        "sky3": 10.0,
    }
    assert {f["properties"]["category"] for f in then["features"]} == {"Very Good"}
    earlier = client.get(
        "/air/isopleths", params={"at": (morning - timedelta(hours=2)).isoformat()}
    )
    assert earlier.json()["features"] == earlier.json()["cameras"] == []  # no readings yet
    png = client.get("/air/isopleths.png", params={"at": morning.isoformat()})
    assert png.status_code == 200
    assert png.content != client.get("/air/isopleths.png").content
    ahead = client.get(
        "/air/isopleths", params={"at": (clock.now + timedelta(minutes=5)).isoformat()}
    )
    assert ahead.status_code == 422
    assert ahead.json()["code"] == "bad_time"
    for path in ("/air/isopleths", "/air/isopleths.png"):  # before the history kept
        first = client.get(path, params={"at": "0001-01-01T00:00:00Z"})
        assert first.status_code == 422, first.text
        assert first.json()["code"] == "bad_time"
        assert "before the history this service keeps" in first.json()["detail"]


def test_the_map_names_graded_cameras_it_cannot_place(
    client: TestClient, admin: dict[str, str], city: dict[str, Any]
) -> None:
    """A camera registered without a place is graded but cannot be mapped: the map says so
    instead of leaving it out silently."""
    calibrate(client, admin)
    r = client.post(
        "/cameras", json={"id": "roof", "kind": "sky", "roi": [0, 0, 160, 55]}, headers=admin
    )
    city["tokens"]["roof"] = (r.json()["token"], None)
    assert client.patch("/cameras/sky1", json={"name": "Duomo"}, headers=admin).status_code == 200
    post(client, city, "sky1", 7, seed=1)
    fc = client.get("/air/isopleths").json()
    assert fc["warnings"] == []
    assert [(c["camera_id"], c["name"]) for c in fc["cameras"]] == [("sky1", "Duomo")]
    post(client, city, "roof", 7, seed=2)
    fc = client.get("/air/isopleths", params={"window": 3601}).json()  # not the cached map
    assert [c["camera_id"] for c in fc["cameras"]] == ["sky1"]
    assert fc["warnings"] == [
        "1 sky camera with readings has no lat/lon and so no place on the map: roof"
        " (PATCH /cameras/{id} with both)"
    ]


def test_the_uncertainty_layer(
    client: TestClient, admin: dict[str, str], city: dict[str, Any]
) -> None:
    """``layer=uncertainty``: where to trust the map, as bands of the distance to the nearest
    camera (idw) or of kriging's standard deviation, in GeoJSON and drawn."""
    calibrate(client, admin)
    for cam, level in (("sky1", 3), ("sky2", 7), ("sky3", 10), ("sky4", 5)):
        post(client, city, cam, level, seed=1)
    levels = client.get("/air/isopleths").json()
    assert levels["layer"] == "levels"
    for method, kind, unit in (
        ("idw", "nearest_camera_m", "m"),
        ("kriging", "kriging_sd", "level"),
    ):
        r = client.get("/air/isopleths", params={"layer": "uncertainty", "method": method})
        assert r.status_code == 200, r.text
        fc = r.json()
        assert fc["layer"] == "uncertainty"
        assert fc["uncertainty"]["kind"] == kind
        assert fc["features"]
        assert {f["properties"]["kind"] for f in fc["features"]} == {kind}
        assert {f["properties"]["unit"] for f in fc["features"]} == {unit}
        assert all(shape(f["geometry"]).is_valid for f in fc["features"])
        assert [c["camera_id"] for c in fc["cameras"]] == ["sky1", "sky2", "sky3", "sky4"]
    png = client.get("/air/isopleths.png", params={"layer": "uncertainty"})
    assert png.status_code == 200
    assert png.headers["content-type"] == "image/png"
    assert png.content != client.get("/air/isopleths.png").content
    assert client.get("/air/isopleths", params={"layer": "variance"}).status_code == 422


def stations_of(fc: dict[str, Any]) -> list[Station]:
    """The map's cameras as the renderer takes them."""
    return [
        Station(
            c["camera_id"], c["lon"], c["lat"], c["level"],
            datetime.fromisoformat(c["captured_at"]), c["name"],
        )
        for c in fc["cameras"]
    ]  # fmt: skip


def test_the_png_map_is_a_labelled_map_at_one_scale_in_metres(
    client: TestClient, admin: dict[str, str], city: dict[str, Any]
) -> None:
    """The PNG is the figure of the GeoJSON's islands: north up at one scale in metres (aspect
    1/cos φ over the bbox), smooth bands, each camera labelled "name (level)", coordinates
    on the axes, a scale bar, a legend with the categories' levels and what blank means."""
    calibrate(client, admin)
    assert client.patch("/cameras/sky1", json={"name": "Duomo"}, headers=admin).status_code == 200
    for cam, level in (("sky1", 3), ("sky2", 7), ("sky3", 10)):
        post(client, city, cam, level, seed=1)
    x0, y0, x1, y1 = 9.0, 45.35, 9.4, 45.55
    params = {"bbox": f"{x0},{y0},{x1},{y1}"}
    r = client.get("/air/isopleths.png", params=params)
    assert r.status_code == 200
    png = cv2.imdecode(np.frombuffer(r.content, np.uint8), cv2.IMREAD_COLOR)
    fc = client.get("/air/isopleths", params=params).json()
    [island] = fc["islands"]
    stations = stations_of(fc)
    islands = isopleths.interpolate_islands(
        np.array([s.lon for s in stations]),
        np.array([s.lat for s in stations]),
        np.array([s.level for s in stations]),
        bbox=(x0, y0, x1, y1),
    )
    fig = map_picture.figure(islands, stations, datetime.fromisoformat(fc["at"]))
    w, h = fig.get_size_inches() * fig.dpi
    assert png.shape[:2] == (round(h), round(w))
    [ax] = fig.axes
    assert (ax.get_xlim(), ax.get_ylim()) == ((x0, x1), (y0, y1))
    assert ax.get_aspect() == pytest.approx(1 / np.cos(np.radians((y0 + y1) / 2)))
    assert "longitude" in ax.get_xlabel()
    assert "latitude" in ax.get_ylabel()
    labels = {t.get_text() for t in ax.texts}
    assert {"Duomo (3)", "sky2 (7)", "sky3 (10)"} <= labels
    assert any(isinstance(a, AnchoredSizeBar) for a in ax.artists)  # the scale bar
    legend = [t.get_text() for t in fig.legends[0].get_texts()]
    assert legend[:5] == ["Very Good 9–10", "Good 7–8", "Fair 5–6", "Poor 3–4", "Very Poor 1–2"]
    assert "no data: no camera within 5 km" in legend
    assert island["camera_ids"] == ["sky1", "sky2", "sky3"]


def test_two_cities_are_two_islands_of_one_map(
    client: TestClient, admin: dict[str, str], city: dict[str, Any]
) -> None:
    """Milan and Rome, 480 km apart: one grid over both had cells of ~4 km (128 per side) or
    57 km, every cell farther than 5 km from a camera, and an empty map. Now each city is an
    island with cells ≤ 2.5 km (half the mask distance), each camera in its own category's
    band; the PNG draws a panel per island."""
    calibrate(client, admin)
    body = {"lat": 41.9, "lon": 12.5, "name": "Colosseo"}
    assert client.patch("/cameras/sky5", json=body, headers=admin).status_code == 200
    for cam, level in (("sky1", 3), ("sky2", 7), ("sky5", 10)):
        post(client, city, cam, level, seed=1)
    fc = client.get("/air/isopleths", params={"resolution": 16}).json()
    assert [i["camera_ids"] for i in fc["islands"]] == [["sky1", "sky2"], ["sky5"]]
    for i in fc["islands"]:
        assert max(i["cell_m"]) <= 2500
    assert {c["camera_id"]: c["band"] for c in fc["cameras"]} == {
        "sky1": "Poor",
        "sky2": "Good",
        "sky5": "Very Good",
    }
    assert {f["properties"]["category"] for f in fc["features"]} >= {"Poor", "Good", "Very Good"}
    assert len({f["properties"]["category"] for f in fc["features"]}) == len(fc["features"])
    assert all(shape(f["geometry"]).is_valid for f in fc["features"])
    stations = stations_of(fc)
    islands = isopleths.interpolate_islands(
        np.array([s.lon for s in stations]),
        np.array([s.lat for s in stations]),
        np.array([s.level for s in stations]),
        resolution=16,
    )
    fig = map_picture.figure(islands, stations, datetime.fromisoformat(fc["at"]))
    assert len(fig.axes) == 2
    assert {t.get_text() for t in fig.axes[1].texts} == {"Colosseo (10)"}
    png = client.get("/air/isopleths.png", params={"resolution": 16})
    assert png.status_code == 200


def test_an_empty_map_says_why(
    client: TestClient, admin: dict[str, str], city: dict[str, Any]
) -> None:
    fc = client.get("/air/isopleths").json()
    assert fc["features"] == []
    assert fc["empty_reason"].startswith("no sky camera has a graded reading in the 3600 s")
    calibrate(client, admin)
    post(client, city, "sky1", 7, seed=1)
    far = client.get("/air/isopleths", params={"bbox": "100,10,101,11"}).json()
    assert far["features"] == []
    assert far["empty_reason"] == (
        "no cell of the bbox lies within max_distance (5000 m) of a camera with a reading"
    )
    fig = map_picture.figure([], [], datetime(2026, 6, 1, tzinfo=UTC), empty_reason="nothing here")
    assert [t.get_text() for t in fig.axes[0].texts] == ["No map: nothing here"]
    assert client.get("/air/isopleths.png", params={"bbox": "100,10,101,11"}).status_code == 200


def test_a_map_is_computed_once_per_cache_period_and_revalidated_by_its_etag(
    client: TestClient, admin: dict[str, str], city: dict[str, Any], app: Any
) -> None:
    """Dashboards poll the public map; each poll computed it again (kriging over thousands
    of cameras takes seconds). A map is kept for the cache period (30 s by default) per
    request, says when it was computed, and answers If-None-Match with 304; after the period
    a reading taken meanwhile shows."""
    cache = MapCache(ttl=30.0, clock=lambda: seconds[0])
    seconds = [1000.0]
    app.state.isopleth_cache = cache
    calibrate(client, admin)
    for cam in ("sky1", "sky2", "sky3"):
        post(client, city, cam, 7, seed=1)
    first = client.get("/air/isopleths")
    assert first.status_code == 200, first.text
    assert first.headers["cache-control"] == "public, max-age=30"
    etag = first.headers["etag"]
    assert [c["camera_id"] for c in first.json()["cameras"]] == ["sky1", "sky2", "sky3"]

    post(client, city, "sky4", 3, seed=2)  # a new reading, within the period
    seconds[0] += 29
    again = client.get("/air/isopleths")
    assert (again.content, again.headers["etag"]) == (first.content, etag)
    assert again.json()["computed_at"] == first.json()["computed_at"]
    r = client.get("/air/isopleths", headers={"If-None-Match": etag})
    assert (r.status_code, r.content, r.headers["etag"]) == (304, b"", etag)
    # weak: the map goes gzipped to clients that take it (RFC 9110 §8.8.1), and matches as
    # such, in either form (§13.1.2)
    assert etag.startswith('W/"')
    zipped = client.get("/air/isopleths", headers={"Accept-Encoding": "gzip"})
    plain = client.get("/air/isopleths", headers={"Accept-Encoding": "identity"})
    assert zipped.headers["content-encoding"] == "gzip"
    assert "content-encoding" not in plain.headers
    for r in (zipped, plain, client.get("/air/isopleths", headers={"If-None-Match": etag})):
        varies = [v.strip() for v in r.headers["vary"].split(",")]
        assert varies.count("Accept-Encoding") == 1, r.headers["vary"]
    assert zipped.content == plain.content  # decoded by the client
    assert zipped.headers["etag"] == plain.headers["etag"] == etag
    for tag in (etag, etag.removeprefix("W/")):
        r = client.get("/air/isopleths", headers={"If-None-Match": tag, "Accept-Encoding": "gzip"})
        assert r.status_code == 304
    other = client.get("/air/isopleths", params={"method": "kriging"})  # another request
    assert [c["camera_id"] for c in other.json()["cameras"]][-1] == "sky4"
    png = client.get("/air/isopleths.png")
    assert png.headers["content-type"] == "image/png"
    assert (
        client.get("/air/isopleths.png", headers={"If-None-Match": png.headers["etag"]}).status_code
        == 304
    )

    seconds[0] += 2  # the period is over: computed again, with sky4
    later = client.get("/air/isopleths", headers={"If-None-Match": etag})
    assert later.status_code == 200, later.text
    assert later.headers["etag"] != etag
    assert [c["camera_id"] for c in later.json()["cameras"]][-1] == "sky4"
    bad = client.get("/air/isopleths", params={"bbox": "1,2,0,3"})  # errors are not kept
    assert bad.status_code == 422
    assert "etag" not in bad.headers


def test_a_map_from_two_cameras(
    client: TestClient, admin: dict[str, str], city: dict[str, Any]
) -> None:
    bbox = {"bbox": "9.0,45.3,9.4,45.6"}
    off_globe = client.get("/air/isopleths", params={"bbox": "170,0,181,1"})  # no readings yet
    assert off_globe.status_code == 422, off_globe.text
    assert off_globe.headers["content-type"] == "application/problem+json"
    calibrate(client, admin)
    assert post(client, city, "sky1", 3, seed=1)["level"] == 3
    assert post(client, city, "sky2", 10, seed=1)["level"] == 10
    r = client.get("/air/isopleths", params={**bbox, "max_distance": 100_000})
    assert r.status_code == 200, r.text
    assert len(r.json()["cameras"]) == 2
    assert r.json()["features"]
    for method in ("kriging", "rbf"):  # both need three places: drawn by idw, and said so
        r = client.get("/air/isopleths", params={**bbox, "method": method})
        assert r.status_code == 200, (method, r.text)
        fc = r.json()
        assert [i["method"] for i in fc["islands"]] == ["idw"]
        assert f"fewer than 3 places, which {method} needs: drawn by idw" in fc["warnings"][0]
        assert fc["features"]
        png = client.get("/air/isopleths.png", params={**bbox, "method": method})
        assert png.status_code == 200


def test_window_excludes_old_readings(
    client: TestClient, admin: dict[str, str], city: dict[str, Any]
) -> None:
    calibrate(client, admin)
    post(client, city, "sky2", 7, seed=1)
    city["clock"].advance(hours=3)
    fc = client.get("/air/isopleths", params={"window": 3600}).json()
    assert fc["cameras"] == []
    city["clock"].now -= timedelta(hours=3)


def test_at_dusk_the_map_shows_what_latest_says(
    client: TestClient, admin: dict[str, str], city: dict[str, Any]
) -> None:
    """After dusk a camera's frames are night frames, ungraded, each keeping the camera's
    smoothed level while NowCast has a graded reading in the 3 hours before. /latest gave
    that level (current) for those 3 hours, but the map took only graded readings of its
    window (1 h): from an hour after dusk the camera was off the map while /latest and the
    alerts still spoke for it. The map now takes the newest reading of its window that has a
    level, smoothed or its own: three hours after dusk the camera has no public level, and an
    hour later (the window) it is off the map."""
    assert calibrate(client, admin).status_code == 201
    for k in range(6):
        city["clock"].advance(minutes=20)
        post(client, city, "sky2", 7, seed=k)
        post(client, city, "sky5", 10, seed=k)
    ok, night = cv2.imencode(".jpg", np.full((100, 160, 3), 3, np.uint8))
    assert ok

    def on_map() -> dict[str, float]:
        fc = client.get("/air/isopleths").json()
        return {c["camera_id"]: c["level"] for c in fc["cameras"]}

    for _ in range(6):  # two hours of night frames, beyond the map's window
        city["clock"].advance(minutes=20)
        assert post_bytes(client, city, "sky2", night.tobytes())["level"] is None
        post(client, city, "sky5", 10, seed=99)
    latest = client.get("/air/cameras/sky2/latest").json()
    assert latest["current"] is True
    assert latest["smoothed_level"] is not None
    assert on_map()["sky2"] == pytest.approx(latest["smoothed_level"])
    for _ in range(3):  # past three hours without a graded reading
        city["clock"].advance(minutes=20)
        post_bytes(client, city, "sky2", night.tobytes())
        post(client, city, "sky5", 10, seed=98)
    latest = client.get("/air/cameras/sky2/latest").json()
    assert latest["smoothed_level"] is None
    assert "sky2" in on_map()  # its last public level, 20 minutes old
    for _ in range(3):  # and a window's length later
        city["clock"].advance(minutes=20)
        post_bytes(client, city, "sky2", night.tobytes())
        post(client, city, "sky5", 10, seed=97)
    assert "sky2" not in on_map()
    assert "sky5" in on_map()
