"""Calibration: a synthetic rig with exact ground truth, and OpenCV's sample set."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from app.core.calibration import CalibrationError, board_points, calibrate

K_TRUE = np.array([[800.0, 0.0, 320.0], [0.0, 790.0, 240.0], [0.0, 0.0, 1.0]])
DIST_TRUE = np.array([-0.2, 0.05, 0.001, -0.0005, 0.0])


def synthetic_views(n: int, seed: int = 0) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """The board seen from n poses through a known camera (noise-free projections)."""
    rng = np.random.default_rng(seed)
    obj = board_points(9, 6, 25.0)
    objs, imgs = [], []
    for _ in range(n):
        rvec = rng.normal(0, 0.3, 3)
        tvec = np.array([-100.0, -60.0, 600.0]) + rng.normal(0, 40, 3)
        pts, _ = cv2.projectPoints(obj, rvec, tvec, K_TRUE, DIST_TRUE)
        objs.append(obj)
        imgs.append(pts.astype(np.float32))
    return objs, imgs


def test_recovers_a_known_camera() -> None:
    objs, imgs = synthetic_views(12)
    c = calibrate(objs, imgs, (640, 480))
    np.testing.assert_allclose(c.K, K_TRUE, rtol=1e-4, atol=0.05)
    np.testing.assert_allclose(c.dist, DIST_TRUE, atol=2e-3)
    assert c.rms < 1e-3
    assert len(c.per_view_rms) == 12
    assert set(c.std) == {"fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3"}


def test_too_few_views() -> None:
    objs, imgs = synthetic_views(2)
    with pytest.raises(CalibrationError, match="at least 3"):
        calibrate(objs, imgs, (640, 480))
