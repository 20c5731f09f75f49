"""Soiling from a panel's daily output: the ratio of what it made to what it would make clean.

The method is the field's: Deceglie et al., "Quantifying soiling loss directly from PV yield",
IEEE J. Photovoltaics 8(2), 2018, as RdTools implements it (``rdtools.soiling.soiling_srr``,
the stochastic rate and recovery method). The daily performance index

.. math:: PI_d = E_d / E^{exp}_d

(measured over expected energy) falls while dust builds up and recovers when the panel is
cleaned (a robot, rain). The days are cut into soiling intervals at the recoveries, and a
Theil–Sen line is fitted to each. The soiling ratio is the fitted index normalised to its value
at the interval's start, the panel just after its cleaning:

.. math:: SR(t) = \\frac{a + b\\,t}{a}

with ``t`` days since that cleaning. This is a simpler estimator than SRR's Monte Carlo over
interval choices: one set of intervals, and for the interval of the ratio
Sen's distribution-free interval of the slope (95 %) carried to ``t``. ``bench/soiling_eval.py``
measures it against RdTools on the same series, and ``tests/solar/test_soiling.py`` against the
intervals RdTools reports on its own test data.

Cleaning pays, for dust that builds up linearly (a loss rate ``ρ`` of the clean energy ``E``
per day, worth ``P`` a kWh), when the value lost since the last cleaning reaches the cleaning's
cost ``C``: the cost per day of a cycle of ``τ`` days, ``(C + ρ E P τ² / 2) / τ``, is least at
``τ* = √(2C / (ρ E P))``, where the lost value ``ρ E P τ*² / 2`` equals ``C``.

Days are proleptic Gregorian ordinals (``date.toordinal()``); energies in kWh.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from datetime import date

import numpy as np
from numpy.typing import NDArray
from scipy import stats as sstats
from scipy.ndimage import median_filter

MIN_DAYS = 7
"""Days of output an interval needs before its line is fitted (RdTools' ``min_interval_length``
is 7)."""

STEP_WINDOW = 5
"""Days of output on each side of a day whose medians are compared to find a recovery."""

MIN_STEP = 0.02
"""The least rise of the performance index taken for a cleaning: smaller ones are noise."""

STEP_SIGMAS = 5.0
"""A rise must also stand this many times above the spread noise alone gives it."""

OUTLIER_SIGMAS = 5.0
"""A day this many robust deviations from its neighbours' median is left out (an inverter
outage, snow on the panel, a clipped export)."""

LOW_LIGHT = 0.1
"""A day expected to make less than this share of the panel's median day is left out: its
index is mostly noise."""

RAIN_MM = 5.0
"""A recovery on or the day after a day with this much rain [mm] is put down to rain."""

MIN_EXPECTED_KWH = 1e-3
"""A day expected to make less than this [kWh] is left out."""

CONFIDENCE = 0.95
"""Of Sen's interval of each slope, and so of the ratio's."""


@dataclass(frozen=True, slots=True)
class Interval:
    """One soiling interval: from a cleaning (or the first day) to the day before the next."""

    start: int
    """First day [ordinal]."""
    end: int
    """Last day [ordinal]."""
    cause: str
    """What began it: ``robot`` (a completed cleaning task), ``rain``, ``detected`` (a recovery
    of the output with no known cause) or ``start`` (the first day of data)."""
    days: int
    """Days of output used in its fit."""
    level: float | None
    """The fitted index at the start, ``a`` [–]; None with too few days."""
    rate: float | None
    """Soiling rate ``b / a`` [1/day], negative while dust builds up."""
    rate_low: float | None
    rate_high: float | None


@dataclass(frozen=True, slots=True)
class Current:
    """The panel on its last day of output."""

    day: int
    since: int
    """The current interval's first day (the last cleaning, or the first day of data)."""
    cause: str
    ratio: float
    low: float
    high: float
    rate: float | None
    """Soiling rate of the current interval [1/day]; None before it has ``MIN_DAYS``."""
    clean_kwh_per_day: float
    """What the clean panel makes on a day like the last fortnight's [kWh]."""
    loss_kwh_per_day: float
    loss_since_cleaning_kwh: float


@dataclass(frozen=True, slots=True)
class Analysis:
    days: NDArray[np.int64]
    pi: NDArray[np.float64]
    """Daily performance index, NaN where there is no usable output."""
    used: NDArray[np.bool_]
    """Days that entered the fits."""
    ratio: NDArray[np.float64]
    """Fitted soiling ratio per day, NaN in intervals too short to fit."""
    low: NDArray[np.float64]
    high: NDArray[np.float64]
    intervals: list[Interval]
    current: Current | None


def performance_index(
    kwh: NDArray[np.float64], expected_kwh: NDArray[np.float64]
) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
    """``PI = E / E_exp`` per day, and which days are usable: expected above ``LOW_LIGHT`` of
    the median expected day, finite, and within ``OUTLIER_SIGMAS`` of the rolling median of
    the usable days around them (7 days)."""
    kwh = np.asarray(kwh, dtype=np.float64)
    expected = np.asarray(expected_kwh, dtype=np.float64)
    # a day expected to make less than a watt-hour made nothing to compare (and its ratio can
    # overflow)
    ok = np.isfinite(kwh) & np.isfinite(expected) & (expected >= MIN_EXPECTED_KWH)
    if ok.any():
        ok &= expected >= LOW_LIGHT * float(np.median(expected[ok]))
    pi = np.full(kwh.shape, np.nan)
    pi[ok] = kwh[ok] / expected[ok]
    idx = np.flatnonzero(ok)
    if idx.size >= 3:
        values = pi[idx]
        smooth = median_filter(values, size=7, mode="nearest")
        dev = values - smooth
        sigma = max(1.4826 * float(np.median(np.abs(dev))), 1e-3)
        ok[idx[np.abs(dev) > OUTLIER_SIGMAS * sigma]] = False
    return pi, ok


def recoveries(pi: NDArray[np.float64], used: NDArray[np.bool_]) -> NDArray[np.int64]:
    """Positions (into ``pi``) of the days that begin a recovery: the median index of the next
    ``STEP_WINDOW`` usable days exceeds the previous ``STEP_WINDOW``'s by ``MIN_STEP`` and by
    ``STEP_SIGMAS`` robust deviations of all such differences, the largest within the window
    (RdTools' ``clean_criterion='shift'``, on a rolling median)."""
    idx = np.flatnonzero(used)
    k = STEP_WINDOW
    if idx.size < 2 * k + 1:
        return np.zeros(0, dtype=np.int64)
    values = pi[idx]
    windows = np.lib.stride_tricks.sliding_window_view(values, k)
    medians = np.median(windows, axis=1)  # medians[i]: of values[i : i + k]
    # split j (j ≥ k): after = values[j : j + k], before = values[j - k : j]
    splits = np.arange(k, idx.size - k + 1)
    diff = medians[splits] - medians[splits - k]
    # the day-to-day noise from consecutive differences (a slow decline hardly shows in them),
    # and so the spread of a difference of two medians of k days (a median's efficiency is
    # 2/π: its spread is √(π/2) times the mean's)
    day_sigma = 1.4826 * float(np.median(np.abs(np.diff(values)))) / math.sqrt(2.0)
    spread = math.sqrt(math.pi / 2.0) * day_sigma * math.sqrt(2.0 / k)
    threshold = max(MIN_STEP, STEP_SIGMAS * spread)
    found: list[int] = []
    for pos in np.argsort(-diff):
        if diff[pos] <= threshold:
            break
        if all(abs(int(pos) - f) > k for f in found):
            found.append(int(pos))
    return np.sort(idx[[_refine(values, int(splits[f]), k) for f in found]]).astype(np.int64)


def _refine(values: NDArray[np.float64], split: int, k: int) -> int:
    """The split near ``split`` that best cuts ``values[split - k : split + k]`` into two
    levels (least squares: the split that maximises ``n₁ n₂ / n · (ȳ₂ − ȳ₁)²``, outliers
    already left out): the medians' comparison finds a recovery, but its largest difference
    can sit a day or two off the step."""
    lo, hi = max(split - k, 0), min(split + k, values.size)
    window = values[lo:hi]
    n = window.size
    left_n = np.arange(1, n)
    left_sum = np.cumsum(window)[:-1]
    left_mean = left_sum / left_n
    right_mean = (window.sum() - left_sum) / (n - left_n)
    gain = left_n * (n - left_n) / n * (right_mean - left_mean) ** 2
    return lo + 1 + int(np.argmax(gain))


def _boundaries(
    days: NDArray[np.int64],
    detected: NDArray[np.int64],
    cleanings: Sequence[int],
    rain_mm: NDArray[np.float64] | None,
) -> list[tuple[int, str]]:
    """Interval starts as (position, cause): the first day, each known cleaning (the first day
    of output on or after it) and each detected recovery not within ``STEP_WINDOW`` days of a
    known one."""
    starts: dict[int, str] = {0: "start"}
    known = []
    for c in sorted(set(cleanings)):
        pos = int(np.searchsorted(days, c))
        if 0 < pos < days.size:
            starts[pos] = "robot"
            known.append(int(days[pos]))
    for pos in detected.tolist():
        day = int(days[pos])
        if pos == 0 or any(abs(day - k) <= STEP_WINDOW for k in known):
            continue
        rained = False
        if rain_mm is not None:
            near = (days >= day - 1) & (days <= day)
            rained = bool(np.nanmax(np.where(near, rain_mm, 0.0), initial=0.0) >= RAIN_MM)
        starts[pos] = "rain" if rained else "detected"
    return sorted(starts.items())


def analyse(
    days: NDArray[np.int64],
    kwh: NDArray[np.float64],
    expected_kwh: NDArray[np.float64],
    *,
    cleanings: Sequence[int] = (),
    rain_mm: NDArray[np.float64] | None = None,
) -> Analysis:
    """The soiling intervals, daily ratio with its band, and the panel on its last day.

    ``days`` sorted and distinct, shape (N,), with ``kwh`` and ``expected_kwh`` of the same
    shape; ``cleanings``: days of known cleanings; ``rain_mm``: each day's rain, NaN unknown."""
    days = np.asarray(days, dtype=np.int64)
    if days.ndim != 1 or np.any(np.diff(days) <= 0):
        raise ValueError("days must be a sorted 1-D array of distinct ordinals")
    expected = np.asarray(expected_kwh, dtype=np.float64)
    pi, used = performance_index(kwh, expected)
    starts = _boundaries(days, recoveries(pi, used), cleanings, rain_mm)
    ratio = np.full(days.shape, np.nan)
    low, high = ratio.copy(), ratio.copy()
    intervals = []
    for n, (begin, cause) in enumerate(starts):
        stop = starts[n + 1][0] if n + 1 < len(starts) else days.size
        fit = _fit(days[begin:stop], pi[begin:stop], used[begin:stop])
        span = slice(begin, stop)
        t = (days[span] - days[begin]).astype(np.float64)
        if fit is not None:
            a, b, b_low, b_high = fit
            ratio[span] = 1.0 + b / a * t
            low[span] = 1.0 + b_low / a * t
            high[span] = 1.0 + b_high / a * t
        intervals.append(
            Interval(
                start=int(days[begin]),
                end=int(days[stop - 1]),
                cause=cause,
                days=int(used[span].sum()),
                level=None if fit is None else fit[0],
                rate=None if fit is None else fit[1] / fit[0],
                rate_low=None if fit is None else fit[2] / fit[0],
                rate_high=None if fit is None else fit[3] / fit[0],
            )
        )
    current = _current(days, pi, used, expected, ratio, low, high, intervals)
    return Analysis(days, pi, used, ratio, low, high, intervals, current)


def _fit(
    days: NDArray[np.int64], pi: NDArray[np.float64], used: NDArray[np.bool_]
) -> tuple[float, float, float, float] | None:
    """Theil–Sen's intercept at the first day, slope and Sen's interval of the slope [1/day],
    or None with fewer than ``MIN_DAYS`` usable days or a non-positive level."""
    if used.sum() < MIN_DAYS:
        return None
    t = (days[used] - days[0]).astype(np.float64)
    res = sstats.theilslopes(pi[used], t, alpha=CONFIDENCE)
    a = float(res.intercept)
    if not a > 0:
        return None
    return a, float(res.slope), float(res.low_slope), float(res.high_slope)


FORTNIGHT = 14
"""Days of expected energy averaged for "a day like the last ones" in the losses a day."""


def _current(
    days: NDArray[np.int64],
    pi: NDArray[np.float64],
    used: NDArray[np.bool_],
    expected: NDArray[np.float64],
    ratio: NDArray[np.float64],
    low: NDArray[np.float64],
    high: NDArray[np.float64],
    intervals: list[Interval],
) -> Current | None:
    """The last day's ratio and the losses. An interval too short to fit has its ratio from
    its days' median index against the median level of the earlier intervals that began with a
    cleaning (the panel clean), the band from their spread; None without such a level."""
    if not intervals or not used.any():
        return None
    last = intervals[-1]
    begin = int(np.searchsorted(days, last.start))
    recent = slice(max(begin, days.size - FORTNIGHT), days.size)
    ok = np.isfinite(expected[recent]) & (expected[recent] > 0)
    typical = float(expected[recent][ok].mean()) if ok.any() else 0.0
    if last.level is not None and last.rate is not None:
        a, r, lo, hi = last.level, float(ratio[-1]), float(low[-1]), float(high[-1])
        t = (days[begin:] - days[begin]).astype(np.float64)
        e = np.where(np.isfinite(expected[begin:]), expected[begin:], 0.0)
        lost = float(np.sum(-last.rate * a * t * e))  # kWh the fitted line lost since the start
        rate: float | None = last.rate
    else:
        levels = [i.level for i in intervals[:-1] if i.level is not None and i.cause != "start"]
        mine = pi[begin:][used[begin:]]
        if not levels or mine.size == 0:
            return None
        a = float(np.median(levels))
        r = float(np.median(mine)) / a
        spread = 1.4826 * float(np.median(np.abs(mine - np.median(mine)))) / a
        half = 2.0 * max(spread, 0.01) / math.sqrt(mine.size)
        lo, hi = r - half, r + half
        e = np.where(np.isfinite(expected[begin:]), expected[begin:], 0.0)
        lost = float(np.sum(e * a * (1.0 - r)))
        rate = None
    clean = typical * a
    return Current(
        day=int(days[-1]),
        since=last.start,
        cause=last.cause,
        ratio=r,
        low=min(lo, hi),
        high=max(lo, hi),
        rate=rate,
        clean_kwh_per_day=clean,
        loss_kwh_per_day=clean * (1.0 - r),
        loss_since_cleaning_kwh=lost,
    )


HORIZON_DAYS = 3650
"""A day cleaning would pay further ahead than this is no date."""


@dataclass(frozen=True, slots=True)
class Recommendation:
    clean: bool
    by: int | None
    """The day [ordinal] cleaning starts to pay (today when it already does); None when the
    output shows no soiling to pay for."""
    reason: str
    optimal_days: float | None
    """``τ*``, the cleaning interval of least cost per day [days]."""
    lost_value: float
    """Value of the energy lost since the last cleaning [currency]."""


def recommend(current: Current, *, price_per_kwh: float, cleaning_cost: float) -> Recommendation:
    """Whether to clean now, and from when it pays: clean once the value lost since the last
    cleaning reaches ``cleaning_cost``, the interval ``τ* = √(2C / (ρ E P))`` of least cost
    per day for dust that builds up linearly (module docstring)."""
    lost = current.loss_since_cleaning_kwh * price_per_kwh
    rho = -current.rate if current.rate is not None else None
    worth = rho * current.clean_kwh_per_day * price_per_kwh if rho is not None else 0.0
    optimal = math.sqrt(2.0 * cleaning_cost / worth) if worth > 0 else None
    if lost >= cleaning_cost:
        return Recommendation(
            True,
            current.day,
            f"the energy lost since {_date(current.since)} is worth {lost:.2f}, more than the "
            f"cleaning's cost of {cleaning_cost:.2f}",
            optimal,
            lost,
        )
    if current.rate is None:
        return Recommendation(
            False,
            None,
            f"too few days of output since {_date(current.since)} to measure how fast dust "
            f"builds up (it takes {MIN_DAYS})",
            None,
            lost,
        )
    if rho is None or worth <= 0 or current.high >= 1.0:
        return Recommendation(
            False,
            None,
            f"the output shows no soiling it can tell from noise since {_date(current.since)}",
            None,
            lost,
        )
    # the day the lost value reaches C: V(t) = V_now + ρEP (t² − t_now²) / 2
    t_now = current.day - current.since
    t_due = math.sqrt(t_now**2 + 2.0 * (cleaning_cost - lost) / worth)
    if t_due - t_now > HORIZON_DAYS:
        return Recommendation(
            False,
            None,
            f"losing {100 * rho:.3f} % a day, the energy lost since {_date(current.since)} "
            f"would take more than {HORIZON_DAYS // 365} years to be worth the cleaning's "
            f"{cleaning_cost:.2f}",
            optimal,
            lost,
        )
    by = current.since + math.ceil(t_due)
    return Recommendation(
        False,
        by,
        f"the energy lost since {_date(current.since)} is worth {lost:.2f} of the cleaning's "
        f"{cleaning_cost:.2f}; at {100 * rho:.2f} % a day it pays from {_date(by)}"
        if rho is not None
        else f"the energy lost is worth {lost:.2f} of the cleaning's {cleaning_cost:.2f}",
        optimal,
        lost,
    )


def _date(ordinal: int) -> str:
    return date.fromordinal(ordinal).isoformat()
