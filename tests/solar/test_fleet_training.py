"""The fleet model's training: the panel test's conformal limit, the not-sure band and the
snow floor chosen on the training photos, the nested figures."""

from __future__ import annotations

from datetime import UTC, datetime

import numpy as np
import pytest

from app.solar.core.fleet import (
    ALL_FEATURES,
    SHAPE_FEATURES,
    UNSURE,
    Head,
    KernelModel,
    Shape,
    pick,
)
from app.solar.services.fleet_training import (
    ANSWERED,
    choose_band,
    conformal_limit,
    fit_fleet,
    shape_model,
)
from app.solar.services.panels import as_core_model
from tests.factories.solar import one_feature_model

NOW = datetime(2026, 6, 1, tzinfo=UTC)
K = len(ALL_FEATURES)


def test_the_conformal_limit_is_the_rank_of_the_held_out_scores() -> None:
    """n = 39 scores 1…39: the ⌈40 · 0.95⌉ = 38th smallest, 38; n = 10: ⌈11 · 0.95⌉ = 11 > n,
    the largest, 10."""
    scores = np.arange(39, 0, -1).astype(float)
    assert conformal_limit(scores) == 38.0
    assert conformal_limit(np.arange(1.0, 11.0)) == 10.0


def test_a_panel_photo_like_the_training_photos_is_called_unlike_them_about_5_percent() -> None:
    """Training and new photos drawn alike (seeded correlated Gaussians, all features): over
    90 training sets of 80 (three seeds' mixes), the share of 400 new photos beyond the shape
    model's limit is about α = 0.05. About, not at most: each photo's distance is held out of
    a fit on the others (a jackknife), whose guarantee is 2α at worst (Barber et al.,
    *Predictive inference with the jackknife+*, Ann. Statist. 49(1), 2021); measured, the
    mean of 30 sets was 0.061, 0.049 and 0.044 for these seeds, each ± 0.005. The bound,
    ± 0.015, is three times the spread of the mean of 90."""
    shares = []
    for seed in (3, 4, 5):
        rng = np.random.default_rng(seed)
        mix = rng.normal(0, 1, (K, K)) / np.sqrt(K)
        for _ in range(30):
            train = rng.normal(0, 1, (80, K)) @ mix
            new = rng.normal(0, 1, (400, K)) @ mix
            stored = shape_model(train, None)
            assert stored is not None
            z = (pick(new, SHAPE_FEATURES) - stored["mean"]) / stored["scale"] - stored["location"]
            distance = np.sqrt(np.einsum("ij,jk,ik->i", z, np.asarray(stored["precision"]), z))
            shares.append(float(np.mean(distance > stored["limit"])))  # Shape.distance, all at once
    assert abs(np.mean(shares) - 0.05) < 0.015


def test_the_distance_is_mahalanobis() -> None:
    """Known answer: standardised by mean 1 and scale 2, located at 0, precision diag(4, 1,
    1, …): a vector 3 on its first shape feature and 1 elsewhere lies at z = (1, 0, …), so
    √(4 · 1²) = 2."""
    n = len(SHAPE_FEATURES)
    shape = Shape(
        mean=np.ones(n),
        scale=np.full(n, 2.0),
        location=np.zeros(n),
        precision=np.diag([4.0] + [1.0] * (n - 1)),
        limit=1.0,
    )
    f = np.ones(K)
    f[ALL_FEATURES.index(SHAPE_FEATURES[0])] = 3.0
    assert shape.distance(f) == pytest.approx(2.0, abs=1e-12)


def test_shape_needs_all_features() -> None:
    assert shape_model(np.zeros((20, 8)), None) is None


class TestBand:
    def test_the_band_whose_answers_are_best_while_answering_enough(self) -> None:
        """20 photos. Those at p 0.35 and 0.62 are the wrong side of 0.5; a band of 0.15
        leaves both out (answering 18 of 20 = 0.9 ≥ ANSWERED), and every answer is right;
        a band of 0.1 keeps the 0.62 (wrong), so 0.15 wins; 0.2 and wider answer fewer than
        80 %, as 5 photos lie within 0.2."""
        p = np.array([0.05] * 8 + [0.95] * 7 + [0.35, 0.62, 0.68, 0.31, 0.66])
        dirty = np.array([False] * 8 + [True] * 7 + [True, False, True, False, True])
        assert ANSWERED == 0.8
        assert choose_band(p, dirty) == 0.15

    def test_the_narrowest_when_every_band_answers_alike(self) -> None:
        p = np.array([0.0] * 10 + [1.0] * 10)
        dirty = p > 0.5
        assert choose_band(p, dirty) == 0.1

    def test_the_narrowest_when_none_answers_enough(self) -> None:
        p = np.full(20, 0.52)
        dirty = np.arange(20) % 2 == 0
        assert choose_band(p, dirty) == 0.1


def test_a_frame_sent_to_brushing_is_doubted_down_to_the_snow_floor() -> None:
    """p(snow) 0.2, below 0.5 − band (0.3): a frame judged dirty (p 0.915) is doubted when
    the training's lowest held-out snow photo had p(snow) 0.15, not when there is no floor;
    a frame judged clean with the same p(snow) opens no brushing and is answered."""
    dirty, clean = np.eye(K)[0] * 2.0, -np.eye(K)[0] * 2.0
    snow = Head(np.zeros(K), float(np.log(0.2 / 0.8)))
    floored = one_feature_model(snow=snow, snow_floor=0.15)
    reason = floored.doubt(dirty)
    assert reason is not None
    assert "not sure the panel is free of snow: p(snow) 0.20" in reason
    assert floored.doubt(clean) is None
    assert one_feature_model(snow=snow).doubt(dirty) is None
    assert one_feature_model(snow=snow, snow_floor=0.25).doubt(dirty) is None
    assert one_feature_model().band == UNSURE


class TestFit:
    def photos(self, seed: int) -> tuple[np.ndarray, list[str]]:
        """Seeded photos whose first 20 features tell clean (−1.5) from dust (+1.5), with noise
        of 1; 6 snow photos far along the next 20; the rest noise."""
        rng = np.random.default_rng(seed)
        x = rng.normal(0, 1, (46, K))
        labels = ["clean"] * 20 + ["dust"] * 20 + ["snow"] * 6
        x[:20, :20] -= 1.5
        x[20:40, :20] += 1.5
        x[40:, 20:40] += 3.0
        return x, labels

    def test_the_nested_figures_and_the_choices_are_kept(self) -> None:
        x, labels = self.photos(0)
        row = fit_fleet(x, labels, now=NOW)
        assert row.cv_balanced_accuracy is not None
        assert row.cv_balanced_accuracy > 0.9
        assert row.cv_sure_balanced_accuracy is not None
        assert row.cv_sure_balanced_accuracy >= row.cv_balanced_accuracy - 0.05
        assert row.cv_answered is not None
        assert 0.5 <= row.cv_answered <= 1.0
        assert (row.n_farm, row.cv_without_farm) == (0, None)
        model = as_core_model(row)
        assert isinstance(model, KernelModel)
        assert model.band in (0.1, 0.15, 0.2, 0.25, 0.3)
        assert model.shape is not None
        assert model.snow is not None
        assert model.snow_floor is not None
        assert 0.0 < model.snow_floor < 1.0
        assert model.condition(x[43]) == "snow"

    def test_what_the_farms_labels_did(self) -> None:
        """The farm's 10 frames carry the only clear clean and dust: without them the
        remaining photos' labels are a coin toss, so the figure without them is lower."""
        x, labels = self.photos(1)
        rng = np.random.default_rng(2)
        noise = rng.normal(0, 1, (30, K))
        mixed = np.vstack([noise, x[:5], x[20:25]])
        names = ["clean"] * 15 + ["dust"] * 15 + ["clean"] * 5 + ["dust"] * 5
        farm = [False] * 30 + [True] * 10
        row = fit_fleet(mixed, names, now=NOW, farm=farm)
        assert row.n_farm == 10
        assert row.cv_without_farm is not None
        assert row.cv_balanced_accuracy is not None
        assert row.cv_without_farm < row.cv_balanced_accuracy
