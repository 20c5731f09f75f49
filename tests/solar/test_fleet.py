"""Fleet-model features and the logistic model."""

from __future__ import annotations

import numpy as np
import pytest
from sklearn.svm import SVC

from app.solar.core.fleet import (
    ALL_FEATURES,
    FEATURES,
    Head,
    KernelModel,
    LogisticModel,
    features,
    reduce,
)
from tests.factories import panel


def dusty(image: np.ndarray, amount: float) -> np.ndarray:
    """Dust as a haze: blend towards a sandy grey."""
    sand = np.array([190.0, 180.0, 160.0])
    return np.clip((1 - amount) * image + amount * sand, 0, 255).astype(np.uint8)


def test_shape_and_names() -> None:
    f = features(panel())
    assert f.shape == (len(ALL_FEATURES),)
    assert ALL_FEATURES[: len(FEATURES)] == FEATURES
    assert np.isfinite(f).all()


def test_dust_lifts_the_dark_channel_and_whiteness() -> None:
    clean = dict(zip(ALL_FEATURES, features(panel()), strict=True))
    dirty = dict(zip(ALL_FEATURES, features(dusty(panel(), 0.5)), strict=True))
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


def test_the_kernel_model_decides_as_scikit_learn_does() -> None:
    """KernelModel's decision is SVC's decision_function, from the fitted model's public
    attributes (support vectors, dual coefficients, intercept, γ), on standardised features."""
    rng = np.random.default_rng(3)
    k = len(ALL_FEATURES)
    x = rng.normal(0, 1, (60, k))
    y = x[:, 0] + 0.5 * x[:, 3] ** 2 > 0.4
    mean, scale = rng.normal(0, 1, k), rng.uniform(0.5, 2, k)
    svm = SVC(C=3.0, gamma=1.0 / k).fit(x, y)
    model = KernelModel(
        feature_names=ALL_FEATURES,
        mean=mean,
        scale=scale,
        support=svm.support_vectors_,
        dual=svm.dual_coef_[0],
        intercept=float(svm.intercept_[0]),
        gamma=1.0 / k,
        platt=(2.0, -0.5),
        snow=Head(np.eye(k)[1], -10.0),
    )
    raw = rng.normal(0, 1, (20, k)) * scale + mean
    np.testing.assert_allclose(
        model.decision(raw), svm.decision_function((raw - mean) / scale), rtol=1e-9, atol=1e-12
    )
    p = model.probability(raw)
    np.testing.assert_allclose(p, 1 / (1 + np.exp(-(2.0 * model.decision(raw) - 0.5))))
    snowy = raw[0].copy()
    snowy[1] = mean[1] + 20 * scale[1]  # the snow head: σ(z₁ − 10) > 0.5
    assert model.condition(snowy) == "snow"
    assert model.condition(raw[1]) in ("clean", "dirty")
