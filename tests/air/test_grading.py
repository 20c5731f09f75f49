"""Grading sky frames: smog is graded (not taken for a fault), leaves over the sky region
are reported."""

from __future__ import annotations

from typing import Any

import cv2
import numpy as np
from fastapi.testclient import TestClient

from tests.factories import make_jpeg
from tests.factories.air import calibrate, post, post_bytes, sky_jpeg


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
