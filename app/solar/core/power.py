"""What a panel's T² baseline can detect: the power of the F test of eqs. 5.19–5.21 against a
dust veil, and when a baseline is too broad to judge.

A veil of strength s over the panel blends every pixel towards the colour of dust,
p' = (1 − s) p + s h, so the mode vector moves from x̄ₘ to (1 − s) x̄ₘ + s h: by δ(s) = s (h − x̄ₘ).
For a new photo x ~ N(x̄ₘ + δ, Σ), independent of the n baseline photos, the statistic of eq. 5.20,
F = (n − 3)/(3(n − 1)) · n/(n + 1) · (x − x̄ₘ)' Σ̂⁻¹ (x − x̄ₘ), follows the noncentral
F(3, n − 3, λ) with λ = n/(n + 1) · δ' Σ⁻¹ δ (Hotelling's T² with a shifted mean; Anderson,
An Introduction to Multivariate Statistical Analysis, §5.2.2). Its power at the baseline's
critical value F₍₃,ₙ₋₃,ς₎ (eq. 5.21) grows with λ, so with s²: the smallest veil detected with
probability ``POWER`` solves one equation in λ.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike
from scipy import optimize, stats

DUST = np.array([170.0, 155.0, 135.0])
"""h: the colour of a brown-grey dust veil [level] (the dusty panels' haze in the
photos of [Fayed 2013], chapter 5 Figure 5.2)."""

POWER = 0.9
"""Probability with which the veil must be detected."""

USEFUL_VEIL = 0.3
"""A baseline that needs a thicker veil than this to notice it judges nothing useful: a panel
under a 30 % veil has long lost its yield."""

ONE_PANEL_VARIANCE = 900.0
"""Largest variance of one channel's mode [level²] (σ 30 levels) among photos of one panel by
one camera in daylight: photos of different panels or cameras vary far more (3,000–6,300 seen)."""


def noncentrality(n: int, covariance: ArrayLike, shift: ArrayLike) -> float:
    """λ = n/(n + 1) · δ' Σ⁻¹ δ of a mode shift δ [level] (see the module)."""
    d = np.asarray(shift, dtype=np.float64)
    return float(n / (n + 1) * d @ np.linalg.solve(np.asarray(covariance, np.float64), d))


def power(n: int, f_critical: float, lam: float) -> float:
    """P(F > F₍₃,ₙ₋₃,ς₎) under the noncentral F(3, n − 3, λ); at λ = 0 the central F (SciPy's
    noncentral F answers −0.95 there)."""
    if lam <= 0:
        return float(stats.f.sf(f_critical, 3, n - 3))
    return float(stats.ncf.sf(f_critical, 3, n - 3, lam))


def detectable_veil(
    n: int,
    mean_modes: ArrayLike,
    covariance: ArrayLike,
    f_critical: float,
    *,
    dust: ArrayLike = DUST,
    probability: float = POWER,
) -> float:
    """The smallest veil strength s (0–1 and beyond: inf when the dust colour is the panel's)
    that the baseline's F test rejects with ``probability``."""
    direction = np.asarray(dust, dtype=np.float64) - np.asarray(mean_modes, dtype=np.float64)
    per_unit = noncentrality(n, covariance, direction)  # λ at s = 1; λ(s) = s² · per_unit
    if not per_unit > 0:
        return math.inf
    hi = 1.0
    while power(n, f_critical, hi) < probability:
        hi *= 2.0
        if hi > 1e12:
            return math.inf
    lam = optimize.brentq(lambda x: power(n, f_critical, x) - probability, 0.0, hi, xtol=1e-10)
    return math.sqrt(lam / per_unit)


def too_broad(veil: float, covariance: ArrayLike) -> str | None:
    """Why a baseline is too broad to judge, with its figures, or None."""
    variances = np.diag(np.asarray(covariance, dtype=np.float64))
    if variances.max() > ONE_PANEL_VARIANCE:
        spread = ", ".join(f"{v:.0f}" for v in variances)
        return (
            f"its photos vary far more than one panel's (mode variances R, G, B {spread} "
            f"level², one panel's stay under {ONE_PANEL_VARIANCE:.0f}): different panels or "
            "cameras?"
        )
    if veil > USEFUL_VEIL:
        return (
            f"it would notice only a dust veil of strength {veil:.2f} or more (with probability "
            f"{POWER:.0%}), beyond a useful {USEFUL_VEIL}"
        )
    return None
