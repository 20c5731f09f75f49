"""Chapter 5 against direct computations (scipy) and synthetic known answers."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from app.platform.frames.stats import channel_stats
from app.stats.hotelling import (
    QUANTISATION_VARIANCE,
    BaselineError,
    classify,
    f_critical,
    fit_baseline,
    gamma_parameters,
    misclassification,
    two_sample_t2,
)

RNG = np.random.default_rng(20240521)
# a clean panel's modes: R 56, G 60, B 84 (dissertation, chapter 5 §III, Figure 5.3a)
CLEAN_MEAN = np.array([56.0, 60.0, 84.0])
CLEAN_COV = np.array([[4.0, 2.0, 1.0], [2.0, 5.0, 1.5], [1.0, 1.5, 6.0]])


def clean_modes(n: int, seed: int = 1) -> np.ndarray:
    return np.random.default_rng(seed).multivariate_normal(CLEAN_MEAN, CLEAN_COV, size=n)


class TestGamma:
    def test_known_gamma_recovered_from_its_mode_and_mean(self) -> None:
        # Gamma(α = 5, β = 10): mean αβ = 50 (5.6), mode (α − 1)β = 40 (5.7)
        g = gamma_parameters(40.0, 50.0)
        assert g.alpha == pytest.approx(5.0, abs=1e-12)
        assert g.beta == pytest.approx(10.0, abs=1e-12)

    def test_from_a_sampled_gamma_histogram(self) -> None:
        # 1e6 draws from Gamma(α = 6, β = 12): mean 72, mode 60
        x = np.random.default_rng(3).gamma(6.0, 12.0, size=1_000_000)
        levels = np.clip(np.round(x), 0, 255).astype(np.uint8)
        image = np.repeat(levels.reshape(1000, 1000, 1), 3, axis=2)
        s = channel_stats(image)
        g = gamma_parameters(float(s.modes[0]), float(s.means[0]))
        # the empirical mode of 1e6 draws lies within ~2 levels of 60
        assert g.alpha == pytest.approx(6.0, rel=0.2)
        assert g.beta == pytest.approx(12.0, rel=0.2)

    @pytest.mark.parametrize(("mode", "mean"), [(100.0, 100.0), (120.0, 80.0)])
    def test_not_right_skewed_gives_no_parameters(self, mode: float, mean: float) -> None:
        g = gamma_parameters(mode, mean)
        assert g.alpha is None
        assert g.beta is None
        assert "not right-skewed" in (g.reason or "")


class TestBaseline:
    def test_mean_and_covariance_with_n_minus_1(self) -> None:
        x = clean_modes(30)
        b = fit_baseline(x)
        np.testing.assert_allclose(b.mean_modes, x.mean(axis=0), atol=1e-12)  # eq. 5.12
        d = x - x.mean(axis=0)
        np.testing.assert_allclose(b.covariance, d.T @ d / 29, atol=1e-12)  # eq. 5.13
        assert b.f_critical == pytest.approx(stats.f.ppf(0.95, 3, 27), rel=1e-12)

    @pytest.mark.parametrize("n", [0, 1, 2, 3])
    def test_fewer_than_four_images(self, n: int) -> None:
        with pytest.raises(BaselineError, match="at least 4"):
            fit_baseline(clean_modes(max(n, 1))[:n] if n else np.empty((0, 3)))

    def test_identical_images_are_refused_with_the_reason(self) -> None:
        with pytest.raises(BaselineError, match="same in all 5 images"):
            fit_baseline(np.tile([56.0, 60.0, 84.0], (5, 1)))

    def test_constant_channel_is_refused_unless_shrinkage_is_asked_for(self) -> None:
        x = clean_modes(10)
        x[:, 0] = 56.0
        with pytest.raises(BaselineError, match="R mode"):
            fit_baseline(x)
        b = fit_baseline(x, shrinkage=QUANTISATION_VARIANCE)
        assert b.covariance[0, 0] == pytest.approx(1 / 12)
        assert np.isfinite(classify(b, [56.0, 60.0, 84.0]).f_stat)

    def test_collinear_modes_are_ill_conditioned(self) -> None:
        t = np.arange(8, dtype=float)
        x = np.column_stack([50 + t, 60 + 2 * t, 80 + 3 * t])  # rank 1 after centring
        with pytest.raises(BaselineError, match="singular or ill-conditioned"):
            fit_baseline(x)

    @pytest.mark.parametrize("significance", [0.0, 0.1, -1])
    def test_significance_range(self, significance: float) -> None:
        with pytest.raises(ValueError, match="significance"):
            fit_baseline(clean_modes(10), significance=significance)


class TestClassify:
    def test_t2_f_p_against_direct_scipy(self) -> None:
        x = clean_modes(12)
        b = fit_baseline(x, significance=0.01)
        new = np.array([60.0, 63.0, 88.0])
        v = classify(b, new)
        n = 12
        d = new - x.mean(axis=0)
        s = np.cov(x, rowvar=False)
        t2 = n / (n + 1) * d @ np.linalg.inv(s) @ d  # eq. 5.19
        f = (n - 3) / (3 * (n - 1)) * t2  # eq. 5.20
        assert v.t2 == pytest.approx(t2, rel=1e-10)
        assert v.f_stat == pytest.approx(f, rel=1e-10)
        assert v.p_value == pytest.approx(stats.f.sf(f, 3, n - 3), rel=1e-10)
        assert v.threshold == pytest.approx(stats.f.ppf(0.99, 3, n - 3), rel=1e-12)
        assert v.clean == (f < stats.f.ppf(0.99, 3, n - 3))

    def test_eq_5_22_holds_and_5_23_is_not_equivalent(self) -> None:
        x = clean_modes(20)
        b = fit_baseline(x)
        n = 20
        inv = np.linalg.inv(b.covariance)
        rhs = 3 * (n**2 - 1) / (n * (n - 3)) * b.f_critical
        m = b.mean_modes
        disagreements = 0
        for new in RNG.normal(m, 6.0, size=(400, 3)):
            d = new - m
            eq_5_22 = d @ inv @ d < rhs
            eq_5_23 = new @ inv @ new < m @ inv @ m + rhs
            assert classify(b, new).clean == eq_5_22
            disagreements += eq_5_22 != eq_5_23
        assert disagreements > 0  # 5.23 drops the cross term: it decides differently

    def test_clean_vs_dusty_shift(self) -> None:
        b = fit_baseline(clean_modes(50))
        assert classify(b, CLEAN_MEAN).clean
        # a dusty panel: R 79, G 82, B 105 (Figure 5.3b)
        dusty = classify(b, [79.0, 82.0, 105.0])
        assert not dusty.clean
        assert dusty.p_value < 1e-6

    def test_false_alarm_rate_matches_significance(self) -> None:
        # under H0 (new clean panel from the same distribution), P(refused) = ς exactly
        rng = np.random.default_rng(11)
        refused = 0
        trials = 4000
        for _ in range(trials):
            sample = rng.multivariate_normal(CLEAN_MEAN, CLEAN_COV, size=9)
            b = fit_baseline(sample[:8], significance=0.05)
            refused += not classify(b, sample[8]).clean
        assert refused / trials == pytest.approx(0.05, abs=0.012)  # ~3.5 binomial sd


class TestTwoSample:
    def test_against_direct_computation(self) -> None:
        a = clean_modes(15, seed=4)
        b = clean_modes(10, seed=5) + [20.0, 20.0, 20.0]
        r = two_sample_t2(a, b)
        n1, n2 = 15, 10
        sp = ((n1 - 1) * np.cov(a, rowvar=False) + (n2 - 1) * np.cov(b, rowvar=False)) / (
            n1 + n2 - 2
        )
        d = a.mean(0) - b.mean(0)
        t2 = n1 * n2 / (n1 + n2) * d @ np.linalg.solve(sp, d)
        f = (n1 + n2 - 3 - 1) / (3 * (n1 + n2 - 2)) * t2
        assert r.t2 == pytest.approx(t2, rel=1e-10)
        assert r.f_stat == pytest.approx(f, rel=1e-10)
        assert (r.df1, r.df2) == (3, 21)
        assert r.p_value == pytest.approx(stats.f.sf(f, 3, 21), rel=1e-8)
        np.testing.assert_allclose(r.mean_difference, b.mean(0) - a.mean(0))

    def test_rates(self) -> None:
        clean = clean_modes(40, seed=6)
        dirty = clean_modes(20, seed=7) + [23.0, 22.0, 21.0]
        m = misclassification(clean, dirty)
        assert m.dirty_called_clean == 0.0
        assert m.clean_called_dirty <= 0.15
        assert (m.n_clean, m.n_dirty) == (40, 20)


def test_f_critical_matches_scipy() -> None:
    for n in (4, 5, 10, 50):
        assert f_critical(n, 0.05) == pytest.approx(stats.f.ppf(0.95, 3, n - 3), rel=1e-12)
