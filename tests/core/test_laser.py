"""Finding the laser dot among red distractors."""

from __future__ import annotations

import numpy as np
import pytest

from app.core.laser import Spot, find_spots, locate


def test_spot_centroid_is_sub_pixel() -> None:
    y, x = np.mgrid[0:60, 0:80]
    g = np.exp(-((x - 40.3) ** 2 + (y - 21.7) ** 2) / (2 * 1.5**2))
    image = np.full((60, 80, 3), 100.0)
    image[..., 0] += 150 * g
    image[..., 1:] -= 60 * g[..., None]
    [spot] = find_spots(np.clip(image, 0, 255).astype(np.uint8))
    assert spot.u == pytest.approx(40.3, abs=0.1)
    assert spot.v == pytest.approx(21.7, abs=0.1)


def test_grey_and_white_are_not_spots() -> None:
    image = np.full((20, 20, 3), 250, np.uint8)
    assert find_spots(image) == []


def test_locate_picks_the_consistent_combination() -> None:
    # a triangulator whose error is the distance of each view's u from 10
    def tri(obs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        err = np.sqrt(np.nanmean((obs[..., 0] - 10.0) ** 2, axis=1))
        return np.zeros((len(obs), 3)), err

    cands = [[Spot(10, 0, 5, 1.0), Spot(50, 0, 5, 2.0)], [Spot(11, 0, 5, 1.0)], []]
    dot = locate(cands, tri)
    assert dot.pixels == [(10, 0), (11, 0), None]
    with pytest.raises(ValueError, match=r"camera\(s\) 2, 3"):
        locate([[Spot(1, 1, 1, 1.0)], [], []], tri)
