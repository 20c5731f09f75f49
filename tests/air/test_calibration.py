"""Calibrating the sky's grading over HTTP: the regression, a camera's own calibration and
its region, stored frames, releasing a camera."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import cv2
import numpy as np
import pytest
from fastapi.testclient import TestClient

from app.air.core import airquality
from tests.factories import make_jpeg
from tests.factories.air import calibrate, post, post_bytes, sky_jpeg


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
        # the most probable category, said plainly from a probability of 0.8
        assert 0 < v["probability"] <= 1
        assert v["uncertain"] is (v["probability"] < 0.8)
        assert v["category"] in {low, high, airquality.category(e["value"])}
        assert airquality.category(v["level"]) == v["category"]
        assert abs(v["level"] - e["value"]) <= 1.5
        if low == high:  # an interval within one category: that category, sure
            assert v["category"] == low
            assert v["uncertain"] is False
        if v["uncertain"]:
            assert v["reason"].startswith(f"uncertain: likely {v['category']}, probability")
            assert v["message"] == f"Today's Air Quality is likely {v['category']}"
        else:
            assert v["reason"] is None
            assert v["message"] == f"Today's Air Quality is {v['category']}"
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
