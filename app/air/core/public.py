"""The public reading of a camera: the best estimate of the air with its doubt, never silence.

A regression's verdict is a predictive distribution of the reference value in the unit it was
fitted in (ln(1 + PM2.5), ln(1 + AQI) or the level): Student's t with the calibration's
residual degrees of freedom, centred on the fitted value ŷ with the scale
σ·√(1 + 1/n + h) of its prediction interval (``airquality.Regression.estimate``). The public
reading is the category that distribution makes most probable, that probability, the
estimate and its ``airquality.INTERVAL`` range; the camera's reading is the same made of its
last 12 hours' frames, weighted as NowCast weighs hours (``smooth``). Alerts follow the
smoothed probability of Poor or worse (``alert_kind``).

Not in [Fayed 2013], whose clusters (ch. 6) name a level or nothing: the probabilities are
what a reader of a regression's interval needs to act on it.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from datetime import datetime, timedelta
from functools import lru_cache

import numpy as np
from scipy.stats import t as t_dist

from app.air.core import airquality

SURE = 0.8
"""Probability of the shown category from which it is said plainly ("is Fair"); below it,
"is likely Fair" and the reading is ``uncertain``. The same 80 % as the interval's."""

ALERT_RAISE = 0.45
"""Smoothed probability of Poor or worse at which an alert is raised: what
bench/airquality_eval.py's rule (the share of bad days alerted less twice the share of clean
days alerted, the middle of the best) chooses on the Milan series' out-of-fold readings; the
same rule, run on some days and judged on the others, is the figure in bench/README.md (its
choice there ranges 0.30–0.70 from fold to fold: each has six or seven bad days to learn
from)."""

ALERT_CLEAR = ALERT_RAISE / 2
"""An open alert is cleared when the smoothed probability of Poor or worse falls to this; a
new one is raised only after it has (the hysteresis between the two)."""

NAMES = tuple(name for _, name in airquality.CATEGORIES)
"""The categories, clearest first."""

WORSE_THAN_FAIR = ("Poor", "Very Poor")


@lru_cache(maxsize=16)
def category_edges(unit: str, table: str) -> tuple[float, ...]:
    """The values of ``unit`` at which the category changes, ascending (4 of them): found by
    bisection of ``airquality.level_of`` (to 1e-9 of the unit), so they are the breakpoint
    tables' own, truncation and rounding included (EPA PM2.5 9.1, 35.5, 55.5, 125.5 µg/m³;
    European 10, 20, 25, 50 µg/m³; AQI 50.5 … 200.5; levels 2.5 … 8.5)."""

    def index(v: float) -> int:
        return NAMES.index(airquality.category(airquality.level_of(v, unit, table)))

    top = 10.0 if unit == "level" else 1000.0
    edges = []
    lo_i = index(0.0)
    for step in range(1, len(NAMES)):
        target = lo_i + step if unit != "level" else lo_i - step
        a, b = 0.0, top
        while b - a > 1e-9:  # the smallest value whose category is past ``target - 1``
            m = (a + b) / 2
            past = index(m) >= target if unit != "level" else index(m) <= target
            a, b = (a, m) if past else (m, b)
        edges.append(b)
    return tuple(sorted(edges))


def _fitted(value: float | np.ndarray, unit: str) -> np.ndarray:
    """A value in ``unit`` in the space the regression is fitted in."""
    return np.asarray(value, dtype=np.float64) if unit == "level" else np.log1p(value)


def _out(y: float, unit: str) -> float:
    return float(y) if unit == "level" else float(np.expm1(y))


@dataclass(frozen=True, slots=True)
class Predictive:
    """Student's t over the fitted value: ``loc`` + ``scale`` · t(``dof``) in ln(1 + unit)
    (or levels); what ``unit`` the estimate is in and by which ``table`` it becomes levels."""

    loc: float
    scale: float
    dof: float
    unit: str
    table: str = "us_epa"


@dataclass(frozen=True, slots=True)
class Public:
    """A reading as the public gets it."""

    category: str
    """The most probable category."""
    probability: float
    """Its probability, 0–1."""
    level: int
    """The level 1–10 of the estimate, within ``category`` (the category's level nearest the
    estimate when the estimate itself lies in a neighbour, as a narrow category may)."""
    value: float
    low: float
    high: float
    """The estimate and its ``airquality.INTERVAL`` range, in the unit."""
    poor: float
    """The probability of Poor or worse."""
    probabilities: dict[str, float]
    """Every category's probability."""

    @property
    def uncertain(self) -> bool:
        return self.probability < SURE


def probabilities(p: Predictive) -> dict[str, float]:
    """The probability of each category under ``p``: the t's mass between the category's
    edges (``category_edges``) in fitted space."""
    edges = _fitted(np.array(category_edges(p.unit, p.table)), p.unit)
    cdf = t_dist.cdf((edges - p.loc) / max(p.scale, 1e-12), max(p.dof, 1.0))
    mass = np.diff(np.concatenate(([0.0], cdf, [1.0])))  # along increasing value
    order = NAMES if p.unit != "level" else NAMES[::-1]
    return {name: float(m) for name, m in zip(order, mass, strict=True)}


def public(p: Predictive) -> Public:
    """The reading ``p`` gives: its most probable category (ties: the worse), the
    probability, the estimate and its range, the probability of Poor or worse."""
    probs = probabilities(p)
    best = max(reversed(NAMES), key=lambda n: probs[n])  # ties go to the worse
    half = airquality.t_quantile(max(p.dof, 1.0)) * p.scale
    value = _out(p.loc, p.unit)
    low, high = sorted((_out(p.loc - half, p.unit), _out(p.loc + half, p.unit)))
    lowest = next(lo for lo, name in airquality.CATEGORIES if name == best)
    level = int(np.clip(airquality.level_of(value, p.unit, p.table), lowest, lowest + 1))
    poor = sum(probs[n] for n in WORSE_THAN_FAIR)
    return Public(best, probs[best], level, value, low, high, poor, probs)


@dataclass(frozen=True, slots=True)
class Read:
    """A graded frame as smoothing reads it: when it was taken, its fitted value and the
    scale of its predictive t (``Predictive``)."""

    at: datetime
    loc: float
    scale: float


@dataclass(frozen=True, slots=True)
class Shape:
    """What a calibration's regression says of every verdict's predictive t: its degrees of
    freedom, unit, breakpoint table, and the share of its errors a day's frames have in
    common (``airquality.Regression.day_share``)."""

    dof: float
    unit: str
    table: str = "us_epa"
    shared: float = 1.0

    @classmethod
    def of(cls, model: airquality.Regression) -> Shape:
        return cls(model.dof, model.unit, model.table, model.day_share)


def predictive_of(value: float, low: float, high: float, shape: Shape) -> Predictive:
    """The predictive t of a verdict kept as its estimate and its ``INTERVAL`` range (the
    range is loc ± t_q·scale in fitted space)."""
    lo, hi = _fitted(np.array([low, high]), shape.unit)
    half = (float(hi) - float(lo)) / 2
    scale = half / airquality.t_quantile(max(shape.dof, 1.0))
    return Predictive(float(_fitted(value, shape.unit)), scale, shape.dof, shape.unit, shape.table)


HOUR = timedelta(hours=1)


def smooth(reads: Sequence[Read], at: datetime, shape: Shape) -> Predictive | None:
    """The camera's predictive distribution at ``at`` from its frames taken up to it, made
    NowCast-style: the frames of the hour k before ``at`` ((at − (k+1) h, at − k h], k < 12)
    averaged, the hours weighted wᵏ with w = max(min/max of the hourly mean estimates, 0.5)
    (``airquality.nowcasts``, here over estimates). None without a frame in the 3 hours
    before.

    The mean is the weighted mean of the frames' fitted values (ω, summing to 1); its
    scale, that of a weighted mean of errors that share ``shape.shared`` of their variance (a
    day's weather errs alike in all its frames, the rest is each frame's own):
    s² = shared·(Σ ω s)² + (1 − shared)·Σ ω² s². With shared = 1 the range is never
    narrower than a frame's; measured on the Milan series, shared from the calibration's
    days (``airquality.Regression.day_share``) keeps the 80 % range's coverage at 80 %.
    """
    window = [r for r in reads if at - 12 * HOUR < r.at <= at]
    if not any(at - r.at < airquality.FRESH for r in window):
        return None
    hours = np.array([max(int(np.ceil((at - r.at) / HOUR)) - 1, 0) for r in window])
    loc = np.array([r.loc for r in window])
    scale = np.array([r.scale for r in window])
    value = np.array([_out(v, shape.unit) for v in loc])
    present = np.unique(hours)
    means = np.array([value[hours == k].mean() for k in present])
    lo, hi = means.min(), means.max()
    w = max(lo / hi if hi > 0 else 1.0, 0.5)
    per_hour = w ** present.astype(np.float64)
    per_hour /= per_hour.sum()
    counts = np.array([(hours == k).sum() for k in present])
    omega = (per_hour / counts)[np.searchsorted(present, hours)]
    mean = float(omega @ loc)
    shared = shape.shared
    var = shared * float(omega @ scale) ** 2 + (1 - shared) * float(omega**2 @ scale**2)
    return Predictive(mean, float(np.sqrt(var)), shape.dof, shape.unit, shape.table)


def alert_kind(
    poor: float,
    earlier: Iterable[float],
    episode_open: bool,
    *,
    raise_at: float = ALERT_RAISE,
    clear_at: float = ALERT_CLEAR,
) -> str | None:
    """Whether an alert is "raised", "cleared" or neither (None) by the smoothed probability
    of Poor or worse ``poor``: raised when it reaches ``raise_at`` coming from clear air (the
    newest of ``earlier``, the camera's earlier smoothed probabilities newest first, outside
    the dead band (``clear_at``, ``raise_at``) is at most ``clear_at``, or there is none);
    cleared when it falls to ``clear_at`` while an alert is open."""
    if poor >= raise_at and not episode_open:
        for p in earlier:
            if p <= clear_at:
                return "raised"
            if p >= raise_at:
                return None
        return "raised"
    if poor <= clear_at and episode_open:
        return "cleared"
    return None


def alert_category(reading: Public) -> str:
    """The category an alert names: the more probable of Poor and Very Poor."""
    return max(WORSE_THAN_FAIR, key=lambda n: reading.probabilities[n])


def words(reading: Public) -> str:
    """What the screen says: "Today's Air Quality is Fair" when sure, "… is likely Fair"
    otherwise."""
    likely = "likely " if reading.uncertain else ""
    return f"Today's Air Quality is {likely}{reading.category}"
