"""Air-quality alerts: raised when a camera's smoothed level turns Poor, cleared when it is
back, one per episode, history never an alert; the listing."""

from __future__ import annotations

from datetime import datetime, timedelta
from itertools import pairwise
from typing import Any

import cv2
import numpy as np
import pytest
from fastapi.testclient import TestClient

from tests.factories.air import calibrate, post, sky_jpeg


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
