"""Per-channel statistics against images with known histograms."""

from __future__ import annotations

import numpy as np
import pytest

from app.platform.frames.stats import bounding_box, channel_stats, crop, polygon_pixels


def image_with_histogram(counts: dict[int, int], width: int = 10) -> np.ndarray:
    """A single-channel column laid out from {level: count}, repeated into R, G, B."""
    values = np.concatenate([np.full(n, level, np.uint8) for level, n in counts.items()])
    assert values.size % width == 0
    channel = values.reshape(-1, width)
    return np.repeat(channel[:, :, None], 3, axis=2)


def test_mode_and_mean_known_answer() -> None:
    # 60 × level 100, 30 × level 200, 10 × level 0: mode 100, mean (6000 + 6000) / 100 = 120
    image = image_with_histogram({100: 60, 200: 30, 0: 10})
    stats = channel_stats(image)
    assert stats.pixels == 100
    np.testing.assert_array_equal(stats.modes, [100, 100, 100])
    np.testing.assert_allclose(stats.means, [120.0, 120.0, 120.0], rtol=0, atol=1e-12)
    assert stats.histograms.shape == (3, 256)
    assert stats.histograms[0, 200] == 30


def test_ties_go_to_the_lowest_level() -> None:
    image = image_with_histogram({180: 50, 40: 50})
    np.testing.assert_array_equal(channel_stats(image).modes, [40, 40, 40])


def test_channels_are_independent() -> None:
    image = np.zeros((4, 5, 3), np.uint8)
    image[..., 0], image[..., 1], image[..., 2] = 10, 20, 30
    stats = channel_stats(image)
    np.testing.assert_array_equal(stats.modes, [10, 20, 30])


def test_random_image_matches_numpy() -> None:
    rng = np.random.default_rng(42)
    image = rng.integers(0, 256, (37, 53, 3), dtype=np.uint8)
    stats = channel_stats(image)
    for c in range(3):
        counts = np.bincount(image[..., c].ravel(), minlength=256)
        np.testing.assert_array_equal(stats.histograms[c], counts)
        assert stats.modes[c] == counts.argmax()
        assert stats.means[c] == pytest.approx(image[..., c].mean(), abs=1e-9)


@pytest.mark.parametrize(
    "shape",
    [(480, 640), (700, 800), (1080, 1920), (2, 600_000), (600_000, 1)],
    ids=["small, read interleaved", "one band", "two bands", "wide rows", "a column"],
)
def test_every_size_and_view_matches_numpy(shape: tuple[int, int]) -> None:
    """Small regions are read interleaved, large ones split a band at a time into one
    buffer of planes: each way, and a region cut from a larger image (strided rows), counts
    what ``np.bincount`` counts, on every call."""
    rng = np.random.default_rng(7)
    image = rng.integers(0, 256, (*shape, 3), dtype=np.uint8)
    image[: shape[0] // 2] //= 4  # unlike halves: a band that kept the last one's counts shows
    region = image[1:, 1:] if min(shape) > 1 else image[1:]
    for view in (image, region, image):
        expected = [np.bincount(view[..., c].ravel(), minlength=256) for c in range(3)]
        np.testing.assert_array_equal(channel_stats(view).histograms, expected)


def test_roi() -> None:
    image = np.zeros((10, 10, 3), np.uint8)
    image[2:5, 3:8] = 255
    stats = channel_stats(image, (3, 2, 5, 3))
    assert stats.pixels == 15
    np.testing.assert_array_equal(stats.modes, [255, 255, 255])
    with pytest.raises(ValueError, match="does not lie inside the 10×10 frame"):
        crop(image, (8, 8, 5, 5))


def test_polygon_pixels_are_those_inside() -> None:
    image = np.zeros((100, 120, 3), np.uint8)
    image[..., 0] = np.arange(120)[None, :]  # R = x
    square = ((10, 20), (59, 20), (59, 69), (10, 69))  # 50 × 50 pixels, edges included
    pixels = polygon_pixels(image, square)
    assert pixels.shape == (2500, 1, 3)
    assert pixels[:, 0, 0].min() == 10
    assert pixels[:, 0, 0].max() == 59
    assert bounding_box(square) == (10, 20, 50, 50)
    triangle = ((0, 0), (99, 0), (0, 99))
    # the rasterised right triangle holds about half the 100 × 100 box (edges included)
    assert polygon_pixels(image, triangle).shape[0] == pytest.approx(5050, rel=0.02)
    with pytest.raises(ValueError, match="inside"):
        polygon_pixels(image, ((0, 0), (130, 0), (0, 10)))
