"""What a baseline can detect (``app.solar.core.power``): the noncentral F power of eqs.
5.19–5.21 against a dust veil, checked by simulation."""

from __future__ import annotations

import numpy as np
import pytest

from app.solar.core import power
from app.stats import hotelling


def test_the_veil_found_is_detected_nine_times_in_ten() -> None:
    """Draw a baseline of n photos and a photo under the veil, 4,000 times (seeded): the F test
    of eq. 5.21 rejects the veiled photo with the probability asked (binomial σ 0.005)."""
    rng = np.random.default_rng(12)
    mean = np.array([56.0, 60.0, 84.0])
    cov = np.array([[4.0, 1.0, 0.5], [1.0, 4.0, 1.0], [0.5, 1.0, 6.0]])
    n = 10
    critical = hotelling.f_critical(n, 0.05)
    veil = power.detectable_veil(n, mean, cov, critical)
    assert 0.01 < veil < 0.3
    rejected = 0
    trials = 4000
    for _ in range(trials):
        baseline = hotelling.fit_baseline(rng.multivariate_normal(mean, cov, n))
        photo = rng.multivariate_normal(mean + veil * (power.DUST - mean), cov)
        rejected += not hotelling.classify(baseline, photo).clean
    assert rejected / trials == pytest.approx(power.POWER, abs=0.02)


def test_power_grows_with_the_veil_and_is_the_test_size_without_one() -> None:
    n, critical = 8, hotelling.f_critical(8, 0.05)
    assert power.power(n, critical, 0.0) == pytest.approx(0.05, rel=1e-9)
    lams = [0.5, 2.0, 8.0, 32.0]
    powers = [power.power(n, critical, lam) for lam in lams]
    assert powers == sorted(powers)


def test_photos_of_different_panels_are_too_broad() -> None:
    wide = np.diag([3000.0, 4500.0, 6300.0])  # what 5 photos of 5 panels gave
    assert "different panels" in (power.too_broad(0.1, wide) or "")
    narrow = np.diag([4.0, 4.0, 6.0])
    assert power.too_broad(0.05, narrow) is None
    assert "0.45" in (power.too_broad(0.45, narrow) or "")


def test_a_panel_the_colour_of_dust_cannot_see_it() -> None:
    cov = np.eye(3)
    assert power.detectable_veil(6, power.DUST, cov, hotelling.f_critical(6, 0.05)) == np.inf
