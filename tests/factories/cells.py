"""Robot-cell cases: the cross rig, rendered checkerboard views, calibrations."""

from __future__ import annotations

import json
from typing import Any

import cv2
import numpy as np
from fastapi.testclient import TestClient

from app.cells.core import hand_eye
from app.cells.core.triangulation import CrossRig, View
from tests.cells.scenes import checkerboard_photo

K_RENDER = np.array([[800.0, 0.0, 320.0], [0.0, 800.0, 240.0], [0.0, 0.0, 1.0]])


RIG = CrossRig(f=800.0, ax=0.30, ay=0.20, cx=320.0, cy=240.0)


def points(n: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return np.column_stack(
        [rng.uniform(-0.5, 0.5, n), rng.uniform(-0.4, 0.4, n), rng.uniform(1.0, 5.0, n)]
    )


def calibrated_views() -> list[View]:
    k = np.array([[800.0, 0, 320], [0, 800, 240], [0, 0, 1]])
    dist = np.array([-0.1, 0.01, 0.0, 0.0, 0.0])
    views = []
    for i in range(4):
        r = cv2.Rodrigues(np.radians([0.0, (i - 1.5) * 8, 0.0]))[0]
        centre = np.array([(i - 1.5) * 0.3, 0.05 * i, 0.0])
        views.append(View(k, dist, r, -r @ centre))
    return views


def corner_error(found: np.ndarray, truth: np.ndarray) -> float:
    """Largest distance between matched corners, over the rotations of the found cycle."""
    if found.shape != truth.shape:
        return float("inf")
    return min(
        float(np.linalg.norm(np.roll(found, -k, axis=0) - truth, axis=1).max())
        for k in range(len(found))
    )


def rendered_board(width: int, height: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """A 9×6-corner board (40 px squares, a white margin) warped in perspective onto a grey
    width × height image, rendered at 4× and area-averaged down; and its 54 inner corners in
    the image [px, pixel centres at integers], exact by construction."""
    sq = 40
    board = np.kron((np.indices((7, 10)).sum(0) % 2) * 255, np.ones((sq, sq))).astype(np.uint8)
    board = cv2.copyMakeBorder(board, sq, sq, sq, sq, cv2.BORDER_CONSTANT, value=255)
    h, w = board.shape
    src = np.float32([[0, 0], [w, 0], [w, h], [0, h]])
    dst = np.float32(
        [[0.2, 0.15], [0.8, 0.2], [0.75, 0.85], [0.25, 0.8]] * np.array([width, height])
    )
    m = cv2.getPerspectiveTransform(src, dst)
    big = cv2.warpPerspective(
        board, np.diag([4.0, 4.0, 1.0]) @ m, (4 * width, 4 * height), borderValue=128
    )
    image = cv2.resize(big, (width, height), interpolation=cv2.INTER_AREA)
    image = cv2.add(image, np.random.default_rng(seed).integers(0, 6, image.shape, np.uint8))
    # an inner corner lies between board pixels: at sq·k − 0.5 in pixel-centre coordinates; a
    # 4× render area-averaged down moves pixel centres by −3/8
    corners = np.array(
        [[sq * (2 + i) - 0.5, sq * (2 + j) - 0.5] for j in range(6) for i in range(9)],
        np.float32,
    )
    truth = cv2.perspectiveTransform(corners.reshape(-1, 1, 2), m).reshape(-1, 2) - 0.375
    return image, truth


def rig_camera(client: TestClient, admin: dict[str, str]) -> dict[str, str]:
    cam = client.post("/cameras", json={"id": "c", "kind": "rig"}, headers=admin).json()
    return {"Authorization": f"Bearer {cam['token']}", "Content-Type": "image/jpeg"}


def rendered_views(
    n: int,
    *,
    size: tuple[int, int] = (640, 480),
    k: np.ndarray = K_RENDER,
    seed: int = 0,
    noise_seed: int | None = None,
    quality: int = 95,
) -> list[bytes]:
    """JPEGs of the 9 × 6 board at n poses drawn from ``seed`` through a known camera
    (tests/core/scenes), with sensor noise drawn from ``noise_seed`` (default: ``seed``)."""
    rng = np.random.default_rng(seed)
    noise = seed if noise_seed is None else noise_seed
    out = []
    centre = np.array([100.0, 62.5, 0.0])  # of the 9 × 6 board of 25 mm squares
    for i in range(n):
        rvec = rng.normal(0, 0.3, 3)
        r = cv2.Rodrigues(rvec)[0]
        # turned about its centre, 60 cm ahead, ±3 cm aside: the whole board in the frame
        tvec = -r @ centre + np.array([0.0, 0.0, 600.0]) + rng.normal(0, [30, 30, 60])
        image = checkerboard_photo(k, rvec, tvec, size, seed=noise + i)
        out.append(cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, quality])[1].tobytes())
    return out


def upload(
    client: TestClient, admin: dict[str, str], images: list[tuple[str, bytes]]
) -> tuple[int, dict[str, Any]]:
    r = client.post(
        "/calibrations",
        files=[("files", (name, data, "image/jpeg")) for name, data in images],
        data={"pattern_cols": "9", "pattern_rows": "6", "square_size": "25"},
        headers=admin,
    )
    return r.status_code, r.json()


# --- hand-eye: a camera fixed in a robot's base, the board on its flange -------------------

SQUARE = 0.03  # m: the 9 × 6 board of 30 mm squares
CENTRE = np.array([4 * SQUARE, 2.5 * SQUARE, 0.0])
# eye to hand: the camera fixed in the base, looking back and down at the robot; the board on
# the flange, 10 cm out along its axis
CAMERA_IN_BASE = hand_eye.rigid(cv2.Rodrigues(np.array([2.2, 0.1, -0.3]))[0], np.r_[0.9, 0.2, 0.7])
BOARD_ON_FLANGE = hand_eye.rigid(cv2.Rodrigues(np.array([0.0, 0.1, 0.2]))[0], np.r_[0.0, 0.02, 0.1])


def board_poses(n: int, seed: int) -> list[np.ndarray]:
    """Camera ← board: turned by ≈ 17° about random axes through its centre, 0.6 m ahead."""
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(n):
        r = cv2.Rodrigues(rng.normal(0, 0.3, 3))[0]
        t = -r @ CENTRE + np.r_[0.0, 0.0, 0.6] + rng.normal(0, [0.03, 0.03, 0.05])
        out.append(hand_eye.rigid(r, t))
    return out


def flange_of(board_in_camera: np.ndarray) -> np.ndarray:
    """Base ← flange that puts the board there: F⁻¹ X C = Y, so F = X C Y⁻¹."""
    return CAMERA_IN_BASE @ board_in_camera @ hand_eye.inverse(BOARD_ON_FLANGE)


def angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.degrees(np.linalg.norm(cv2.Rodrigues(a[:3, :3].T @ b[:3, :3])[0])))


def pose_json(f: np.ndarray) -> str:
    return json.dumps({"rotation": f[:3, :3].tolist(), "translation": f[:3, 3].tolist()})


def render(cs: list[np.ndarray], size: tuple[int, int] = (1280, 960)) -> list[bytes]:
    """PNGs of the 9 × 6 board of 30 mm at camera ← board poses ``cs``, through K_RENDER's
    camera scaled to ``size`` (the 640 × 480 camera at 1280 × 960 by default)."""
    scale = size[0] / 640
    k = K_RENDER * np.array([[scale], [scale], [1.0]])
    out = []
    for i, c in enumerate(cs):
        rvec = cv2.Rodrigues(c[:3, :3])[0].ravel()
        image = checkerboard_photo(k, rvec, c[:3, 3], size, square=SQUARE, seed=i)
        out.append(cv2.imencode(".png", image)[1].tobytes())
    return out


def charuco_photo(
    k: np.ndarray,
    rvec: np.ndarray,
    tvec: np.ndarray,
    size: tuple[int, int],
    board: Any,
    *,
    seed: int = 0,
) -> np.ndarray:
    """OpenCV's ChArUco ``board`` at pose (rvec, tvec) of a distortion-free pinhole camera
    ``k`` on a grey image, as ``checkerboard_photo`` renders a checkerboard: the board's
    texture (40 px a square, a square's margin) through the plane's homography at 4×, area-
    averaged down, with noise. Board point (X, Y, 0) is where ``getChessboardCorners`` puts it
    (the board's outer corner at the origin)."""
    from tests.cells.scenes import finish

    sx, sy = board.getChessboardSize()
    px = 40
    texture = board.generateImage((sx * px + 2 * px, sy * px + 2 * px), marginSize=px)
    r = cv2.Rodrigues(np.asarray(rvec, np.float64))[0]
    plane = k @ np.column_stack([r[:, 0], r[:, 1], np.asarray(tvec, np.float64)])
    s = board.getSquareLength() / px
    # texture pixel centre (u, v) → board (X, Y): the board starts at the margin's inner edge
    to_board = np.array([[s, 0, -(px - 0.5) * s], [0, s, -(px - 0.5) * s], [0, 0, 1]])
    up = np.array([[4.0, 0, 1.5], [0, 4.0, 1.5], [0, 0, 1]])
    big = cv2.warpPerspective(
        texture, up @ plane @ to_board, (4 * size[0], 4 * size[1]), borderValue=128
    )
    image = cv2.resize(big, size, interpolation=cv2.INTER_AREA).astype(np.float64)
    return finish(image, noise=1.0, blur=0.0, seed=seed)
