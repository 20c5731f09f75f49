"""Robots find their panel and the board shows the cameras' latest word: the claim carries the
panel's name and place, a robot may read the panel of a task it holds (and no other), and a
panel's dirty streak toward the trigger is in its listing and status."""

from __future__ import annotations

from typing import Any

import pytest
from fastapi.testclient import TestClient

from tests.factories import bearer
from tests.factories.solar import CLEAN_RGB, DUST, clean_set, post_frame, train


@pytest.fixture
def farm(farm: dict[str, Any], client: TestClient, admin: dict[str, str]) -> dict[str, Any]:
    """The solar tests' farm, its panel p1 named and placed, and a second panel p2."""
    body = {"name": "A-7", "lat": 37.1, "lon": -2.3, "location": "row 3, string B"}
    assert client.patch("/panels/p1", json=body, headers=admin).status_code == 200
    assert client.post("/panels", json={"id": "p2"}, headers=admin).status_code == 201
    return farm


def test_the_streak_toward_the_trigger_is_shown(
    client: TestClient, admin: dict[str, str], farm: dict[str, Any]
) -> None:
    assert train(client, admin, clean_set(10)).status_code == 201
    post_frame(client, farm, CLEAN_RGB + DUST)
    post_frame(client, farm, CLEAN_RGB + DUST, seed=1)
    [p1] = [p for p in client.get("/panels", headers=admin).json() if p["id"] == "p1"]
    assert (p1["state"], p1["last_clean"], p1["dirty_streak"], p1["streak_needed"]) == (
        "clean",
        False,
        2,
        3,
    )
    assert p1["doubted"] is False  # its latest word is a verdict, not a doubt
    status = client.get("/panels/p1/status", headers=admin).json()
    assert (status["dirty_streak"], status["streak_needed"]) == (2, 3)


def test_a_claim_says_where_the_panel_is(
    client: TestClient, admin: dict[str, str], farm: dict[str, Any]
) -> None:
    assert train(client, admin, clean_set(10)).status_code == 201
    for k in range(3):
        post_frame(client, farm, CLEAN_RGB + DUST, seed=k)
    r1, r2 = bearer(farm["robots"]["r1"]), bearer(farm["robots"]["r2"])
    assert client.get("/panels/p1", headers=r1).status_code == 403  # no task held yet
    claimed = client.post("/cleaning/claim", headers=r1)
    assert claimed.status_code == 200, claimed.text
    assert claimed.json()["panel"] == {
        "id": "p1",
        "name": "A-7",
        "lat": 37.1,
        "lon": -2.3,
        "location": "row 3, string B",
    }
    # the holder reads its task's panel; another robot, or another panel, is refused
    mine = client.get("/panels/p1", headers=r1)
    assert mine.status_code == 200, mine.text
    assert mine.json()["location"] == "row 3, string B"
    assert client.get("/panels/p2", headers=r1).status_code == 403
    assert client.get("/panels/p1", headers=r2).status_code == 403
    # once its lease has run out, the robot holds nothing
    farm["clock"].advance(hours=2)
    assert client.get("/panels/p1", headers=r1).status_code == 403


def test_a_location_is_bounded_and_patched(client: TestClient, admin: dict[str, str]) -> None:
    long = {"id": "p9", "location": "x" * 201}
    assert client.post("/panels", json=long, headers=admin).status_code == 422
    assert client.get("/panels/p9", headers=admin).status_code == 404
    assert client.post("/panels", json={"id": "p9"}, headers=admin).status_code == 201
    patched = client.patch("/panels/p9", json={"location": "roof, east"}, headers=admin)
    assert patched.json()["location"] == "roof, east"
    cleared = client.patch("/panels/p9", json={"location": None}, headers=admin)
    assert cleared.json()["location"] is None
