"""ChArUco boards: calibration and hand-eye from views where the board is partly out of the
frame, rendered through a known camera (K_RENDER, known only to the renderer)."""

from __future__ import annotations

import json
from typing import Any

import cv2
import numpy as np
import pytest
from fastapi.testclient import TestClient

from app.cells.core import charuco, hand_eye
from tests.factories.cells import BOARD_ON_FLANGE, CAMERA_IN_BASE, K_RENDER, charuco_photo

SQUARE, MARKER = 0.04, 0.03  # m
BOARD = {
    "board": "charuco",
    "dictionary": "DICT_5X5_100",
    "pattern_cols": "7",
    "pattern_rows": "5",
    "square_size": str(SQUARE),
    "marker_size": str(MARKER),
}


def poses(n: int, seed: int) -> list[np.ndarray]:
    """Camera ← board, every third view pushed 12 cm aside: a third of the board out."""
    rng = np.random.default_rng(seed)
    centre = np.array([3.5 * SQUARE, 2.5 * SQUARE, 0.0])
    out = []
    for i in range(n):
        r = cv2.Rodrigues(rng.normal(0, 0.35, 3))[0]
        aside = np.array([0.12 if i % 3 == 0 else 0.0, 0.0, 0.0])
        t = -r @ centre + np.array([0.0, 0.0, 0.55]) + rng.normal(0, [0.02, 0.02, 0.04]) + aside
        out.append(hand_eye.rigid(r, t))
    return out


@pytest.fixture(scope="module")
def views() -> tuple[list[np.ndarray], list[tuple[str, tuple[str, bytes, str]]]]:
    board = charuco.board(7, 5, SQUARE, MARKER, "DICT_5X5_100")
    cs = poses(12, seed=2)
    files = []
    for i, c in enumerate(cs):
        rvec = cv2.Rodrigues(c[:3, :3])[0].ravel()
        image = charuco_photo(K_RENDER, rvec, c[:3, 3], (640, 480), board, seed=i)
        files.append(
            ("files", (f"c{i}.png", cv2.imencode(".png", image)[1].tobytes(), "image/png"))
        )
    return cs, files


def test_partly_visible_boards_count(client: TestClient, admin: dict[str, str], views: Any) -> None:
    _, files = views
    r = client.post("/calibrations", files=files, data=BOARD, headers=admin)
    assert r.status_code == 201, r.text
    c = r.json()
    assert len(c["views_used"]) == 12  # the boards a third out of the frame too
    assert c["board"] == "charuco"
    assert c["K"][0][0] == pytest.approx(800.0, rel=0.005)  # K_RENDER's
    assert c["K"][0][2] == pytest.approx(320.0, abs=2)
    assert c["rms_px"] < 0.15
    assert c["loo_rms_px"] <= 1.2 * c["rms_px"]


def test_hand_eye_with_a_charuco_board(
    client: TestClient, admin: dict[str, str], views: Any
) -> None:
    cs, files = views
    cal = client.post("/calibrations", files=files, data=BOARD, headers=admin).json()
    flange = [CAMERA_IN_BASE @ c @ hand_eye.inverse(BOARD_ON_FLANGE) for c in cs]
    poses_json = [
        json.dumps(
            {"rvec": cv2.Rodrigues(f[:3, :3])[0].ravel().tolist(), "tvec": f[:3, 3].tolist()}
        )
        for f in flange
    ]
    form = {**BOARD, "calibration_id": cal["id"], "setup": "eye_to_hand", "poses": poses_json}
    r = client.post("/calibrations/hand-eye", files=files, data=form, headers=admin)
    assert r.status_code == 201, r.text
    x = np.array(r.json()["camera_to_base"])
    assert np.linalg.norm(x[:3, 3] - CAMERA_IN_BASE[:3, 3]) < 3e-3
    turn = cv2.Rodrigues(x[:3, :3].T @ CAMERA_IN_BASE[:3, :3])[0]
    assert np.degrees(np.linalg.norm(turn)) < 0.3


@pytest.mark.parametrize(
    ("change", "says"),
    [
        ({"marker_size": None}, "needs marker_size"),
        ({"marker_size": "0.05"}, "below square_size"),
        ({"dictionary": "DICT_9X9_1"}, "not one of OpenCV's"),
        ({"dictionary": "DICT_4X4_50", "pattern_cols": "20", "pattern_rows": "20"}, "needs 200"),
        ({"board": "aruco"}, "checkerboard or charuco"),
    ],
)
def test_a_board_opencv_cannot_make_is_422(
    client: TestClient, admin: dict[str, str], views: Any, change: dict[str, Any], says: str
) -> None:
    _, files = views
    form = {k: v for k, v in {**BOARD, **change}.items() if v is not None}
    r = client.post("/calibrations", files=files[:3], data=form, headers=admin)
    assert r.status_code == 422, r.text
    assert says in r.json()["detail"]
    assert client.get("/calibrations", headers=admin).json() == []
