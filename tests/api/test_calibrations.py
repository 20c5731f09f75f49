"""POST /calibrations on OpenCV's stereo sample set (reference figures in its README)."""

from __future__ import annotations

import pytest
from fastapi.testclient import TestClient

from tests.conftest import SHARED_DATA

DATA = SHARED_DATA / "calibration" / "opencv_stereo"
needs_data = pytest.mark.skipif(not DATA.exists(), reason="shared data absent")
NUMBERS = ["01", "02", "03", "04", "05", "06", "07", "08", "09", "11", "12", "13", "14"]


def files(side: str, field: str) -> list[tuple[str, tuple[str, bytes, str]]]:
    return [
        (field, (f"{side}{n}.jpg", (DATA / f"{side}{n}.jpg").read_bytes(), "image/jpeg"))
        for n in NUMBERS
    ]


@needs_data
def test_left_camera_matches_the_reference(client: TestClient, admin: dict[str, str]) -> None:
    r = client.post(
        "/calibrations",
        files=files("left", "files"),
        headers=admin,
        data={"pattern_cols": "9", "pattern_rows": "6", "square_size": "1.0"},
    )
    assert r.status_code == 201, r.text
    c = r.json()
    (fx, _, cx), (_, fy, cy), _ = c["K"]
    # the README's reference: fx 536.07, fy 536.02, cx 342.37, cy 235.54, RMS 0.4087
    assert fx == pytest.approx(536.07, rel=0.005)
    assert fy == pytest.approx(536.02, rel=0.005)
    assert cx == pytest.approx(342.37, abs=2)
    assert cy == pytest.approx(235.54, abs=2)
    assert c["rms_px"] <= 0.45
    assert len(c["per_view_rms_px"]) == len(c["views_used"]) == 13
    assert c["views_rejected"] == []
    assert c["std"]["fx"] > 0
    assert client.get(f"/calibrations/{c['id']}", headers=admin).json()["K"] == c["K"]


@needs_data
def test_stereo_baseline(client: TestClient, admin: dict[str, str]) -> None:
    r = client.post(
        "/calibrations/stereo", files=files("left", "left") + files("right", "right"), headers=admin
    )
    assert r.status_code == 201, r.text
    s = r.json()
    assert s["baseline"] == pytest.approx(3.345, rel=0.01)  # README: 3.345 squares
    assert s["rms_px"] <= 0.46
    assert s["rotation_deg"] == pytest.approx(0.31, abs=0.1)


def test_unusable_images_are_named(client: TestClient, admin: dict[str, str]) -> None:
    bad = [
        ("files", ("x.jpg", b"not an image", "image/jpeg")),
        ("files", ("y.png", b"\x89PNG", "image/png")),
    ]
    r = client.post("/calibrations", files=bad, headers=admin)
    assert r.status_code == 422
    body = r.json()
    assert "at least 3" in body["detail"]
    assert [v["file"] for v in body["views_rejected"]] == ["x.jpg", "y.png"]
    assert client.post("/calibrations", files=bad).status_code == 401
