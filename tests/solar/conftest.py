"""The solar tests' farm: a panel p1, its camera c1 and two robots, on the test clock."""

from __future__ import annotations

from typing import Any

import pytest
from fastapi.testclient import TestClient

from tests.factories import Clock


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
