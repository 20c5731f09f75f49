"""Fleet-model features and the logistic model."""

from __future__ import annotations

from collections.abc import Callable
from datetime import UTC, datetime
from typing import Any

import cv2
import numpy as np
import pytest
from fastapi.testclient import TestClient
from sklearn.svm import SVC

from app.platform.http.errors import Unprocessable
from app.solar.core.fleet import (
    ALL_FEATURES,
    FEATURES,
    Head,
    KernelModel,
    LogisticModel,
    features,
    lbp_histogram,
    reduce,
)
from app.solar.services.fleet_training import fit_fleet, fold_interval
from tests.factories import bearer
from tests.factories.air import sky_jpeg
from tests.factories.solar import (
    CLEAN_RGB,
    SAND,
    clean_set,
    one_feature_model,
    panel,
    panel_jpeg,
    post_frame,
    status,
    train,
    train_fleet,
)


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


@pytest.mark.parametrize(("points", "radius"), [(8, 1), (24, 3)])
def test_lbp_histogram_known_answers(points: int, radius: int) -> None:
    # uniform rotation-invariant LBP (Ojala et al. 2002): on a flat image every neighbour
    # equals the centre, s(0) = 1 for all P, so every pixel at least ⌈R⌉ from the border takes
    # the code P
    flat = np.full((40, 40), 90, np.uint8)
    hist = lbp_histogram(flat, points, radius)
    assert hist.shape == (points + 2,)
    assert hist[points] == pytest.approx(1.0, abs=1e-12)
    # a lone bright pixel is brighter than all its neighbours: code 0, one pixel of (40 − 2R)²
    dot = flat.copy()
    dot[20, 20] = 200
    inner = (40 - 2 * radius) ** 2
    assert lbp_histogram(dot, points, radius)[0] == pytest.approx(1 / inner, abs=1e-12)


@pytest.mark.parametrize(("points", "radius"), [(8, 1), (24, 3)])
def test_lbp_histogram_is_scikit_images(points: int, radius: int) -> None:
    """The reference: scikit-image's ``local_binary_pattern(…, "uniform")`` over the same
    pixels (those ⌈R⌉ from the border), on a seeded textured image. The two interpolate the
    circle's points alike; a few pixels whose neighbour ties the centre to within rounding
    may differ, so each share within 0.01 (of ~4,000 pixels)."""
    from skimage.feature import local_binary_pattern

    rng = np.random.default_rng(4)
    grey = cv2.GaussianBlur(rng.integers(0, 256, (70, 64)).astype(np.uint8), (0, 0), 1.5)
    codes = local_binary_pattern(grey, points, radius, "uniform").astype(int)
    r = int(np.ceil(radius))
    inner = codes[r:-r, r:-r]
    expected = np.bincount(inner.ravel(), minlength=points + 2) / inner.size
    np.testing.assert_allclose(lbp_histogram(grey, points, radius), expected, atol=0.01)


def test_the_coarse_lbp_scale_is_a_histogram_among_the_features() -> None:
    f = dict(zip(ALL_FEATURES, features(panel()), strict=True))
    coarse = [f[f"lbp24r3_{k}"] for k in range(26)]
    assert sum(coarse) == pytest.approx(1.0, abs=1e-9)
    assert sum(f[f"lbp_{k}"] for k in range(10)) == pytest.approx(1.0, abs=1e-9)


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
    # p = σ(1.5) = 0.82: sure; at f = (0, 2), z = −0.5 + 0.5 = 0, p = 0.5: not sure
    assert m.doubt([3.0, 2.0]) is None
    reason = m.doubt([0.0, 2.0])
    assert reason is not None
    assert "not sure: p(needs cleaning) 0.50" in reason


def test_a_model_of_fewer_features_reads_its_own_from_the_full_vector() -> None:
    # a model stored before the coarse LBP scale names 47 features; frames now carry 73
    older = ALL_FEATURES[:47]
    assert not any(n.startswith("lbp24r3") for n in older)
    rng = np.random.default_rng(3)
    m = LogisticModel(
        feature_names=older,
        mean=rng.normal(0, 1, 47),
        scale=rng.uniform(0.5, 2, 47),
        coef=rng.normal(0, 0.3, 47),
        intercept=0.1,
    )
    full = features(panel())
    assert float(m.probability(full)) == pytest.approx(float(m.probability(full[:47])), abs=1e-15)


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


class TestDoubt:
    def test_a_probability_near_the_threshold_is_not_sure(self) -> None:
        model = one_feature_model()
        k = len(ALL_FEATURES)
        undecided, dirty = np.zeros(k), np.eye(k)[0] * 2.0
        assert float(model.probability(undecided)) == pytest.approx(0.5)
        reason = model.doubt(undecided)
        assert reason is not None
        assert "not sure: p(needs cleaning) 0.50" in reason
        # exp(−0.5·1) − exp(−0.5·9) = 0.5954, ·4 → 2.38: p = 0.915, far from 0.5
        assert float(model.probability(dirty)) == pytest.approx(
            1 / (1 + np.exp(-4 * (np.exp(-0.5) - np.exp(-4.5)))), rel=1e-12
        )
        assert model.doubt(dirty) is None

    def test_the_band_is_unsure_on_either_side(self) -> None:
        """p within UNSURE (0.2) of 0.5 is doubted, beyond it not: the band's edges."""
        model = one_feature_model()
        k = len(ALL_FEATURES)
        e0 = np.eye(k)[0]

        def p_at(t: float) -> float:
            return float(model.probability(e0 * t))

        from scipy.optimize import brentq

        edge = brentq(lambda t: p_at(t) - 0.7, 0.0, 1.0)  # p rises from 0.5 to 0.97 on [0, 1]
        assert model.doubt(e0 * (edge - 1e-3)) is not None
        assert model.doubt(e0 * (edge + 1e-3)) is None
        assert model.doubt(-e0 * (edge - 1e-3)) is not None  # p just above 0.3
        assert model.doubt(-e0 * (edge + 1e-3)) is None

    def test_a_frame_unlike_the_training_photos_is_not_judged(self) -> None:
        k = len(ALL_FEATURES)
        training = np.random.default_rng(0).normal(0, 1, (30, k))
        model = one_feature_model(training=training, reach=2.0)
        far = np.eye(k)[0] * 2.0 + 50.0  # nowhere near what was learnt
        reason = model.doubt(far)
        assert reason is not None
        assert reason.startswith("unlike every photo")
        sure = np.eye(k)[0] * 2.0  # p = 0.915
        assert model.doubt(sure) is not None  # 7 units from every random training photo
        beside = one_feature_model(training=np.vstack([training, sure + 0.1]), reach=2.0)
        assert beside.doubt(sure) is None  # 0.1·√k = 0.69 from one: within reach

    def test_a_model_without_its_training_photos_checks_only_the_band(self) -> None:
        k = len(ALL_FEATURES)
        model = one_feature_model()
        assert model.doubt(np.eye(k)[0] * 2.0) is None
        far = model.doubt(np.eye(k)[0] * 2.0 + 50.0)  # far from both support vectors: p = 0.5
        assert far is not None
        assert far.startswith("the fleet model is not sure")


def test_a_frame_that_may_be_snow_is_not_judged_for_brushing() -> None:
    """p(snow) 0.4: not snow by the head, but within UNSURE of it, so not a dirty verdict
    either (brushing snow cleans nothing); p(snow) 0.2 leaves the dirty verdict standing."""
    k = len(ALL_FEATURES)
    dirty = np.eye(k)[0] * 2.0  # p(needs cleaning) 0.915
    maybe = one_feature_model(snow=Head(np.zeros(k), float(np.log(0.4 / 0.6))))
    reason = maybe.doubt(dirty)
    assert reason is not None
    assert "not sure the panel is free of snow: p(snow) 0.40" in reason
    assert maybe.condition(dirty) != "snow"
    clear = one_feature_model(snow=Head(np.zeros(k), float(np.log(0.2 / 0.8))))
    assert clear.doubt(dirty) is None


class TestGroups:
    """Photos of one panel are near-duplicates: folds that split a panel test the model on
    panels it trained on."""

    def photos(self, seed: int) -> tuple[np.ndarray, list[str], list[str]]:
        """12 panels, 6 photos each around the panel's own point (seeded), labelled by panel
        at random: the features say which panel, never whether it is clean."""
        rng = np.random.default_rng(seed)
        centres = rng.normal(0, 1, (12, 8))
        x = np.repeat(centres, 6, axis=0) + rng.normal(0, 0.05, (72, 8))
        label = rng.permutation(["clean"] * 6 + ["dust"] * 6)
        return x, list(np.repeat(label, 6)), [f"p{i}" for i in range(12) for _ in range(6)]

    def test_grouped_folds_say_the_model_has_learnt_nothing(self) -> None:
        """Over 5 seeds: without groups the reported accuracy is near 1 (a fold always holds
        the panel's other photos); with them it is that of a guess, 0.5 ± 0.2."""
        now = datetime(2026, 6, 1, tzinfo=UTC)
        flattered, grouped = [], []
        for seed in range(5):
            x, labels, groups = self.photos(seed)
            flattered.append(fit_fleet(x, labels, now=now).cv_balanced_accuracy)
            model = fit_fleet(x, labels, now=now, groups=groups)
            assert model.n_groups == 12
            grouped.append(model.cv_balanced_accuracy)
        assert min(flattered) > 0.9
        assert abs(np.mean(grouped) - 0.5) < 0.2

    def test_too_few_groups_of_a_class_are_refused(self) -> None:
        x, labels, groups = self.photos(0)
        clean = [g for g, label in zip(groups, labels, strict=True) if label == "clean"]
        merged = [("one" if g in clean[:18] else g) for g in groups]  # 3 clean panels → 1
        with pytest.raises(Unprocessable, match="the photos clean come from 4 groups"):
            fit_fleet(x, labels, now=datetime(2026, 6, 1, tzinfo=UTC), groups=merged)


def test_the_fold_interval_is_students() -> None:
    """Known answer: scores 0.8, 0.85, 0.9, 0.95, 1.0 have mean 0.9, s = 0.0790569 and
    t(0.975, 4) = 2.776445 (tables), so ±0.0981623; clipped at 1."""
    low, high = fold_interval(np.array([0.8, 0.9, 1.0, 0.85, 0.95]))
    assert low == pytest.approx(0.9 - 0.0981623, abs=1e-6)
    assert high == pytest.approx(0.9 + 0.0981623, abs=1e-6)
    assert fold_interval(np.array([1.0, 1.0, 0.9, 1.0, 1.0]))[1] == 1.0


class TestFleetModel:
    def test_train_and_judge_a_panel_without_baseline(
        self, client: TestClient, admin: dict[str, str], farm: Any
    ) -> None:
        r = train_fleet(client, admin)
        assert r.json()["cv_balanced_accuracy"] == 1.0
        assert r.json()["band"] in (0.1, 0.15, 0.2, 0.25, 0.3)
        assert r.json()["snow_floor"] is None  # no snow photos: no snow head
        assert r.json()["cv_answered"] == 1.0  # 8 and 8 far apart: every one answered
        assert status(client, admin)["state"] == "unknown"
        v = post_frame(client, farm, CLEAN_RGB)
        assert (v["method"], v["clean"]) == ("fleet", True)
        v = post_frame(client, farm, 0.5 * CLEAN_RGB + 0.5 * SAND)
        assert (v["method"], v["clean"]) == ("fleet", False)
        assert v["p_dirty"] > 0.5

    def test_a_view_without_a_baseline_is_judged_by_the_fleet_model(
        self, client: TestClient, admin: dict[str, str], farm: Any
    ) -> None:
        """c1's view of p1 has a baseline; c2, added later with another view, has none yet. Its
        frames got `clean: null` though a fleet model could judge them, as it judges panels
        with no baseline at all."""
        train_fleet(client, admin)
        assert train(client, admin, clean_set(8)).status_code == 201  # c1's view: the whole frame
        # most of the frame: features like those of the fleet's whole-frame photos
        c2 = {"id": "c2", "kind": "panel", "panel_id": "p1", "roi": [0, 0, 160, 112]}
        r = client.post("/cameras", json=c2, headers=admin)
        assert r.status_code == 201, r.text
        side = {**bearer(r.json()["token"]), "Content-Type": "image/jpeg"}

        v = post_frame(client, farm, CLEAN_RGB)  # c1: its view's baseline
        assert (v["method"], v["clean"]) == ("baseline", True), v
        for rgb, clean in ((CLEAN_RGB, True), (0.5 * CLEAN_RGB + 0.5 * SAND, False)):
            farm["clock"].advance(minutes=10)
            r = client.post("/cameras/c2/frames", content=panel_jpeg(rgb, seed=7), headers=side)
            assert r.status_code == 201, r.text
            v = r.json()["verdict"]
            assert (v["method"], v["clean"], v["baseline_id"]) == ("fleet", clean, None), v

    def test_a_view_of_no_panel_gets_no_verdict(
        self, client: TestClient, admin: dict[str, str], farm: Any
    ) -> None:
        """A camera turned to the street (smooth sky above, a dark street below) is unlike the
        panel photos the model learnt from: no verdict and no task, the reason given, however
        sure its probability looks."""
        train_fleet(client, admin)
        c2 = {"id": "c2", "kind": "panel", "panel_id": "p1"}
        r = client.post("/cameras", json=c2, headers=admin)
        assert r.status_code == 201, r.text
        side = {**bearer(r.json()["token"]), "Content-Type": "image/jpeg"}
        for k in range(4):  # past the debounce, had the frames been judged dirty
            farm["clock"].advance(minutes=10)
            r = client.post("/cameras/c2/frames", content=sky_jpeg(3.0, seed=k), headers=side)
            assert r.status_code == 201, r.text
            v = r.json()["verdict"]
            assert (v["method"], v["clean"], v["condition"]) == ("fleet", None, None), v
            assert v["reason"].startswith("unlike the panel photos the fleet model learnt from")
        s = status(client, admin)
        assert s["state"] == "unknown", s
        assert client.get("/cleaning/tasks", headers=admin).json() == []

    def farm_photos(self, panels: int) -> tuple[list[Any], list[str], list[str]]:
        """Each panel photographed clean and half covered in sand (seeded)."""
        rng = np.random.default_rng(6)
        files, labels, groups = [], [], []
        for i in range(panels):
            c = CLEAN_RGB + rng.normal(0, 6, 3)
            for name, rgb in (("clean", c), ("dust", 0.5 * c + 0.5 * SAND)):
                photo = panel_jpeg(rgb, seed=10 * i + len(files))
                files.append(("files", (f"{name}{i}.jpg", photo, "image/jpeg")))
                labels.append(name)
                groups.append(f" row-A-{i} ")  # as cut from a CSV: stripped
        return files, labels, groups

    def test_photos_grouped_by_panel(self, client: TestClient, admin: dict[str, str]) -> None:
        files, labels, groups = self.farm_photos(8)
        data = {"labels": labels, "groups": groups}
        r = client.post("/fleet/model", files=files, data=data, headers=admin)
        assert r.status_code == 201, r.text
        assert r.json()["n_groups"] == 8
        assert r.json()["cv_balanced_accuracy"] == 1.0
        r = client.post("/fleet/model", files=files, data={"labels": labels}, headers=admin)
        assert r.status_code == 201, r.text
        assert r.json()["n_groups"] is None

    @pytest.mark.parametrize(
        ("regroup", "code"),
        [
            (lambda g: g[1:], "groups_mismatch"),
            (lambda g: [f"row-{i % 4}" for i in range(len(g))], "too_few_groups"),
            (lambda g: [*g[:3], " ", *g[4:]], "empty_group"),
        ],
    )
    def test_groups_that_cannot_fold_are_refused_and_nothing_stored(
        self,
        client: TestClient,
        admin: dict[str, str],
        regroup: Callable[[list[str]], list[str]],
        code: str,
    ) -> None:
        files, labels, groups = self.farm_photos(8)
        data = {"labels": labels, "groups": regroup(groups)}
        r = client.post("/fleet/model", files=files, data=data, headers=admin)
        assert r.status_code == 422, r.text
        assert r.json()["code"] == code
        assert client.get("/fleet/model", headers=admin).status_code == 404

    def test_labels_must_match_files(self, client: TestClient, admin: dict[str, str]) -> None:
        files = [("files", ("a.jpg", panel_jpeg(CLEAN_RGB), "image/jpeg"))]
        r = client.post("/fleet/model", files=files, data={"labels": "shiny"}, headers=admin)
        assert r.status_code == 422
        assert client.get("/fleet/model", headers=admin).status_code == 404


def test_the_histogram_percentile_is_numpys() -> None:
    """The colour percentiles come from a histogram; the reference is ``np.percentile``'s
    default (linear between order statistics), on seeded planes of odd and even sizes."""
    from app.solar.core.fleet import _percentile

    rng = np.random.default_rng(0)
    for n in (1, 7, 100, 4097):
        plane = rng.integers(0, 256, n).astype(np.uint8)
        for q in (0, 10, 50, 90, 100):
            assert _percentile(plane, q) == pytest.approx(np.percentile(plane, q), abs=1e-9)
