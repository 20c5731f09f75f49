"""A sky camera's readings as the public reads them: the latest of every camera, the public
level, a camera gone quiet."""

from __future__ import annotations

import math
from typing import Any

import cv2
import numpy as np
import pytest
from fastapi.testclient import TestClient

from tests.factories.air import calibrate, post, post_bytes


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


def test_a_camera_gone_quiet_does_not_speak_of_today(
    client: TestClient, admin: dict[str, str], city: dict[str, Any]
) -> None:
    """A camera's latest reading, hours old, keeps its level and time but no longer says
    "Today's Air Quality is ..." nor gives a smoothed level (NowCast wants a reading in the
    last 3 hours): the screen says, in its words, how old it is. Before, a week-old reading
    read as today's."""
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
    assert quiet["message"] == "No reading in the last 3 hours (the latest was taken 3 h ago)"
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
    assert nothing["message"] == "Air quality not measured here yet"
