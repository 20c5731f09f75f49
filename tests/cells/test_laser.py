"""Finding the laser dot among red distractors."""

from __future__ import annotations

import numpy as np
import pytest

from app.cells.core.laser import Spot, find_spots, locate


def test_spot_centroid_is_sub_pixel() -> None:
    y, x = np.mgrid[0:60, 0:80]
    g = np.exp(-((x - 40.3) ** 2 + (y - 21.7) ** 2) / (2 * 1.5**2))
    image = np.full((60, 80, 3), 100.0)
    image[..., 0] += 150 * g
    image[..., 1:] -= 60 * g[..., None]
    [spot] = find_spots(np.clip(image, 0, 255).astype(np.uint8))
    assert spot.u == pytest.approx(40.3, abs=0.1)
    assert spot.v == pytest.approx(21.7, abs=0.1)


def spot_image(peak_red: float, peak_dim: float, *, noise: float = 2.0) -> np.ndarray:
    """A grey 80 × 60 image with a Gaussian red spot (σ 1.5 px) at (40.3, 21.7): R rises by
    ``peak_red`` and G, B fall by ``peak_dim`` at its centre (clipped at 0 and 255)."""
    rng = np.random.default_rng(7)
    y, x = np.mgrid[0:60, 0:80]
    g = np.exp(-((x - 40.3) ** 2 + (y - 21.7) ** 2) / (2 * 1.5**2))
    image = np.full((60, 80, 3), 100.0) + rng.normal(0, noise, (60, 80, 3))
    image[..., 0] += peak_red * g
    image[..., 1:] -= peak_dim * g[..., None]
    return np.clip(np.rint(image), 0, 255).astype(np.uint8)


@pytest.mark.parametrize(
    ("peak_red", "peak_dim", "tolerance", "exposure"),
    [
        # over 100 seeds and sub-pixel positions, error median 0.05, 95th percentile 0.11,
        # most 0.17 px: the noise (σ 2) against a peak excess of 70
        (30.0, 40.0, 0.2, "dim: R peaks at 130, below the fixed R ≥ 150 of before"),
        # median 0.02, most 0.04 px over the same 100
        (500.0, -250.0, 0.1, "so bright that R, G and B all saturate over its core"),
    ],
)
def test_a_dim_and_a_saturated_spot_are_found(
    peak_red: float, peak_dim: float, tolerance: float, exposure: str
) -> None:
    image = spot_image(peak_red, peak_dim)
    if peak_dim < 0:
        assert (image[21, 40] == 255).all()  # a white core: no red excess there
    [spot] = find_spots(image)
    assert spot.u == pytest.approx(40.3, abs=tolerance), exposure
    assert spot.v == pytest.approx(21.7, abs=tolerance), exposure


def test_the_most_intense_spots_are_kept() -> None:
    """A large dull-red patch outweighs the dot in summed excess, not in intensity."""
    image = spot_image(150.0, 60.0)
    image[5:45, 60:78] = (140, 60, 60)  # 720 px of excess 80
    spots = find_spots(image)
    assert spots[0].u == pytest.approx(40.3, abs=0.1)
    assert (spots[1].u, spots[1].v) == (pytest.approx(68.5, abs=0.1), pytest.approx(24.5, abs=0.1))
    assert spots[1].strength > spots[0].strength


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
    # red spots that are not one point in space are no dot (over-exposed views whose dot
    # had vanished gave patches of a red part, matched at 3.8 px)
    with pytest.raises(ValueError, match="do not meet in one point"):
        locate([[Spot(13, 0, 5, 1.0)], [Spot(7, 0, 5, 1.0)], []], tri)
    assert locate([[Spot(11.5, 0, 5, 1.0)], [Spot(8.5, 0, 5, 1.0)], []], tri).pixels[0] == (
        11.5,
        0,
    )
