"""VANTAGE_HISTORY_RETENTION_DAYS: a city keeps its readings (and trends) longer than the
photos they were read from."""

from __future__ import annotations

from typing import Any

import pytest
from fastapi.testclient import TestClient
from pydantic import ValidationError

from app.platform.settings import Settings
from tests.factories import table_counts
from tests.factories.air import calibrate, sky_jpeg


@pytest.fixture
def settings(settings: Settings) -> Settings:
    return settings.model_copy(update={"history_retention_days": 365.0})


def test_readings_outlive_their_images(
    client: TestClient,
    admin: dict[str, str],
    city: dict[str, Any],
    engine: Any,
) -> None:
    assert calibrate(client, admin).status_code == 201

    def post(seed: int) -> str:
        r = client.post(
            "/cameras/sky0/frames",
            content=sky_jpeg(10, seed),
            headers={
                "Authorization": f"Bearer {city['tokens']['sky0'][0]}",
                "Content-Type": "image/jpeg",
            },
        )
        assert r.status_code == 201, r.text
        return str(r.json()["frame_id"])

    old = []
    for k in range(3):
        old.append(post(seed=k))
        city["clock"].advance(hours=1)
    city["clock"].advance(days=40)
    fresh = post(seed=9)

    swept = client.post("/admin/retention/sweep", headers=admin).json()
    assert swept == {"frames": 0, "files": 3, "images": 3}  # three hours' packs
    readings = client.get("/air/readings", params={"camera_id": "sky0"}).json()
    assert [r["frame_id"] for r in readings] == [fresh, *reversed(old)]
    assert all(r["level"] == 10 for r in readings)
    days = client.get("/air/readings", params={"camera_id": "sky0", "aggregate": "daily"}).json()
    assert [d["n"] for d in days] == [1, 3]
    for frame_id in old:
        assert client.get(f"/frames/{frame_id}", headers=admin).json()["stored"] is False
        assert client.get(f"/frames/{frame_id}/image", headers=admin).status_code == 404
    assert client.get(f"/frames/{fresh}/image", headers=admin).status_code == 200
    assert client.post("/admin/retention/sweep", headers=admin).json() == {
        "frames": 0,
        "files": 0,
        "images": 0,
    }

    # a year on, the rows go too
    city["clock"].advance(days=366)
    swept = client.post("/admin/retention/sweep", headers=admin).json()
    assert swept == {"frames": 4, "files": 1, "images": 0}  # the fresh frame's pack
    assert client.get("/air/readings", params={"camera_id": "sky0"}).json() == []
    assert table_counts(engine)["frames"] == 0


def test_history_shorter_than_the_images_is_refused() -> None:
    with pytest.raises(ValidationError, match="HISTORY_RETENTION_DAYS must be at least"):
        Settings(frame_retention_days=30, history_retention_days=7)
