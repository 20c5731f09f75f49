"""Hotelling's T² of colour-channel modes against a baseline: [Fayed 2013]'s chapter 5
(solar-panel soiling), which chapter 6 reuses for the sky's levels, and what it needs.

A camera photographs a panel; dust, sand and droppings shift the modes of the R, G and B
histograms upwards. A clean baseline of ``n`` images gives the mean mode vector and its
covariance; a new image is clean when Hotelling's T² of its mode vector against the baseline is
below the F critical value.

All functions are pure: arrays in, dataclasses out.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy import linalg, special, stats

P = 3
"""Dimension of the feature vector: the modes of R, G and B."""

MAX_CONDITION = 1e10
"""Covariances more ill-conditioned than this are refused: T² would be noise."""

QUANTISATION_VARIANCE = 1.0 / 12.0
"""Variance of rounding to an integer level, uniform on [-½, ½] [level²]."""


class BaselineError(ValueError):
    """The clean images cannot make a baseline (too few, or a degenerate covariance)."""


@dataclass(frozen=True, slots=True)
class Gamma:
    """Gamma-distribution parameters of one channel, estimated from its mode and mean."""

    alpha: float | None
    beta: float | None
    reason: str | None = None
    """Why the gamma model does not apply, when it does not."""


def gamma_parameters(mode: float, mean: float) -> Gamma:
    r"""Theorem 1: α̂ = x̄ / (x̄ − x̂), β̂ = x̄ − x̂ (eqs. 5.9–5.10).

    From mean = αβ (5.6) and mode = (α − 1)β (5.7). The estimates exist only for a right-skewed
    histogram, x̄ > x̂: then β̂ > 0 and α̂ > 1. When x̄ ≤ x̂ (a symmetric or left-skewed channel,
    e.g. a saturated or dark-dominated one) the gamma model does not fit: β̂ would be ≤ 0 and
    α̂ negative or infinite, so no parameters are returned, with the reason.

    Parameters
    ----------
    mode : histogram mode x̂ [level, 0–255].
    mean : channel mean x̄ [level].
    """
    if not (np.isfinite(mode) and np.isfinite(mean)):
        raise ValueError(f"mode and mean must be finite; got {mode}, {mean}")
    beta = mean - mode  # eq. 5.9
    if beta <= 0:
        return Gamma(None, None, f"mean {mean:.2f} ≤ mode {mode:.0f}: not right-skewed")
    return Gamma(alpha=mean / beta, beta=beta)  # eq. 5.10


@dataclass(frozen=True, slots=True)
class Baseline:
    """A panel's clean baseline (eqs. 5.12–5.13) and its decision threshold (5.21)."""

    n: int
    mean_modes: NDArray[np.float64]
    """x̄ₘ, shape (3,) [level] (eq. 5.12)."""
    covariance: NDArray[np.float64]
    """Σ̂, shape (3, 3), with n − 1 (eq. 5.13) [level²]."""
    significance: float
    """ς, the level of significance."""
    f_critical: float
    """F₍₃,ₙ₋₃,ς₎: the upper-ς quantile of F(3, n − 3)."""
    condition_number: float
    shrinkage: float = 0.0
    """Variance added to each diagonal element of Σ̂ [level²]; 0 unless asked for."""


def f_critical(n: int, significance: float) -> float:
    """F₍₃,ₙ₋₃,ς₎, the value exceeded with probability ς under F(3, n − 3) (eq. 5.21)."""
    return float(stats.f.isf(significance, P, n - P))


def fit_baseline(
    modes: ArrayLike, *, significance: float = 0.05, shrinkage: float = 0.0
) -> Baseline:
    """Baseline from the mode vectors of n ≥ 4 clean images (eqs. 5.12, 5.13).

    Parameters
    ----------
    modes : array of shape (n, 3): the R, G, B modes of each clean image [level].
    significance : ς in (0, 0.05] ([Fayed 2013] requires ≤ 0.05).
    shrinkage : variance added to the diagonal of Σ̂ [level²]. 0 (default) refuses a singular
        covariance; ``QUANTISATION_VARIANCE`` (1/12) is the principled choice when a channel's
        mode is constant across the images, since modes are rounded to integer levels.

    Raises
    ------
    BaselineError
        n < 4 (F(3, n − 3) needs n − 3 ≥ 1 degrees of freedom), or Σ̂ singular or
        ill-conditioned (identical images, a constant channel), with the reason.
    """
    x = np.asarray(modes, dtype=np.float64)
    if x.ndim != 2 or x.shape[1] != P:
        raise ValueError(f"modes must have shape (n, 3); got {x.shape}")
    if not np.isfinite(x).all():
        raise ValueError("modes must be finite")
    if not 0.0 < significance <= 0.05:
        raise ValueError(f"significance must be in (0, 0.05]; got {significance}")
    if shrinkage < 0 or not np.isfinite(shrinkage):
        raise ValueError(f"shrinkage must be ≥ 0; got {shrinkage}")
    n = x.shape[0]
    if n < P + 1:
        raise BaselineError(f"need at least 4 clean images (F(3, n − 3)); got {n}")
    mean = x.mean(axis=0)  # eq. 5.12
    cov = np.cov(x, rowvar=False, ddof=1)  # eq. 5.13: 1/(n − 1) Σ (xᵢ − x̄)(xᵢ − x̄)'
    cov = cov + shrinkage * np.eye(P)
    constant = [c for c, name in enumerate("RGB") if cov[c, c] == 0.0]
    if constant:
        names = ", ".join("RGB"[c] for c in constant)
        raise BaselineError(
            f"the {names} mode is the same in all {n} images, so the covariance is singular; "
            "use more varied images, or ask for shrinkage (0.0833, the variance of rounding "
            "modes to whole grey levels)"
        )
    eig = np.linalg.eigvalsh(cov)
    condition = float(eig[-1] / eig[0]) if eig[0] > 0 else float("inf")
    if not condition < MAX_CONDITION:
        raise BaselineError(
            f"the covariance of the modes is singular or ill-conditioned (condition number "
            f"{condition:.3g}): the images vary along fewer than three independent directions"
        )
    return Baseline(
        n=n,
        mean_modes=mean,
        covariance=cov,
        significance=significance,
        f_critical=f_critical(n, significance),
        condition_number=condition,
        shrinkage=shrinkage,
    )


@dataclass(frozen=True, slots=True)
class T2Verdict:
    t2: float
    """t² = n/(n+1) (x − x̄ₘ)' Σ̂⁻¹ (x − x̄ₘ) (eq. 5.19)."""
    f_stat: float
    """(n − 3)/(3(n − 1)) t² ~ F(3, n − 3) (eq. 5.20)."""
    p_value: float
    """P(F(3, n − 3) ≥ f_stat)."""
    threshold: float
    """F₍₃,ₙ₋₃,ς₎ (eq. 5.21)."""
    clean: bool


def _mahalanobis2(baseline: Baseline, x: NDArray[np.float64]) -> float:
    """(x − x̄ₘ)' Σ̂⁻¹ (x − x̄ₘ), by solving rather than inverting."""
    d = x - baseline.mean_modes
    return float(d @ np.linalg.solve(baseline.covariance, d))


def classify(baseline: Baseline, modes: ArrayLike) -> T2Verdict:
    r"""Is the panel with mode vector ``modes`` clean? (Theorem 2, eqs. 5.19–5.22.)

    .. math:: t^2 = \frac{n}{n+1} (x - \bar x_m)' \hat\Sigma^{-1} (x - \bar x_m)
    .. math:: F = \frac{n-3}{3(n-1)} t^2 \sim F_{3,n-3}

    Clean iff F < F₍₃,ₙ₋₃,ς₎ (5.21), i.e. (x − x̄ₘ)' Σ̂⁻¹ (x − x̄ₘ) < 3(n² − 1)/(n(n − 3)) F₍₃,ₙ₋₃,ς₎
    (5.22). [Fayed 2013]'s eq. 5.23, x' Σ̂⁻¹ x < x̄ₘ' Σ̂⁻¹ x̄ₘ + …, is *not* equivalent: expanding
    the quadratic form of 5.22 leaves the cross term −2 x̄ₘ' Σ̂⁻¹ x + 2 x̄ₘ' Σ̂⁻¹ x̄ₘ, which 5.23
    drops. 5.22 is implemented (in its F form, 5.21).
    """
    x = np.asarray(modes, dtype=np.float64)
    if x.shape != (P,) or not np.isfinite(x).all():
        raise ValueError(f"modes must be 3 finite numbers; got {x!r}")
    n = baseline.n
    t2 = float(n / (n + 1) * _mahalanobis2(baseline, x))  # eq. 5.19
    f_stat = (n - P) / (P * (n - 1)) * t2  # eq. 5.20
    p_value = float(special.fdtrc(P, n - P, f_stat))  # = stats.f.sf, without its overhead
    return T2Verdict(
        t2=t2,
        f_stat=f_stat,
        p_value=p_value,
        threshold=baseline.f_critical,
        clean=f_stat < baseline.f_critical,  # eq. 5.21 ⇔ eq. 5.22
    )


@dataclass(frozen=True, slots=True)
class TwoSampleT2:
    """Hotelling's two-sample T² test that two sets of mode vectors share one mean."""

    t2: float
    f_stat: float
    df1: int
    df2: int
    p_value: float
    mean_difference: NDArray[np.float64]
    """Mean of the second set minus mean of the first [level]."""


def two_sample_t2(first: ArrayLike, second: ArrayLike) -> TwoSampleT2:
    r"""Hotelling's two-sample T² with the pooled covariance.

    .. math:: T^2 = \frac{n_1 n_2}{n_1 + n_2} (\bar x_1 - \bar x_2)' S_p^{-1} (\bar x_1 - \bar x_2)
    .. math:: F = \frac{n_1 + n_2 - p - 1}{p (n_1 + n_2 - 2)} T^2 \sim F_{p,\, n_1 + n_2 - p - 1}

    [Fayed 2013] uses it to show that clean and dusty panels differ (chapter 5, §III).
    """
    a = np.asarray(first, dtype=np.float64)
    b = np.asarray(second, dtype=np.float64)
    for name, s in (("first", a), ("second", b)):
        if s.ndim != 2 or s.shape[1] != P or s.shape[0] < 2:
            raise ValueError(f"{name} set must have shape (n ≥ 2, 3); got {s.shape}")
    n1, n2 = a.shape[0], b.shape[0]
    if n1 + n2 - P - 1 < 1:
        raise BaselineError(f"need n1 + n2 ≥ 5 images; got {n1 + n2}")
    pooled = ((n1 - 1) * np.cov(a, rowvar=False) + (n2 - 1) * np.cov(b, rowvar=False)) / (
        n1 + n2 - 2
    )
    eig = np.linalg.eigvalsh(pooled)
    if eig[0] <= 0 or eig[-1] / eig[0] >= MAX_CONDITION:
        raise BaselineError("the pooled covariance of the two sets is singular")
    d = a.mean(axis=0) - b.mean(axis=0)
    t2 = float(n1 * n2 / (n1 + n2) * d @ linalg.solve(pooled, d, assume_a="pos"))
    df1, df2 = P, n1 + n2 - P - 1
    f_stat = df2 / (P * (n1 + n2 - 2)) * t2
    return TwoSampleT2(
        t2=t2,
        f_stat=f_stat,
        df1=df1,
        df2=df2,
        p_value=float(stats.f.sf(f_stat, df1, df2)),
        mean_difference=-d,
    )


@dataclass(frozen=True, slots=True)
class Misclassification:
    dirty_called_clean: float
    """Fraction of dirty images the clean baseline accepts."""
    clean_called_dirty: float
    """Fraction of clean images refused by a baseline fitted without them (leave-one-out)."""
    n_clean: int
    n_dirty: int


def misclassification(
    clean: ArrayLike, dirty: ArrayLike, *, significance: float = 0.05, shrinkage: float = 0.0
) -> Misclassification:
    """The two error rates of the T² classifier on labelled mode vectors.

    Dirty images are classified against the baseline of all clean images; each clean image
    against the baseline of the others, so it is never judged by a baseline it helped build.
    """
    c = np.asarray(clean, dtype=np.float64)
    d = np.asarray(dirty, dtype=np.float64)
    if d.ndim != 2 or d.shape[1] != P or d.shape[0] < 1:
        raise ValueError(f"dirty set must have shape (n ≥ 1, 3); got {d.shape}")
    if c.ndim != 2 or c.shape[1] != P or c.shape[0] < P + 2:
        raise BaselineError("leave-one-out needs at least 5 clean images")
    full = fit_baseline(c, significance=significance, shrinkage=shrinkage)
    dirty_clean = sum(classify(full, x).clean for x in d)
    clean_dirty = 0
    for i in range(c.shape[0]):
        rest = fit_baseline(np.delete(c, i, axis=0), significance=significance, shrinkage=shrinkage)
        clean_dirty += not classify(rest, c[i]).clean
    return Misclassification(
        dirty_called_clean=dirty_clean / d.shape[0],
        clean_called_dirty=clean_dirty / c.shape[0],
        n_clean=c.shape[0],
        n_dirty=d.shape[0],
    )
