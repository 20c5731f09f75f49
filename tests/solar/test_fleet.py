"""Fleet-model features and the logistic model."""

from __future__ import annotations

import numpy as np
import pytest

from app.solar.core.fleet import FEATURES, LogisticModel, features, reduce
from tests.factories import panel


def dusty(image: np.ndarray, amount: float) -> np.ndarray:
    """Dust as a haze: blend towards a sandy grey."""
    sand = np.array([190.0, 180.0, 160.0])
    return np.clip((1 - amount) * image + amount * sand, 0, 255).astype(np.uint8)


def test_shape_and_names() -> None:
    f = features(panel())
    assert f.shape == (len(FEATURES),)
    assert np.isfinite(f).all()


def test_dust_lifts_the_dark_channel_and_whiteness() -> None:
    clean = dict(zip(FEATURES, features(panel()), strict=True))
    dirty = dict(zip(FEATURES, features(dusty(panel(), 0.5)), strict=True))
    assert dirty["dark_mean"] > clean["dark_mean"] + 30
    assert dirty["whiteness"] > clean["whiteness"] + 0.1
    assert dirty["blue_fraction"] < clean["blue_fraction"]


def test_reduce_samples_to_at_most_128() -> None:
    big = np.zeros((1080, 1920, 3), np.uint8)
    assert max(reduce(big).shape[:2]) <= 128
    small = np.zeros((100, 90, 3), np.uint8)
    assert reduce(small) is small


@pytest.mark.parametrize("shape", [(1, 4000), (4000, 1), (3, 1000), (1, 1)], ids=str)
def test_a_thin_image_keeps_a_line_of_pixels(shape: tuple[int, int]) -> None:
    # the sampling started beyond a short side: an empty image, and a 500 on a panel frame
    image = np.full((*shape, 3), 120, np.uint8)
    small = reduce(image)
    assert small.size > 0
    assert max(small.shape[:2]) <= 128
    assert np.isfinite(features(image)).all()


def test_logistic_probability() -> None:
    m = LogisticModel(
        feature_names=("a", "b"),
        mean=np.array([1.0, 2.0]),
        scale=np.array([2.0, 4.0]),
        coef=np.array([1.0, -1.0]),
        intercept=0.5,
    )
    # z = (3 − 1)/2 · 1 + (2 − 2)/4 · (−1) + 0.5 = 1.5
    assert float(m.probability([3.0, 2.0])) == pytest.approx(1 / (1 + np.exp(-1.5)), rel=1e-12)
