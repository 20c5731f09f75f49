"""Air quality end to end over HTTP: sky cameras, calibration, frames, latest, readings, alerts,
isopleths (GeoJSON and PNG)."""

from __future__ import annotations

import math
from collections.abc import Callable
from datetime import UTC, datetime, timedelta
from itertools import pairwise
from typing import Any

import cv2
import numpy as np
import pytest
from fastapi.testclient import TestClient
from mpl_toolkits.axes_grid1.anchored_artists import AnchoredSizeBar
from shapely.geometry import shape

from app.air.core import airquality, isopleths
from app.air.services import map_picture
from app.air.services.map_cache import MapCache
from app.air.services.maps import Station
from tests.factories import calibrate, make_jpeg, post, post_bytes, sky_jpeg


def post_taken(
    client: TestClient, city: dict[str, Any], camera: str, jpeg: bytes, taken: datetime
) -> Any:
    """Post ``jpeg`` for ``camera`` as taken at ``taken`` (a backlog's frame); its verdict."""
    r = client.post(
        f"/cameras/{camera}/frames",
        content=jpeg,
        headers={
            "Authorization": f"Bearer {city['tokens'][camera][0]}",
            "Content-Type": "image/jpeg",
        },
        params={"captured_at": taken.isoformat()},
    )
    assert r.status_code == 201, r.text
    return r.json()["verdict"]


def labelled_frames(
    client: TestClient, city: dict[str, Any], image: Callable[[int, int], bytes]
) -> tuple[list[str], list[int]]:
    """Eight frames of sky1 at each of levels 1, 3, 5, 7 and 10, five minutes apart
    (``image(level, k)`` for the k-th of a level): their ids and levels."""
    ids, levels = [], []
    for level in (1, 3, 5, 7, 10):
        for k in range(8):
            city["clock"].advance(minutes=5)
            r = client.post(
                "/cameras/sky1/frames",
                content=image(level, k),
                headers={
                    "Authorization": f"Bearer {city['tokens']['sky1'][0]}",
                    "Content-Type": "image/jpeg",
                },
            )
            assert r.status_code == 201, r.text
            ids.append(r.json()["frame_id"])
            levels.append(level)
    return ids, levels


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


def test_alert_when_the_smoothed_level_turns_poor(
    client: TestClient, admin: dict[str, str], city: dict[str, Any]
) -> None:
    assert calibrate(client, admin).status_code == 201
    for hour in range(3):
        city["clock"].advance(hours=1)
        post(client, city, "sky1", 10, seed=hour)
    assert client.get("/air/alerts").json() == []
    for k in range(4):
        city["clock"].advance(minutes=20)
        post(client, city, "sky1", 1, seed=10 + k)
    alerts = client.get("/air/alerts").json()
    assert len(alerts) == 1  # entering Poor once raises one alert, not one per frame
    assert alerts[0]["camera_id"] == "sky1"
    assert alerts[0]["category"] in ("Poor", "Very Poor")
    assert alerts[0]["delivery"] == "no_webhook"  # recorded; nothing is configured to send it


def test_alerts_of_a_period(
    client: TestClient, admin: dict[str, str], city: dict[str, Any]
) -> None:
    """A dashboard shows the day's alerts: ``since`` and ``until`` bound when they were raised."""
    assert calibrate(client, admin).status_code == 201
    raised = []
    for cam in ("sky1", "sky2", "sky3"):
        city["clock"].advance(hours=5)
        post(client, city, cam, 1, seed=1)
        raised.append(city["clock"].now)
    assert [a["camera_id"] for a in client.get("/air/alerts").json()] == ["sky3", "sky2", "sky1"]
    span = {"since": raised[1].isoformat(), "until": raised[2].isoformat()}
    assert [a["camera_id"] for a in client.get("/air/alerts", params=span).json()] == ["sky2"]
    since = {"since": raised[1].isoformat()}
    assert [a["camera_id"] for a in client.get("/air/alerts", params=since).json()] == [
        "sky3",
        "sky2",
    ]
    backwards = client.get("/air/alerts", params={"since": span["until"], "until": span["since"]})
    assert backwards.status_code == 422
    # a district's cameras: camera_id repeated (before, the last one alone was answered)
    district = client.get("/air/alerts", params={"camera_id": ["sky1", "sky3"]})
    assert [a["camera_id"] for a in district.json()] == ["sky3", "sky1"]
    unknown = client.get("/air/alerts", params={"camera_id": ["sky1", "sky99"]})
    assert (unknown.status_code, unknown.json()["unknown"]) == (404, ["sky99"])


def test_why_a_delivery_failed_is_for_the_operator(
    client: TestClient, admin: dict[str, str], city: dict[str, Any], app: Any
) -> None:
    """``GET /air/alerts`` is public, and a failed delivery's error can hold the receiver's
    addresses (a redirect's Location, with its token): only the admin token reads it."""
    from app.air.models import AirAlert

    assert calibrate(client, admin).status_code == 201
    post(client, city, "sky1", 1, seed=1)
    error = "HTTP 301 redirect to 'https://hooks.example/T0/B0/s3cr3t', not followed"
    with app.state.sessionmaker() as s:
        s.get(AirAlert, client.get("/air/alerts").json()[0]["id"]).last_error = error
        s.commit()
    public = client.get("/air/alerts").json()[0]
    assert public["last_error"] is None
    assert public["category"] in ("Poor", "Very Poor")
    assert client.get("/air/alerts", headers=admin).json()[0]["last_error"] == error
    camera = {"Authorization": f"Bearer {city['tokens']['sky1'][0]}"}
    assert client.get("/air/alerts", headers=camera).json()[0]["last_error"] is None
    wrong = client.get("/air/alerts", headers={"Authorization": "Bearer nope"})
    assert wrong.status_code == 401


def test_air_getting_worse_again_is_a_second_alert(
    client: TestClient, admin: dict[str, str], city: dict[str, Any]
) -> None:
    """Poor, then Very Poor: one alert for each category entered, worst last (entering Very
    Poor from Poor raised none before); getting better raises none."""
    assert calibrate(client, admin).status_code == 201
    for hour in range(3):
        city["clock"].advance(hours=1)
        post(client, city, "sky1", 10, seed=hour)
    for level, n in ((3, 8), (1, 12), (3, 12)):
        for k in range(n):
            city["clock"].advance(minutes=20)
            post(client, city, "sky1", level, seed=100 * level + k)
    readings = client.get("/air/readings", params={"camera_id": "sky1", "limit": 100}).json()
    smoothed = [r["smoothed_level"] for r in reversed(readings) if r["smoothed_level"]]
    alerts = client.get("/air/alerts").json()
    assert [a["category"] for a in alerts] == ["Very Poor", "Poor"]
    assert min(smoothed) < 2.5  # it did reach Very Poor, and came back to Poor without an alert
    assert 2.5 <= smoothed[-1] < 4.5


def test_an_episode_of_poor_air_is_raised_then_cleared(
    client: TestClient, admin: dict[str, str], city: dict[str, Any]
) -> None:
    """A receiver showing "Poor air at sky1" learns when it is over: once the smoothed level is
    back to 5.0 (clear of Poor by the hysteresis), one ``cleared`` alert; the next episode
    raises again. Hovering just above the edge (4.5–5.0) clears nothing."""
    assert calibrate(client, admin).status_code == 201
    for hour in range(3):
        city["clock"].advance(hours=1)
        post(client, city, "sky1", 10, seed=hour)
    graded = [3] * 6 + [5] * 12 + [10] * 18 + [3] * 8
    for k, level in enumerate(graded):
        city["clock"].advance(minutes=20)
        assert post(client, city, "sky1", level, seed=300 + k)["level"] == level
    readings = client.get("/air/readings", params={"camera_id": "sky1", "limit": 100}).json()
    smoothed = [r["smoothed_level"] for r in reversed(readings)][3:]
    alerts = list(reversed(client.get("/air/alerts").json()))
    assert [(a["kind"], a["category"]) for a in alerts] == [
        ("raised", "Poor"),
        ("cleared", "Fair"),
        ("raised", "Poor"),
    ]
    frames = [r["frame_id"] for r in reversed(readings)][3:]
    raised, cleared = frames.index(alerts[0]["frame_id"]), frames.index(alerts[1]["frame_id"])
    assert smoothed[raised] < 4.5 <= smoothed[raised - 1]
    assert cleared == next(i for i in range(raised, len(smoothed)) if smoothed[i] >= 5.0)
    assert any(4.5 <= v < 5.0 for v in smoothed[raised:cleared])  # the dead band cleared nothing
    only = client.get("/air/alerts", params={"kind": "cleared"}).json()
    assert [a["id"] for a in only] == [alerts[1]["id"]]


def test_an_episode_over_before_cleared_alerts_existed_is_not_cleared_again(
    client: TestClient, admin: dict[str, str], city: dict[str, Any], app: Any
) -> None:
    """Alerts raised before this service sent cleared ones (here: the cleared alert removed,
    as a database upgraded from then holds none) are over once a reading came back to 5.0:
    the next clean frame, weeks on, clears nothing."""
    from app.air.models import AirAlert

    assert calibrate(client, admin).status_code == 201
    for level, n in ((10, 3), (1, 6), (10, 12)):
        for k in range(n):
            city["clock"].advance(minutes=20)
            post(client, city, "sky1", level, seed=400 + k)
    kinds = [(a["kind"], a["category"]) for a in client.get("/air/alerts").json()]
    assert kinds == [("cleared", "Fair"), ("raised", "Very Poor"), ("raised", "Poor")]
    with app.state.sessionmaker() as s:
        s.query(AirAlert).filter(AirAlert.kind == "cleared").delete()
        s.commit()
    city["clock"].advance(days=20)
    post(client, city, "sky1", 10, seed=500)
    assert [a["kind"] for a in client.get("/air/alerts").json()] == ["raised", "raised"]


def test_air_hovering_on_the_poor_edge_is_one_alert(
    client: TestClient, admin: dict[str, str], city: dict[str, Any]
) -> None:
    """Clean air, then frames every 20 minutes graded 3 or 5: the smoothed level settles near
    4.5 and crosses the Fair/Poor edge five times. One episode of Poor air is one alert (and
    one webhook), not one per crossing."""
    assert calibrate(client, admin).status_code == 201
    for hour in range(3):
        city["clock"].advance(hours=1)
        post(client, city, "sky1", 10, seed=hour)
    graded = [3] * 6 + [5, 5, 3, 5, 5, 5, 3, 5, 5, 3, 5, 5, 3, 5, 5, 5, 5, 3]
    for k, level in enumerate(graded):
        city["clock"].advance(minutes=20)
        assert post(client, city, "sky1", level, seed=200 + k)["level"] == level
    readings = client.get("/air/readings", params={"camera_id": "sky1", "limit": 100}).json()
    smoothed = [r["smoothed_level"] for r in reversed(readings)]
    entered = sum(1 for a, b in pairwise(smoothed) if a >= 4.5 > b)
    assert entered == 5
    assert max(smoothed[10:]) < 5.0  # never clearly Fair again after the first entry
    alerts = client.get("/air/alerts").json()
    assert [a["category"] for a in alerts] == ["Poor"]


def test_a_late_upload_of_hazy_hours_is_history_not_an_alert(
    client: TestClient, admin: dict[str, str], city: dict[str, Any]
) -> None:
    """sky1 reports clean air for three hours, then uploads its backlog: four frames of haze
    taken six hours ago. They are graded and smoothed with the hours before they were taken
    (Very Poor then), but they raise no alert now and the camera's latest stays clean; its
    smoothed level now counts them, five and six hours back."""
    assert calibrate(client, admin).status_code == 201
    for hour in range(3):
        city["clock"].advance(hours=1)
        post(client, city, "sky1", 10, seed=hour)
    token = city["tokens"]["sky1"][0]
    for k in range(4):
        taken = city["clock"].now - timedelta(hours=6) + timedelta(minutes=20 * k)
        r = client.post(
            "/cameras/sky1/frames",
            content=sky_jpeg(1, seed=20 + k),
            headers={"Authorization": f"Bearer {token}", "Content-Type": "image/jpeg"},
            params={"captured_at": taken.isoformat()},
        )
        assert r.status_code == 201, r.text
        assert r.json()["verdict"]["level"] in (1, 2)
    assert client.get("/air/alerts").json() == []
    latest = client.get("/air/cameras/sky1/latest").json()
    assert latest["level"] == 10
    readings = client.get("/air/readings", params={"camera_id": "sky1"}).json()
    late = [r for r in readings if r["level"] in (1, 2)]
    assert len(late) == 4
    assert all(r["smoothed_level"] <= 2 for r in late)  # the hours before them had no reading
    # NowCast at the latest: hours 0, 1, 2 ago at 10, hour 5 the three later hazy frames, hour
    # 6 the first; w = max(min/max of the hourly means, 0.5) = 0.5
    five, six = np.mean([r["level"] for r in late[:3]]), late[3]["level"]
    expected = (10 * (1 + 0.5 + 0.25) + five * 0.5**5 + six * 0.5**6) / (1.75 + 0.5**5 + 0.5**6)
    assert latest["smoothed_level"] == pytest.approx(expected, rel=1e-9)
    assert latest["category"] == "Very Good"


def test_a_backlog_uploaded_newest_first_is_smoothed_as_if_uploaded_in_order(
    client: TestClient, admin: dict[str, str], city: dict[str, Any]
) -> None:
    """Cameras that buffer frames while offline may send the newest first. Each reading's
    smoothed level is the NowCast of the readings up to it, whatever order they came in:
    sky2 uploads four hours of changing air in order, sky3 the same frames newest first.
    Ungraded readings (a night frame; one sky outside calibration) keep the camera's smoothed
    level of their time too."""
    assert calibrate(client, admin).status_code == 201
    start = city["clock"].now - timedelta(hours=5)
    frames = [
        (start + timedelta(minutes=20 * k), sky_jpeg(level, seed=k))
        for k, level in enumerate([10, 10, 7, 7, 5, 5, 3, 3, 5, 7, 7, 10])
    ]
    ok, night = cv2.imencode(".jpg", np.full((100, 160, 3), 3, np.uint8))
    assert ok
    frames.insert(4, (start + timedelta(minutes=70), night.tobytes()))
    for camera, order in (("sky2", frames), ("sky3", frames[::-1])):
        for taken, jpeg in order:
            post_taken(client, city, camera, jpeg, taken)
    in_order, newest_first = (
        client.get("/air/readings", params={"camera_id": c}).json() for c in ("sky2", "sky3")
    )
    assert len(in_order) == len(newest_first) == len(frames)
    assert [r["level"] for r in newest_first] == [r["level"] for r in in_order]
    assert len({r["level"] for r in in_order}) >= 3  # the air changed
    ungraded = [r for r in in_order if r["level"] is None]
    assert len(ungraded) == 2
    assert all(r["smoothed_level"] is not None for r in ungraded)
    smoothed = [r["smoothed_level"] for r in in_order]
    assert [r["smoothed_level"] for r in newest_first] == pytest.approx(smoothed, rel=1e-9)
    assert smoothed != pytest.approx([r["level"] for r in in_order])  # smoothing did something
    latest = client.get("/air/cameras/sky3/latest").json()
    assert latest["smoothed_level"] == pytest.approx(smoothed[0], rel=1e-9)


def test_a_backlog_sent_newest_first_raises_the_alert_its_public_level_calls_for(
    client: TestClient, admin: dict[str, str], city: dict[str, Any]
) -> None:
    """Four hours of Poor air and a last frame of Fair sent newest first: the newest alone
    smooths to Fair (no alert); the older frames are history (no alert of their own) but
    smooth it again to Poor, the camera's public level, which then raises the alert, once,
    on the newest frame. Sent in order, the same frames raise one Poor alert too. Before,
    the newest-first camera's backlog raised none."""
    assert calibrate(client, admin).status_code == 201
    start = city["clock"].now - timedelta(hours=4)
    levels = [3] * 11 + [7]
    frames = [
        (start + timedelta(minutes=20 * k), sky_jpeg(level, seed=k))
        for k, level in enumerate(levels)
    ]
    newest_alone = None
    for camera, order in (("sky2", frames), ("sky3", frames[::-1])):
        for taken, jpeg in order:
            post_taken(client, city, camera, jpeg, taken)
            if camera == "sky3" and newest_alone is None:
                newest_alone = client.get("/air/cameras/sky3/latest").json()
    assert newest_alone is not None
    assert newest_alone["category"] not in ("Poor", "Very Poor")
    alerts = client.get("/air/alerts").json()
    by_camera = {c: [a for a in alerts if a["camera_id"] == c] for c in ("sky2", "sky3")}
    assert [(a["kind"], a["category"]) for a in by_camera["sky2"]] == [("raised", "Poor")]
    assert [(a["kind"], a["category"]) for a in by_camera["sky3"]] == [("raised", "Poor")]
    latest = client.get("/air/cameras/sky3/latest").json()
    assert latest["category"] == "Poor"
    newest = client.get("/air/readings", params={"camera_id": "sky3"}).json()[0]
    assert newest["captured_at"] == latest["captured_at"]
    assert by_camera["sky3"][0]["frame_id"] == newest["frame_id"]


def test_a_backlog_sent_newest_first_clears_the_episode_its_public_level_ends(
    client: TestClient, admin: dict[str, str], city: dict[str, Any]
) -> None:
    """An hour of Poor air raises its alert; the camera's backlog of the next two hours, clean
    air then a last Poor frame, comes newest first. That frame smooths to Poor with the hour
    before it (still the episode: nothing); the clean frames, history, smooth it again past
    5.0: the camera's public level has left the episode, which is cleared, once."""
    assert calibrate(client, admin).status_code == 201
    start = city["clock"].now - timedelta(hours=4)

    def send(minutes: int, level: int) -> Any:
        city["clock"].advance(seconds=1)  # received one after another
        taken = start + timedelta(minutes=minutes)
        return post_taken(client, city, "sky2", sky_jpeg(level, seed=minutes), taken)

    for minutes in (0, 20, 40):
        send(minutes, 3)
    assert [(a["kind"], a["category"]) for a in client.get("/air/alerts").json()] == [
        ("raised", "Poor")
    ]
    assert send(180, 3)["level"] in (3, 4)
    assert client.get("/air/cameras/sky2/latest").json()["category"] == "Poor"
    assert len(client.get("/air/alerts").json()) == 1
    for minutes in (160, 140, 120, 100, 80, 60):
        send(minutes, 10)
    latest = client.get("/air/cameras/sky2/latest").json()
    assert latest["smoothed_level"] >= 5.0
    alerts = client.get("/air/alerts").json()  # newest first
    assert [(a["kind"], a["category"]) for a in alerts][1:] == [("raised", "Poor")]
    assert alerts[0]["kind"] == "cleared"
    assert alerts[0]["category"] in ("Fair", "Good", "Very Good")
    newest = client.get("/air/readings", params={"camera_id": "sky2"}).json()[0]
    assert alerts[0]["frame_id"] == newest["frame_id"]


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


def test_the_latest_reading_of_every_camera_in_one_request(
    client: TestClient, admin: dict[str, str], city: dict[str, Any]
) -> None:
    """``GET /air/latest``: each sky camera in service as ``/cameras/{id}/latest`` answers for
    it (current, gone quiet, no frames yet), by id and paged; a retired one is left out."""
    calibrate(client, admin)
    post(client, city, "sky1", 3, seed=1)
    city["clock"].advance(hours=4)
    post(client, city, "sky2", 10, seed=2)
    post(client, city, "sky3", 7, seed=3)
    assert client.delete("/cameras/sky3", headers=admin).status_code == 204
    every = client.get("/air/latest")
    assert every.status_code == 200, every.text
    rows = every.json()
    ids = [f"sky{i}" for i in range(12) if i != 3]
    assert [r["camera_id"] for r in rows] == sorted(ids)
    for row in rows:
        assert row == client.get(f"/air/cameras/{row['camera_id']}/latest").json()
    by_id = {r["camera_id"]: r for r in rows}
    for cid in ("sky0", "sky2"):  # where each is, for a public map of every camera
        registered = client.get(f"/cameras/{cid}", headers=admin).json()
        assert {k: by_id[cid][k] for k in ("name", "lat", "lon")} == {
            k: registered[k] for k in ("name", "lat", "lon")
        }
    assert by_id["sky2"]["lat"] is not None
    assert (by_id["sky2"]["level"], by_id["sky2"]["current"]) == (10, True)
    assert (by_id["sky1"]["level"], by_id["sky1"]["current"]) == (3, False)  # 4 h old
    assert by_id["sky0"]["reason"] == "no frames yet"
    page = client.get("/air/latest", params={"limit": 2, "offset": 1}).json()
    assert [r["camera_id"] for r in page] == sorted(ids)[1:3]
    # a district's: the cameras named (the retired one too: it was asked for), by id
    district = client.get("/air/latest", params={"camera_id": ["sky2", "sky3", "sky1"]}).json()
    assert [(r["camera_id"], r["level"]) for r in district] == [
        ("sky1", 3),
        ("sky2", 10),
        ("sky3", 7),
    ]
    assert district[1] == by_id["sky2"]
    unknown = client.get("/air/latest", params={"camera_id": ["sky1", "nowhere"]})
    assert (unknown.status_code, unknown.json()["unknown"]) == (404, ["nowhere"])


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
    for path in ("/air/isopleths", "/air/isopleths.png"):  # its window reaches before year 1
        first = client.get(path, params={"at": "0001-01-01T00:00:00Z"})
        assert first.status_code == 200, first.text
    assert (
        client.get("/air/isopleths", params={"at": "0001-01-01T00:00:00Z"}).json()["cameras"] == []
    )


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


def test_a_significance_out_of_range_is_422(client: TestClient, admin: dict[str, str]) -> None:
    files = [("files", (f"{k}.jpg", sky_jpeg(5, seed=k), "image/jpeg")) for k in range(4)]
    for significance in (1e-300, 0.5):  # 1e-300: an infinite critical F, a 500 before
        r = client.post(
            "/air/calibration",
            files=files,
            data={"levels": ["5"] * 4},
            params={"significance": significance},
            headers=admin,
        )
        assert r.status_code == 422, r.text
    assert client.get("/air/calibration").status_code == 404


def test_window_excludes_old_readings(
    client: TestClient, admin: dict[str, str], city: dict[str, Any]
) -> None:
    calibrate(client, admin)
    post(client, city, "sky2", 7, seed=1)
    city["clock"].advance(hours=3)
    fc = client.get("/air/isopleths", params={"window": 3600}).json()
    assert fc["cameras"] == []
    city["clock"].now -= timedelta(hours=3)


def test_the_public_level_is_the_smoothed_one_not_one_frames(
    client: TestClient, admin: dict[str, str], city: dict[str, Any]
) -> None:
    """Three hours of clean air, then one hazy frame: the camera's public level, category and
    message are those of its smoothed level (which the map draws and alerts follow), the
    frame's own grade is ``frame_level``. Before, one frame said "Today's Air Quality is
    Very Poor" while the map drew the camera Very Good. A night frame after them keeps the
    public level, and says why it has no grade of its own."""
    assert calibrate(client, admin).status_code == 201
    for k in range(9):
        city["clock"].advance(minutes=20)
        post(client, city, "sky2", 10, seed=k)
    city["clock"].advance(minutes=20)
    assert post(client, city, "sky2", 1, seed=50)["level"] in (1, 2)
    latest = client.get("/air/cameras/sky2/latest").json()
    assert latest["frame_level"] in (1, 2)
    assert latest["frame_category"] == "Very Poor"
    smoothed = latest["smoothed_level"]
    assert 7 <= smoothed < 10  # the haze weighs, the clean hours more
    assert latest["level"] == math.floor(smoothed + 0.5)
    assert latest["category"] == latest["smoothed_category"] != "Very Poor"
    assert latest["message"] == f"Today's Air Quality is {latest['category']}"
    every = {c["camera_id"]: c for c in client.get("/air/latest").json()}
    assert every["sky2"] == latest
    on_the_map = next(
        c for c in client.get("/air/isopleths").json()["cameras"] if c["camera_id"] == "sky2"
    )
    assert on_the_map["level"] == pytest.approx(smoothed)

    city["clock"].advance(minutes=20)
    ok, night = cv2.imencode(".jpg", np.full((100, 160, 3), 3, np.uint8))
    assert ok
    assert post_bytes(client, city, "sky2", night.tobytes())["level"] is None
    dark = client.get("/air/cameras/sky2/latest").json()
    assert dark["frame_level"] is None
    assert dark["reason"]
    assert dark["level"] == math.floor(dark["smoothed_level"] + 0.5)
    assert dark["message"] == f"Today's Air Quality is {dark['category']}"


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


def test_a_camera_gone_quiet_does_not_speak_of_today(
    client: TestClient, admin: dict[str, str], city: dict[str, Any]
) -> None:
    """A camera's latest reading, hours old, keeps its level and time but no longer says
    "Today's Air Quality is ..." nor gives a smoothed level (NowCast wants a reading in the
    last 3 hours). Before, a week-old reading read as today's."""
    calibrate(client, admin)
    post(client, city, "sky2", 10, seed=1)
    city["clock"].advance(hours=2, minutes=59)
    fresh = client.get("/air/cameras/sky2/latest").json()
    assert fresh["current"] is True
    assert fresh["message"] == "Today's Air Quality is Very Good"
    assert fresh["smoothed_level"] == pytest.approx(10)

    city["clock"].advance(minutes=1)
    quiet = client.get("/air/cameras/sky2/latest").json()
    assert quiet["current"] is False
    assert (quiet["level"], quiet["category"]) == (10, "Very Good")
    assert quiet["captured_at"] == fresh["captured_at"]
    assert quiet["message"] is None
    assert quiet["smoothed_level"] is None
    assert quiet["smoothed_category"] is None
    assert quiet["reason"] == "no reading in the last 3 hours: the latest was taken 3 h ago"
    city["clock"].advance(hours=44)
    assert client.get("/air/cameras/sky2/latest").json()["reason"].endswith("taken 47 h ago")
    city["clock"].advance(hours=1)  # from two days on, a person counts days
    assert client.get("/air/cameras/sky2/latest").json()["reason"].endswith("taken 2 days ago")

    post(client, city, "sky2", 10, seed=2)  # it speaks again
    assert client.get("/air/cameras/sky2/latest").json()["current"] is True
    nothing = client.get("/air/cameras/sky3/latest").json()
    assert nothing["current"] is False
    assert nothing["reason"] == "no frames yet"


def deliveries(client: TestClient, admin: dict[str, str]) -> dict[str, float]:
    """``vantage_alert_deliveries_total`` by outcome, as /metrics gives it."""
    from prometheus_client.parser import text_string_to_metric_families

    text = client.get("/metrics", headers=admin).text
    return {
        s.labels["outcome"]: s.value
        for family in text_string_to_metric_families(text)
        for s in family.samples
        if s.name == "vantage_alert_deliveries_total"
    }


def test_alert_webhook_retries_until_delivered(settings: Any, engine: Any) -> None:
    """The first POST fails (HTTP 500); the retry after the backoff is delivered, signed with
    the configured secret (checked with the Standard Webhooks reference library)."""
    import threading
    import time
    from http.server import BaseHTTPRequestHandler, HTTPServer

    import standardwebhooks
    from pydantic import SecretStr

    from app.main import create_app
    from tests.factories import empty_tables

    secret = "whsec_" + "c2lnbmluZyBrZXkgb2YgdGhlIGNpdHkncyBhbGVydHM="  # 32 bytes
    verify = standardwebhooks.Webhook(secret).verify
    received: list[dict[str, Any]] = []

    class Hook(BaseHTTPRequestHandler):
        def do_POST(self) -> None:  # noqa: N802
            body = self.rfile.read(int(self.headers["Content-Length"]))
            received.append(verify(body, dict(self.headers.items())))
            self.send_response(500 if len(received) == 1 else 204)
            self.end_headers()

        def log_message(self, *args: Any) -> None:
            pass

    server = HTTPServer(("127.0.0.1", 0), Hook)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    empty_tables(engine)
    app = create_app(
        settings.model_copy(
            update={
                "alert_webhook_url": f"http://127.0.0.1:{server.server_port}/hook",
                "alert_poll_seconds": 0.05,
                "alert_webhook_secret": SecretStr(secret),
            }
        )
    )
    admin = {"Authorization": f"Bearer {settings.admin_token.get_secret_value()}"}
    try:
        with TestClient(app) as client:
            before = deliveries(client, admin)
            token = client.post(
                "/cameras", json={"id": "s", "kind": "sky", "roi": [0, 0, 160, 55]}, headers=admin
            ).json()["token"]
            assert calibrate(client, admin, camera="s").status_code == 201
            for k in range(3):
                client.post(
                    "/cameras/s/frames",
                    content=sky_jpeg(1, seed=k),
                    headers={"Authorization": f"Bearer {token}", "Content-Type": "image/jpeg"},
                )
            deadline = time.monotonic() + 15
            while time.monotonic() < deadline:
                alerts = client.get("/air/alerts").json()
                if alerts and alerts[0]["delivered"]:
                    break
                time.sleep(0.1)
            assert alerts[0]["delivered"] is True
            assert alerts[0]["attempts"] == 2
            assert alerts[0]["delivery"] == "delivered"
            assert alerts[0]["last_error"] is None
            # what an operator alerts on: the receiver failing (a counter per outcome)
            after = deliveries(client, admin)
            assert {k: after[k] - before.get(k, 0.0) for k in after} == {
                "failed": 1.0,
                "delivered": 1.0,
            }
    finally:
        server.shutdown()
        server.server_close()
    assert len(received) == 2
    assert received[1]["message"].startswith("Today's Air Quality is")


def test_a_test_alert_checks_the_receiver_and_its_secret(
    client: TestClient, settings: Any, engine: Any, admin: dict[str, str]
) -> None:
    """``POST /air/alerts/test``: the operator checks the receiver (and that it verifies the
    signature) before the air turns Poor. Nothing is recorded; without a webhook, 409."""
    import threading
    from http.server import BaseHTTPRequestHandler, HTTPServer

    import standardwebhooks
    from pydantic import SecretStr

    from app.main import create_app

    assert client.post("/air/alerts/test", headers=admin).status_code == 409
    secret = "whsec_" + "dGhlIGNpdHkncyB0ZXN0IHNpZ25pbmcga2V5IDMyYg=="
    got: list[dict[str, Any]] = []
    answers = [204, 500]

    class Hook(BaseHTTPRequestHandler):
        def do_POST(self) -> None:  # noqa: N802
            body = self.rfile.read(int(self.headers["Content-Length"]))
            got.append(standardwebhooks.Webhook(secret).verify(body, dict(self.headers.items())))
            self.send_response(answers[len(got) - 1])
            self.end_headers()

        def log_message(self, *args: Any) -> None:
            pass

    server = HTTPServer(("127.0.0.1", 0), Hook)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    app = create_app(
        settings.model_copy(
            update={
                "alert_webhook_url": f"http://127.0.0.1:{server.server_port}/hook",
                "alert_webhook_secret": SecretStr(secret),
            }
        )
    )
    try:
        with TestClient(app) as hooked:
            r = hooked.post("/air/alerts/test", headers=admin)
            assert r.status_code == 200, r.text
            assert r.json() == {
                "webhook_id": got[0]["alert_id"],
                "delivered": True,
                "error": None,
                "signed": True,
            }
            assert got[0]["kind"] == "test"
            failed = hooked.post("/air/alerts/test", headers=admin).json()
            assert (failed["delivered"], failed["error"]) == (
                False,
                "HTTP 500 Internal Server Error",
            )
            assert hooked.get("/air/alerts").json() == []
            camera = hooked.post("/cameras", json={"id": "s", "kind": "sky"}, headers=admin)
            as_camera = {"Authorization": f"Bearer {camera.json()['token']}"}
            assert hooked.post("/air/alerts/test", headers=as_camera).status_code == 403
    finally:
        server.shutdown()
        server.server_close()


def test_regression_calibration(
    client: TestClient, admin: dict[str, str], city: dict[str, Any]
) -> None:
    """``method=regression``: an estimate for every frame close to the truth on synthetic
    skies, its 80 % interval around it; a level only where the interval's ends share a
    category (else ``uncertain``, with no level)."""
    files, levels = [], []
    for level in range(1, 11):
        for k in range(3):
            files.append(
                ("files", (f"{level}-{k}.jpg", sky_jpeg(level, seed=10 * level + k), "image/jpeg"))
            )
            levels.append(str(level))
    r = client.post(
        "/air/calibration",
        files=files,
        data={"levels": levels},
        headers=admin,
        params={"camera_id": "sky0", "method": "regression"},
    )
    assert r.status_code == 201, r.text
    assert r.json()["method"] == "regression"
    for level in (2, 5, 9):
        v = post(client, city, "sky4", level, seed=500 + level)
        e = v["estimate"]
        assert e["unit"] == "level"
        assert abs(e["value"] - level) <= 0.5
        assert e["low"] < e["value"] < e["high"]
        low, high = airquality.category(e["low"]), airquality.category(e["high"])
        assert v["uncertain"] is (low != high)
        # an interval across categories doubts the level, but still says the estimate's
        assert v["level"] == round(e["value"])
        if low == high:
            assert v["reason"] is None
            assert v["message"] == f"Today's Air Quality is {v['category']}"
        else:
            assert v["reason"].startswith("uncertain: the 80% interval")
            assert v["category"] is None
            assert v["message"].startswith("Not sure")
    # too few images for a regression
    r = client.post(
        "/air/calibration",
        files=files[:4],
        data={"levels": levels[:4]},
        headers=admin,
        params={"method": "regression"},
    )
    assert r.status_code == 422


def even_smog(v: int) -> bytes:
    """An even white-grey sky (v, v + 4, v + 10) over most of the region (rows 0–40), a
    brighter band below it (rows 40–55): its modes are exactly (v, v + 3, v + 10)."""
    image = np.empty((120, 160, 3), np.float64)
    image[:] = (v, v + 4, v + 10)
    image[40:55] += np.linspace(5, 30, 160)[None, :, None]
    image[60:] = (40, 40, 45)
    bgr = np.clip(image, 0, 255).astype(np.uint8)[:, :, ::-1]
    ok, buf = cv2.imencode(".jpg", np.ascontiguousarray(bgr), [cv2.IMWRITE_JPEG_QUALITY, 95])
    assert ok
    return buf.tobytes()


def test_a_regression_needs_no_cluster_covariance(
    client: TestClient, admin: dict[str, str], city: dict[str, Any]
) -> None:
    """Eight even skies of level 1 whose modes lie on one line (one grey sky, eight
    exposures): that level's mode covariance is singular. The dissertation's clusters take
    the rounding variance on its diagonal and say so (201, a warning); a regression never
    uses it."""

    def image(level: int, k: int) -> bytes:
        return even_smog(186 + 3 * k) if level == 1 else sky_jpeg(level, seed=100 * level + k)

    clusters = calibrate(client, admin, "sky0", image=image)
    assert clusters.status_code == 201, clusters.text
    assert any(w.startswith("level 1:") and "1/12" in w for w in clusters.json()["warnings"]), (
        clusters.json()
    )
    r = calibrate(client, admin, "sky0", method="regression", image=image)
    assert r.status_code == 201, r.text
    assert any(w.startswith("level 1:") for w in r.json()["warnings"]), r.json()
    for level in (3, 7):
        v = post(client, city, "sky2", level, seed=700 + level)
        assert abs(v["level"] - level) <= 1, v
    assert post_bytes(client, city, "sky2", even_smog(193))["level"] <= 2


def test_a_camera_calibrated_from_its_own_frames_is_graded_by_its_own_calibration(
    client: TestClient, admin: dict[str, str], city: dict[str, Any]
) -> None:
    """sky1 sees the city's skies with the opposite meaning (a view whose clear sky looks like
    the others' haze): calibrated for it alone, it grades sky1's frames and no other's."""
    own = calibrate(client, admin, "sky1", label=lambda level: 11 - level, applies_to=["sky1"])
    assert own.status_code == 201, own.text
    assert own.json()["camera_ids"] == ["sky1"]
    # no city-wide calibration yet: the other cameras are not graded
    assert "not calibrated" in post(client, city, "sky0", 10, seed=1)["reason"]
    assert client.get("/air/calibration").status_code == 404

    city["clock"].advance(hours=1)
    city_wide = calibrate(client, admin)
    assert city_wide.status_code == 201, city_wide.text
    assert city_wide.json()["camera_ids"] == []

    for seed in range(10, 13):
        mine, other = post(client, city, "sky1", 10, seed), post(client, city, "sky0", 10, seed)
        assert (mine["level"], mine["calibration_id"]) == (1, own.json()["id"])
        assert (other["level"], other["calibration_id"]) == (10, city_wide.json()["id"])

    assert client.get("/air/calibration").json()["id"] == city_wide.json()["id"]
    got = client.get("/air/calibration", params={"camera_id": "sky1"}).json()
    assert (got["id"], got["camera_ids"]) == (own.json()["id"], ["sky1"])
    got = client.get("/air/calibration", params={"camera_id": "sky2"}).json()
    assert got["id"] == city_wide.json()["id"]
    assert client.get("/air/calibration", params={"camera_id": "nope"}).status_code == 404

    # a newer city-wide calibration does not replace a camera's own
    city["clock"].advance(hours=1)
    newer = calibrate(client, admin)
    assert newer.status_code == 201
    assert post(client, city, "sky1", 10, seed=9)["calibration_id"] == own.json()["id"]

    listed = client.get("/air/calibrations").json()  # public, newest first
    assert [(c["id"], c["camera_ids"]) for c in listed] == [
        (newer.json()["id"], []),
        (city_wide.json()["id"], []),
        (own.json()["id"], ["sky1"]),
    ]
    only = client.get("/air/calibrations", params={"camera_id": "sky1"}).json()
    assert [c["id"] for c in only] == [own.json()["id"]]
    assert client.get("/air/calibrations", params={"camera_id": "sky2"}).json() == []
    assert client.get("/air/calibrations", params={"camera_id": "nope"}).status_code == 404
    page = client.get("/air/calibrations", params={"limit": 1, "offset": 1}).json()
    assert [c["id"] for c in page] == [city_wide.json()["id"]]
    assert [c["city_wide"] for c in listed] == [True, True, False]


def test_a_camera_whose_region_changed_is_not_graded_by_the_calibration_made_for_the_old(
    client: TestClient, admin: dict[str, str], city: dict[str, Any]
) -> None:
    """sky1's own calibration (a regression) was made while it measured the sky. Its region
    moved down onto the street, and the street was graded by it: level 10, Very Good. Until
    it is calibrated again its frames get no level; back on the sky, they are graded again.
    The city-wide calibration grades every region."""
    city_wide = calibrate(client, admin).json()
    own = calibrate(client, admin, "sky1", applies_to=["sky1"], method="regression")
    assert own.status_code == 201, own.text
    v = post(client, city, "sky1", 10, seed=1)
    assert v["level"] == 10, v

    street = [0, 65, 160, 35]
    for camera in ("sky1", "sky2"):
        r = client.patch(f"/cameras/{camera}", json={"roi": street}, headers=admin)
        assert r.status_code == 200, r.text
    for seed in range(2, 5):
        city["clock"].advance(minutes=10)
        v = post(client, city, "sky1", 10, seed=seed)
        assert (v["level"], v["roi"]) == (None, street), v
        assert "made when it measured roi [0, 0, 160, 55], not roi [0, 65, 160, 35]" in v["reason"]
    other = post(client, city, "sky2", 10, seed=5)  # graded city-wide, in any region
    assert other["calibration_id"] == city_wide["id"]

    r = client.patch("/cameras/sky1", json={"roi": [0, 0, 160, 55]}, headers=admin)
    assert r.status_code == 200, r.text
    v = post(client, city, "sky1", 10, seed=6)
    assert (v["calibration_id"], v["roi"]) == (own.json()["id"], [0, 0, 160, 55])
    assert v["level"] == 10


def test_a_camera_calibrated_from_its_stored_frames_in_the_region_it_measures(
    client: TestClient, admin: dict[str, str], city: dict[str, Any]
) -> None:
    """sky1's stored frames, labelled, calibrate it. Frames measured in a region it no longer
    measures may not make its own calibration (it would grade another part of the view); they
    may still make a city-wide one."""
    ids, levels = labelled_frames(client, city, lambda level, k: sky_jpeg(level, 100 * level + k))
    body = {"frame_ids": ids, "levels": levels}
    own = client.post("/air/calibration", json=body, headers=admin, params={"applies_to": "sky1"})
    assert own.status_code == 201, own.text
    assert own.json()["camera_ids"] == ["sky1"]
    for level in (1, 10):
        v = post(client, city, "sky1", level, seed=900 + level)
        assert (v["level"], v["calibration_id"]) == (level, own.json()["id"])

    r = client.patch("/cameras/sky1", json={"roi": [0, 0, 160, 50]}, headers=admin)
    assert r.status_code == 200, r.text
    again = client.post("/air/calibration", json=body, headers=admin, params={"applies_to": "sky1"})
    assert again.status_code == 422, again.text
    assert again.json()["code"] == "region_not_in_use"
    assert "camera now measures roi [0, 0, 160, 50]" in again.json()["detail"]
    city_wide = client.post("/air/calibration", json=body, headers=admin)
    assert city_wide.status_code == 201, city_wide.text
    assert len(client.get("/air/calibrations").json()) == 2


def test_no_calibration_from_stored_frames_the_quality_gate_found_unusable(
    client: TestClient, admin: dict[str, str], city: dict[str, Any]
) -> None:
    """A night frame labelled with the day's level (the reference station measures day and
    night) was taken into the calibration: its modes are the dark, not the air. Uploaded, it is
    refused by name; stored, it is refused alike and nothing is made."""
    night = make_jpeg(160, 120, (4, 4, 8))
    ids, levels = labelled_frames(
        client, city, lambda level, k: night if (level, k) == (5, 0) else sky_jpeg(level, seed=k)
    )
    dark = ids[16]
    r = client.get(f"/frames/{dark}", headers=admin)
    assert r.json()["verdict"]["reason"].startswith("too dark to judge"), r.text
    body = {"frame_ids": ids, "levels": levels}
    r = client.post("/air/calibration", json=body, headers=admin)
    assert r.status_code == 422, r.text
    assert (r.json()["code"], r.json()["unusable"]) == ("unusable_frames", [dark])
    assert f"{dark}: too dark to judge" in r.json()["detail"]
    assert client.get("/air/calibrations").json() == []
    rest = {"frame_ids": ids[:16] + ids[17:], "levels": levels[:16] + levels[17:]}
    assert client.post("/air/calibration", json=rest, headers=admin).status_code == 201


def test_uploads_for_cameras_are_measured_in_their_region(
    client: TestClient, admin: dict[str, str], city: dict[str, Any]
) -> None:
    """Uploads calibrating sky2 and sky3 (no camera_id) are those cameras' full frames: measured
    in their common ROI (the sky), as their frames will be. Measured whole, the dark street
    below would make every level look hazier than it is (to the regression on means; the
    clusters' modes are the sky's either way)."""
    r = calibrate(client, admin, None, applies_to=["sky2", "sky3"], method="regression")
    assert r.status_code == 201, r.text
    assert r.json()["warnings"] == []
    for level in (2, 5, 9):
        v = post(client, city, "sky3", level, seed=700 + level)
        assert v["level"] is not None, v
        assert abs(v["level"] - level) <= 1, v


def test_a_calibration_measured_elsewhere_than_its_cameras_says_so(
    client: TestClient, admin: dict[str, str], city: dict[str, Any]
) -> None:
    """Uploads measured whole (city-wide, no camera_id), or in a region other cameras do not
    share: the model names the cameras it grades that measure another region."""
    r = calibrate(client, admin, None)
    assert r.status_code == 201, r.text
    [warning] = [w for w in r.json()["warnings"] if "region" in w]
    for part in ("the whole image", "sky0", "7 more", "camera_id"):
        assert part in warning

    odd = {"id": "odd", "kind": "sky", "lat": 45.4, "lon": 9.1, "roi": [0, 0, 160, 40]}
    assert client.post("/cameras", json=odd, headers=admin).status_code == 201
    r = calibrate(client, admin, "sky0", applies_to=["sky0", "odd"])
    assert r.status_code == 201, r.text
    [warning] = [w for w in r.json()["warnings"] if "region" in w]
    assert "camera 'sky0'" in warning
    assert "odd" in warning
    assert "sky1" not in warning
    # the same cameras without camera_id: no common region, measured whole, both named
    r = calibrate(client, admin, None, applies_to=["sky0", "odd"])
    assert r.status_code == 201, r.text
    [warning] = [w for w in r.json()["warnings"] if "region" in w]
    assert "the whole image" in warning
    assert "odd, sky0" in warning


def test_a_camera_released_from_its_own_calibration_is_graded_city_wide_again(
    client: TestClient, admin: dict[str, str], city: dict[str, Any]
) -> None:
    city_wide = calibrate(client, admin).json()
    city["clock"].advance(hours=1)
    own = calibrate(
        client, admin, "sky1", label=lambda level: 11 - level, applies_to=["sky1", "sky2"]
    ).json()
    assert post(client, city, "sky1", 10, seed=1)["level"] == 1

    path = "/air/cameras/sky1/calibration"
    assert client.delete(path).status_code == 401  # an operator's act
    assert client.delete(path, headers=admin).status_code == 204
    assert client.delete(path, headers=admin).status_code == 404  # none of its own left
    assert client.delete("/air/cameras/nope/calibration", headers=admin).status_code == 404

    v = post(client, city, "sky1", 10, seed=2)
    assert (v["level"], v["calibration_id"]) == (10, city_wide["id"])
    # the calibration keeps grading its other camera, and is still not the city-wide one
    assert post(client, city, "sky2", 10, seed=3)["calibration_id"] == own["id"]
    assert client.get("/air/calibration").json()["id"] == city_wide["id"]
    listed = {c["id"]: c for c in client.get("/air/calibrations").json()}
    assert (listed[own["id"]]["camera_ids"], listed[own["id"]]["city_wide"]) == (["sky2"], False)


@pytest.mark.parametrize(
    ("applies_to", "detail"),
    [
        (["nope"], "no sky camera 'nope'"),
        (["rig0"], "no sky camera 'rig0'"),
        (["sky0", "a/b"], "applies_to"),
        (["sky0", "nope", "rig0"], "no sky camera 'nope' (and 1 more)"),
    ],
)
def test_a_calibration_for_cameras_that_are_not_sky_cameras_is_refused_and_stores_nothing(
    client: TestClient,
    admin: dict[str, str],
    city: dict[str, Any],
    applies_to: list[str],
    detail: str,
) -> None:
    r = client.post("/cameras", json={"id": "rig0", "kind": "rig"}, headers=admin)
    assert r.status_code == 201, r.text
    r = calibrate(client, admin, applies_to=applies_to)
    assert r.status_code == 422, r.text
    assert r.headers["content-type"].startswith("application/problem+json")
    assert detail in r.json()["detail"]
    # nothing stored: a calibration made for cameras is never the city-wide one, so only the
    # full list shows it
    assert client.get("/air/calibrations").json() == []
    assert client.get("/air/calibration", params={"camera_id": "sky0"}).status_code == 404


def panel_verdict(client: TestClient, admin: dict[str, str], jpeg: bytes) -> Any:
    """The verdict on ``jpeg`` of a new panel camera ``pc`` watching a new panel ``p``."""
    assert client.post("/panels", json={"id": "p"}, headers=admin).status_code == 201
    cam = {"id": "pc", "kind": "panel", "panel_id": "p"}
    token = client.post("/cameras", json=cam, headers=admin).json()["token"]
    r = client.post(
        "/cameras/pc/frames",
        content=jpeg,
        headers={"Authorization": f"Bearer {token}", "Content-Type": "image/jpeg"},
    )
    assert r.status_code == 201, r.text
    return r.json()["verdict"]


def test_smog_is_graded_and_calibrated_on_not_taken_for_a_fault(
    client: TestClient, admin: dict[str, str], city: dict[str, Any]
) -> None:
    """A white, even sky is what the worst air looks like: the panel cameras' quality gate took
    it for a blank frame, so a sky camera's verdict had no level on those days, and such photos
    could not calibrate level 1. Sky cameras are gated by limits of their own; a panel camera's
    blank frame is still one."""
    smog = make_jpeg(160, 120, (196, 198, 202), noise=1.5)
    v = post_bytes(client, city, "sky0", smog)
    assert v["level"] is None
    assert "not calibrated" in v["reason"]  # gated, it had said "blank frame"

    # calibrated with smog as level 1, the smoggy frame is graded Very Poor
    def image(level: int, k: int) -> bytes:
        if level == 1:
            return make_jpeg(160, 120, (193 + k, 196 + k % 3, 200 + k % 4), noise=1.5, seed=k)
        return sky_jpeg(level, seed=100 * level + k)

    r = calibrate(client, admin, "sky0", method="regression", image=image)
    assert r.status_code == 201, r.text
    v = post_bytes(client, city, "sky0", make_jpeg(160, 120, (196, 198, 202), noise=1.5, seed=99))
    assert (v["level"], v["category"]) == (1, "Very Poor"), v

    assert panel_verdict(client, admin, smog)["reason"].startswith("blank frame")


def test_leaves_over_a_sky_region_are_reported_not_graded(
    client: TestClient, admin: dict[str, str], city: dict[str, Any]
) -> None:
    """A calibrated sky camera whose region (rows 0–55) is half covered by leaves: the frame
    is stored with level null and the reason, the camera's latest reading stays the graded one
    before, and a calibration that includes the frame is refused by name. A panel camera's
    green view is not an obstruction, nor is a sky camera's without a region (its whole view
    is not meant to be sky)."""
    assert calibrate(client, admin, "sky0").status_code == 201
    graded = post(client, city, "sky0", 7, seed=5)
    assert graded["level"] is not None
    image = cv2.imdecode(np.frombuffer(sky_jpeg(7, seed=6), np.uint8), cv2.IMREAD_COLOR)
    image[25:55] = (50, 140, 60)  # BGR: leaves over the lower 30 rows of the region
    image += np.random.default_rng(3).integers(0, 12, image.shape, dtype=np.uint8)
    leafy = cv2.imencode(".jpg", image)[1].tobytes()
    v = post_bytes(client, city, "sky0", leafy)
    assert (v["level"], v["category"]) == (None, None), v
    assert v["reason"].startswith("obstructed: "), v
    assert "foliage" in v["reason"], v
    latest = client.get("/air/cameras/sky0/latest").json()
    assert latest["level"] == graded["level"], latest
    frames = client.get("/cameras/sky0/frames", headers=admin).json()
    leafy_id = next(f["frame_id"] for f in frames if f["verdict"]["level"] is None)
    body = {"frame_ids": [leafy_id], "levels": [7]}
    r = client.post("/air/calibration", json=body, headers=admin)
    assert r.status_code == 422, r.text
    assert r.json()["unusable"] == [leafy_id], r.text

    assert "obstructed" not in (panel_verdict(client, admin, leafy).get("reason") or "")
    # a sky camera without a region measures its whole view, trees and street included
    whole = {"id": "whole", "kind": "sky", "lat": 45.45, "lon": 9.2}
    token = client.post("/cameras", json=whole, headers=admin).json()["token"]
    city["tokens"]["whole"] = (token, 9.2)
    assert "obstructed" not in (post_bytes(client, city, "whole", leafy).get("reason") or "")
