"""Air quality from the sky: [Fayed 2013] chapter 6.

Street cameras photograph the sky; haze raises the red and green modes of the sky region and
lowers the blue one. Labelled images (levels 1–10 measured by reference instruments) make one
cluster per level — its mean mode vector and covariance (eqs. 6.12–6.13) — and a new frame falls
in the level whose T² test accepts it (6.19–6.22; as in chapter 5, eq. 6.23 is not equivalent
to 6.22 and is not used). The statistics are hotelling's (platform): the same Theorem 2.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from datetime import UTC, datetime, timedelta
from functools import lru_cache
from typing import Any

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.stats import t as t_dist

from app.air.core import breakpoints
from app.platform.frames.stats import channel_histograms
from app.stats import hotelling

LEVELS = range(1, 11)
CATEGORIES = (
    (9, "Very Good"),
    (7, "Good"),
    (5, "Fair"),
    (3, "Poor"),
    (1, "Very Poor"),
)
"""Lowest level of each category: 9–10 Very Good, 7–8 Good, 5–6 Fair, 3–4 Poor, 1–2 Very Poor."""
MIN_CLUSTER = 5
"""A level needs this many images for its own cluster (F(3, n − 3) with n − 3 ≥ 2)."""


def rounded(level: float) -> int:
    """A fractional level (a smoothed one) as the level 1–10 it is reported as: halves up."""
    if not np.isfinite(level) or not 0.5 <= level < 10.5:
        raise ValueError(f"level must lie in 1–10; got {level}")
    return int(np.floor(level + 0.5))


def category(level: float) -> str:
    """The category of a level 1–10 (fractional levels are rounded first)."""
    return next(name for lowest, name in CATEGORIES if rounded(level) >= lowest)


ALERT_CATEGORIES = ("Poor", "Very Poor")


ALERT_REARM = 0.5
"""Hysteresis of alerts [level]: once a camera's smoothed level has entered an alert category,
entering it again alerts only after the level has climbed this far above the category's upper
edge (to 5.0 for Poor, 3.0 for Very Poor). Air hovering on an edge — readings alternating 4 and
5 smooth to 4.3–4.5, and 4.5 is Fair — otherwise crosses it every hour or so, and each crossing
was a new alert and webhook for the same episode."""


CLEAR_LEVEL = 4.5 + ALERT_REARM
"""A camera's raised alert is cleared when its smoothed level reaches this (Fair, clear of
Poor by ``ALERT_REARM``): the level at which entering Poor alerts again."""


def alert_category(smoothed: float, earlier: Iterable[float]) -> str | None:
    """The category to raise an alert for when a camera's smoothed level becomes ``smoothed``
    after ``earlier`` (its earlier smoothed levels, newest first): entering Poor or Very Poor
    from a better category (Poor from Fair, Very Poor from Poor or better); None otherwise.

    Judged by ``category`` alone, so an alert never names a category it is not about (a level
    of exactly 4.5 is Fair). "From a better category" is the newest earlier level outside the
    dead band [edge, edge + ``ALERT_REARM``) above the category: at or above it, the camera
    came from clearer air; below the edge, it was already in the category (or worse) and this
    is the same episode. No earlier level outside the band (a camera's first): an alert."""
    now = category(smoothed)
    if now not in ALERT_CATEGORIES:
        return None
    lowest = next(lowest for lowest, name in CATEGORIES if name == now)
    edge = next(lo for lo, _ in reversed(CATEGORIES) if lo > lowest) - 0.5  # 4.5 for Poor
    for level in earlier:
        if level >= edge + ALERT_REARM:
            return now
        if level < edge:
            return None
    return now


def message(name: str) -> str:
    return f"Today's Air Quality is {name}"


@dataclass(frozen=True, slots=True)
class Cluster:
    levels: tuple[int, ...]
    """The calibration levels pooled into this cluster (one, unless too few images)."""
    level: int
    """The level the cluster reports (the median of its images' levels)."""
    baseline: hotelling.Baseline


@dataclass(frozen=True, slots=True)
class Calibration:
    clusters: tuple[Cluster, ...]
    warnings: tuple[str, ...] = field(default_factory=tuple)


def level_clusters(
    modes: ArrayLike, levels: ArrayLike, *, significance: float = 0.05, shrinkage: float = 0.0
) -> Calibration:
    """One cluster per level (eqs. 6.12–6.13); levels with fewer than ``MIN_CLUSTER`` images are
    pooled with their nearest neighbour (a warning says which). A cluster whose Σ̂ is singular
    or ill-conditioned (its images share a mode in some channel) gets the quantisation
    variance, 1/12 level², on its diagonal, with a warning; eq. 6.13 is unchanged otherwise.

    Raises hotelling.BaselineError when a cluster's covariance is singular even so.
    """
    x = np.asarray(modes, dtype=np.float64)
    lv = np.asarray(levels, dtype=np.int64)
    if x.ndim != 2 or x.shape[1] != 3 or len(lv) != len(x):
        raise ValueError(f"need modes (n, 3) and n levels; got {x.shape} and {lv.shape}")
    if not set(lv.tolist()) <= set(LEVELS):
        raise ValueError("levels must be integers 1–10")
    groups: list[list[int]] = [[int(v)] for v in sorted(set(lv.tolist()))]
    warnings = []
    while True:
        sizes = [int(np.isin(lv, g).sum()) for g in groups]
        small = [i for i, n in enumerate(sizes) if n < MIN_CLUSTER]
        if not small or len(groups) == 1:
            break
        i = small[0]
        # pool with the neighbour whose levels are closest (ties: the smaller group)
        cands = [j for j in (i - 1, i + 1) if 0 <= j < len(groups)]
        j = min(cands, key=lambda k: (abs(np.mean(groups[k]) - np.mean(groups[i])), sizes[k]))
        warnings.append(
            f"level(s) {groups[i]} had {sizes[i]} images (< {MIN_CLUSTER}); pooled with {groups[j]}"
        )
        a, b = sorted((i, j))
        groups[a : b + 1] = [sorted(groups[a] + groups[b])]
    clusters = []
    for g in groups:
        members = np.isin(lv, g)
        named = f"level {g[0]}" if len(g) == 1 else f"levels {g} (pooled)"
        try:
            baseline = hotelling.fit_baseline(
                x[members], significance=significance, shrinkage=shrinkage
            )
        except hotelling.BaselineError as exc:
            if shrinkage >= hotelling.QUANTISATION_VARIANCE:  # say which of up to ten it is
                raise hotelling.BaselineError(f"{named}: {exc}") from exc
            # one grey sky at several exposures shares one mode vector: the modes are whole
            # levels, so each channel carries at least the rounding's variance, 1/12 level²
            try:
                baseline = hotelling.fit_baseline(
                    x[members],
                    significance=significance,
                    shrinkage=hotelling.QUANTISATION_VARIANCE,
                )
            except hotelling.BaselineError as again:
                raise hotelling.BaselineError(f"{named}: {again}") from again
            warnings.append(
                f"{named}: {exc} — 1/12 level² (the variance of rounding modes to whole "
                "levels) added to its covariance's diagonal"
            )
        clusters.append(Cluster(tuple(g), int(np.median(lv[members])), baseline))
    return Calibration(tuple(clusters), tuple(warnings))


@dataclass(frozen=True, slots=True)
class Grade:
    level: int | None
    statistic: float | None
    """F of the chosen cluster (eq. 6.20)."""
    p_value: float | None
    reason: str | None = None


def grade(calibration: Calibration, modes: ArrayLike) -> Grade:
    """The level whose cluster's T² test accepts the mode vector (eqs. 6.19–6.22); of several,
    the smallest F; of none, no level ("outside calibration") rather than a guess."""
    if not calibration.clusters:  # a regression's, made without them
        return Grade(None, None, None, "the calibration has no clusters to grade modes by")
    results = [(c, hotelling.classify(c.baseline, modes)) for c in calibration.clusters]
    accepted = [(c, r) for c, r in results if r.clean]  # F < F₍₃,ₙ₋₃,ς₎ (6.21–6.22)
    if not accepted:
        best = min(results, key=lambda cr: cr[1].f_stat)[1]
        return Grade(
            None, best.f_stat, best.p_value, "outside calibration: no level's test accepts"
        )
    c, r = min(accepted, key=lambda cr: cr[1].f_stat)
    return Grade(c.level, r.f_stat, r.p_value)


NOWCAST_HOURS = 12
FRESH = timedelta(hours=3)
"""A smoothed level needs a reading this recent (the official NowCast wants two of the last
three hours); a camera's latest reading older than this is not today's air."""


_MICROSECOND = timedelta(microseconds=1)
_EPOCH = datetime(1970, 1, 1, tzinfo=UTC)


def _microseconds(times: Iterable[datetime]) -> NDArray[np.int64]:
    """Exact integers, so that a reading exactly k hours old falls in hour k as it does in
    datetime arithmetic (float seconds round at the microseconds of today's epochs)."""
    return np.array([(t - _EPOCH) // _MICROSECOND for t in times], dtype=np.int64)


def nowcasts(
    times: Sequence[datetime], levels: Sequence[float], at: Sequence[datetime]
) -> list[float | None]:
    """A NowCast-style smoothed level at each of ``at`` from the readings (``times``,
    ``levels``) taken up to it: hourly means of the 12 hours before weighted wᵏ for the hour k
    ago, w = max(min/max of the hourly means, 0.5) — steady air weighs history, changing air
    weighs the latest hours (as the official NowCast for PM2.5). None without a reading in the
    3 hours before (the official rule wants two of the last three).

    All at once, so that a reading taken late re-smooths the readings after it: the hour k
    before ``a`` holds the readings
    taken in (a − (k+1) h, a − k h], so each hour's count and sum are differences of the
    sorted readings' running count and sum at 13 boundaries: O((m + n) log n) for m times and
    n readings, not m × n."""
    if len(times) != len(levels):
        raise ValueError(f"{len(times)} times but {len(levels)} levels")
    if not at:
        return []
    t = _microseconds(times)
    order = np.argsort(t, kind="stable")
    t = t[order]
    v = np.asarray(levels, dtype=np.float64)[order]
    running = np.concatenate(([0.0], np.cumsum(v)))
    hour = timedelta(hours=1) // _MICROSECOND
    bounds = _microseconds(at)[:, None] - hour * np.arange(NOWCAST_HOURS + 1)  # m × 13
    upto = np.searchsorted(t, bounds, side="right")  # readings taken at or before each bound
    counts = upto[:, :-1] - upto[:, 1:]  # m × 12: hour k is (bound k+1, bound k]
    sums = running[upto[:, :-1]] - running[upto[:, 1:]]
    fresh = counts[:, : int(FRESH / timedelta(hours=1))].any(axis=1)
    out: list[float | None] = [None] * len(at)
    powers = np.arange(NOWCAST_HOURS)
    for i in np.flatnonzero(fresh):
        present = counts[i] > 0
        means = sums[i, present] / counts[i, present]
        lo, hi = means.min(), means.max()
        w = max(lo / hi if hi > 0 else 1.0, 0.5)
        weights = w ** powers[present]
        out[i] = float(weights @ means / weights.sum())
    return out


SKYLINE_HEIGHT = 0.38
"""The skyline strip under the sky region, as a fraction of the frame's height: the distant
skyline first, nearer buildings lower down."""
SKYLINE_BANDS = ((0.0, 0.17), (0.17, 0.34), (0.42, 0.66), (0.66, 1.0))
"""Bands of the skyline strip (fractions of its height), farthest first: haze fades far
objects more than near ones (eq. below), so each band's contrast carries its own distance."""
SKYLINE_QUANTILES = (5, 20)
"""Percentiles [%] of a band's pixels taken as its dark objects (buildings against the sky)."""

SKY_FEATURES = (
    "mode_r",
    "mode_g",
    "mode_b",
    "mean_r",
    "mean_g",
    "mean_b",
    "blue_red_ratio",
    "darkest_median",
    "spread",
    "skyline_std",
    "skyline_laplacian",
    *(
        f"log_contrast_band{b}_p{q}_{c}"
        for b in range(len(SKYLINE_BANDS))
        for q in SKYLINE_QUANTILES
        for c in "rgb"
    ),
    "log_sky_median_r",
    "log_sky_median_g",
    "log_sky_median_b",
    *(f"log_edges_band{b}" for b in range(len(SKYLINE_BANDS))),
)
"""The regression's features, in order: a stored feature vector of another set was made by
an earlier version and is measured again (``POST /air/cameras/{id}/regrade``)."""

MIN_CONTRAST = 1e-3
"""Apparent contrasts are clipped to this before their logarithm (an object as bright as the
sky has none)."""


BAND_PIXELS = 1 << 20
"""Pixels of the region taken at a time for its darkest channel."""


def _darkest_histogram(sky: NDArray[np.uint8]) -> NDArray[np.float64]:
    """Histogram of each pixel's darkest channel, a band of rows at a time. ``cv2.min`` of the
    channels' views copied each channel whole first: three copies of a 36 MP region at once,
    ~100 MiB (as much again as the decoded frame), and 0.58 against 0.34 ms at 640×480."""
    h, w = sky.shape[:2]
    rows = max(1, BAND_PIXELS // max(w, 1))
    hist = np.zeros(256)
    for top in range(0, h, rows):
        band = sky[top : top + rows]
        lo = np.minimum(band[..., 0], band[..., 1])
        np.minimum(lo, band[..., 2], out=lo)
        hist += cv2.calcHist([lo], [0], None, [256], [0, 256]).ravel()
    return hist


def _percentile(hist: NDArray[Any], q: float) -> float:
    """The lowest level at or below which ``q`` % of a histogram's pixels lie."""
    cdf = np.cumsum(hist)
    return float(np.searchsorted(cdf, q / 100 * cdf[-1]))


def log_contrasts(
    sky_median: NDArray[np.float64], strip: NDArray[np.uint8] | None
) -> NDArray[np.float64]:
    """ln of the apparent contrast of each skyline band's dark objects against the sky, per
    channel: C = (L_sky − L_q) / (L_sky + 1) for the band's ``SKYLINE_QUANTILES`` percentiles
    L_q (grey levels), clipped at ``MIN_CONTRAST``. Shape (bands × quantiles × 3,).

    Not in [Fayed 2013]: Koschmieder's law (Middleton, *Vision through the Atmosphere*,
    1952, ch. 5) gives the contrast of a dark object at distance d as C = C₀·e^(−b·d), b the
    extinction coefficient that fine particles raise, so ln C falls linearly with the haze,
    faster for farther bands. All from histograms: no float copy of the strip."""
    n = len(SKYLINE_BANDS) * len(SKYLINE_QUANTILES) * 3
    if strip is None or strip.shape[0] < len(SKYLINE_BANDS):
        return np.full(n, np.log(MIN_CONTRAST))
    h = strip.shape[0]
    out = []
    for lo, hi in SKYLINE_BANDS:
        band = strip[int(lo * h) : max(int(hi * h), int(lo * h) + 1)]
        hists = [cv2.calcHist([band], [c], None, [256], [0, 256]).ravel() for c in range(3)]
        for q in SKYLINE_QUANTILES:
            for c in range(3):
                dark = _percentile(hists[c], q)
                contrast = (sky_median[c] - dark) / (sky_median[c] + 1)
                out.append(np.log(max(contrast, MIN_CONTRAST)))
    return np.array(out)


EDGE_WIDTH = 480
"""Width [px] the skyline strip is area-averaged to before its edges are measured (never
enlarged): one scale of detail whatever the camera's resolution. With widths of 320–960 px the
Milan webcam's held-out days were ranked within 0.008 of each other (bench/README.md)."""
MIN_GRADIENT = 1e-3
"""Mean gradients [grey level/px] are clipped to this before their logarithm (a flat band)."""


def luma(image: NDArray[np.uint8]) -> NDArray[np.float32]:
    """BT.601 luma of an RGB image (H, W, 3), uint8, as float32 (H, W), channel by channel:
    no float copy of all three channels at once."""
    grey = image[..., 0] * np.float32(0.299)
    grey += image[..., 1] * np.float32(0.587)
    grey += image[..., 2] * np.float32(0.114)
    return grey


def skyline_edges(grey: NDArray[np.float32] | None) -> NDArray[np.float64]:
    """ln of the mean gradient magnitude [grey level/px] of the skyline strip's luma ``grey``
    (H, W; ``luma``) in each of the ``SKYLINE_BANDS``, the strip area-averaged to
    ``EDGE_WIDTH`` px across; Sobel's 3×3 derivative scaled by 1/8, so a ramp of slope s gives
    s. Shape (bands,).

    Not in [Fayed 2013]: haze veils an object of contrast C₀ at distance d to
    C₀·e^(−b·d) (Koschmieder; Middleton, *Vision through the Atmosphere*, 1952, ch. 5), and a
    veil scales every gradient of the object alike, so ln |∇L| falls by b·d: the edges of
    windows, roofs and masts, where ``log_contrasts`` sees only a band's darkest pixels."""
    n = len(SKYLINE_BANDS)
    if grey is None or grey.shape[0] < n:
        return np.full(n, np.log(MIN_GRADIENT))
    h, w = grey.shape
    k = min(1.0, EDGE_WIDTH / w)
    small = cv2.resize(
        grey, (max(1, round(w * k)), max(n, round(h * k))), interpolation=cv2.INTER_AREA
    )
    gx = cv2.Sobel(small, cv2.CV_32F, 1, 0, scale=1 / 8)
    gy = cv2.Sobel(small, cv2.CV_32F, 0, 1, scale=1 / 8)
    magnitude = cv2.magnitude(gx, gy)
    rows = magnitude.shape[0]
    out = []
    for lo, hi in SKYLINE_BANDS:
        band = magnitude[int(lo * rows) : max(int(hi * rows), int(lo * rows) + 1)]
        out.append(np.log(max(float(band.mean()), MIN_GRADIENT)))
    return np.array(out)


def sky_features(
    sky: NDArray[np.uint8],
    below: NDArray[np.uint8] | None = None,
    histograms: NDArray[np.int64] | None = None,
) -> NDArray[np.float64]:
    """``SKY_FEATURES`` of a sky region (RGB, uint8) and of the skyline strip below it for the
    regression that improves on the clusters: modes, means, blue-to-red ratio, median of the
    darkest channel, spread; the strip's contrast (0 without one) and the log contrasts of
    its bands (``log_contrasts``); ln of the sky's median per channel; the log gradients of the
    strip's bands (``skyline_edges``).

    ``histograms``: the region's channel histograms (3, 256) when already computed. Everything
    comes from histograms and uint8 or float32 single-channel arrays: a float64 copy of a 36 MP
    region and its temporaries took ~2 GB of memory.
    """
    hist = channel_histograms(sky) if histograms is None else histograms
    levels = np.arange(256, dtype=np.float64)
    n = float(hist[0].sum())
    modes = hist.argmax(axis=1)
    means = hist @ levels / n
    spread = np.sqrt(np.maximum(hist @ levels**2 / n - means**2, 0.0)).mean()
    medians = np.array([_median(h) for h in hist])
    contrast = [0.0, 0.0]
    grey = luma(below) if below is not None and below.size else None
    if grey is not None:
        # the second difference down the columns, in place
        lap = 0.0
        if grey.shape[0] > 2:
            d = grey[2:] - grey[1:-1]
            d -= grey[1:-1]
            d += grey[:-2]
            lap = float(np.abs(d, out=d).mean())
        contrast = [float(grey.std()), lap]
    return np.array(
        [
            *modes,
            *means,
            (means[2] + 1) / (means[0] + 1),
            _median(_darkest_histogram(sky)),
            spread,
            *contrast,
            *log_contrasts(medians, below),
            *np.log(medians + 1),
            *skyline_edges(grey),
        ]
    )


def _median(hist: NDArray[Any]) -> float:
    """``np.median`` of the values a histogram of 0–255 counts (the mean of the two middle ones
    for an even count)."""
    cdf = np.cumsum(hist)
    n = int(cdf[-1])
    upper = int(np.searchsorted(cdf, n // 2 + 1))  # the value at sorted position n // 2
    if n % 2:
        return float(upper)
    lower = int(np.searchsorted(cdf, n // 2))  # at position n // 2 − 1
    return (lower + upper) / 2


UNITS = ("level", "pm25", "aqi")
"""What a regression is fitted in: the levels themselves, or the reference PM2.5 [µg/m³] or
US AQI, whose levels come from ``breakpoints`` (fitted as ln(1 + value): haze's extinction,
and so the log contrasts, grow with the concentration's logarithm far better than with it)."""
INTERVAL = 0.8
"""Coverage of a verdict's prediction interval."""

MIN_GROUPS = 3
"""Groups (days) a regression needs to leave one out at a time; with fewer, images."""


def groups_left_out(groups: Sequence[str] | None) -> int | None:
    """How many groups ``fit_regression`` leaves out one at a time, or None when it leaves out
    images (no groups, or fewer than ``MIN_GROUPS``)."""
    n = 0 if groups is None else len(set(groups))
    return n if n >= MIN_GROUPS else None


@lru_cache(maxsize=256)
def t_quantile(dof: float) -> float:
    """Student's t quantile of the ``INTERVAL`` interval: one per calibration, not one SciPy
    call (~0.1 ms) per frame."""
    return float(t_dist.ppf((1 + INTERVAL) / 2, dof))


def level_of(value: float, unit: str, table: str = "us_epa") -> int:
    """The level 1–10 of an estimate in ``unit``; PM2.5 by the breakpoint ``table``
    (``breakpoints.TABLES``)."""
    if unit == "pm25":
        return breakpoints.level_of_pm25(max(value, 0.0), table)
    if unit == "aqi":
        return breakpoints.level_of_aqi(max(value, 0.0))
    return int(np.clip(np.rint(value), 1, 10))


@dataclass(frozen=True, slots=True)
class Estimate:
    """A regression's verdict on one frame."""

    level: int
    value: float
    """The estimate in the regression's unit (level, PM2.5 µg/m³ or AQI)."""
    low: float | None
    high: float | None
    """The ``INTERVAL`` prediction interval in that unit (None for a model without one)."""
    leverage: float | None
    """h = z·(ZᵀZ + αI)⁻¹·z of the frame's standardised features."""
    uncertain: str | None
    """Why the level is not to be trusted, or None."""
    outside: bool = False
    """The frame lies outside the calibration: its level is a guess beyond what was learnt,
    not an estimate with a wide interval."""
    span: tuple[str, str] | None = None
    """The clearest and the worst category of the interval when they differ (inside the
    calibration)."""
    loc: float = 0.0
    scale: float | None = None
    """The predictive t's centre and scale in the fitted unit (ln(1 + unit), or levels):
    ŷ and σ·√(1 + 1/n + h); None for a model without an interval."""


@dataclass(frozen=True, slots=True)
class Regression:
    """Standardised ridge regression of the level (or of ln(1 + reference)) on
    ``SKY_FEATURES``, with what its prediction intervals need."""

    mean: NDArray[np.float64]
    scale: NDArray[np.float64]
    coef: NDArray[np.float64]
    intercept: float
    unit: str = "level"
    gram_inv: NDArray[np.float64] | None = None
    """(ZᵀZ + αI)⁻¹ of the standardised training features, p × p."""
    n: int = 0
    sigma: float | None = None
    """Residual scale on data it was not fitted to (grouped or leave-one-out), fitted unit."""
    dof: float = 1.0
    """Residual degrees of freedom, n − tr(H); with days left out, at most the days less one
    (the held-out residuals' independent units)."""
    max_leverage: float | None = None
    """The largest leverage a training image has against the others, hᵢ/(1 − hᵢ) (its
    leverage in the fit that leaves it out): a frame farther out than any image was from the
    rest is extrapolation."""
    table: str = "us_epa"
    """The breakpoint table (``breakpoints.TABLES``) its PM2.5 estimates become levels by."""
    day_share: float = 1.0
    """The share of the held-out residuals' variance common to a day's frames (1 − the
    within-day variance over the total; 1 when images, not days, were left out): how much
    averaging a day's frames narrows an estimate's range (``public.smooth``)."""
    columns: tuple[int, ...] | None = None
    """Positions in a ``SKY_FEATURES`` vector of the features it was fitted on, in its order,
    when those are fewer (made before features were added); None: all of them."""

    def _fitted(self, features: ArrayLike) -> tuple[float, NDArray[np.float64]]:
        x = np.asarray(features, dtype=np.float64)
        if self.columns is not None:
            x = x[list(self.columns)]
        z = (x - self.mean) / self.scale
        return float(z @ self.coef) + self.intercept, z

    def _out(self, y: float) -> float:
        return float(np.expm1(y)) if self.unit != "level" else y

    def level(self, features: ArrayLike) -> int:
        return self.estimate(features).level

    def estimate(self, features: ArrayLike) -> Estimate:
        """The level, the estimate in the reference unit with its prediction interval
        ŷ ± t₍dof₎·σ·√(1 + 1/n + h) (ridge's bias neglected), and whether to doubt it: the
        frame lies outside the calibration — its leverage h = z·(ZᵀZ + αI)⁻¹·z above every
        training image's leverage against the others (Montgomery, Peck & Vining,
        *Introduction to Linear Regression Analysis*, 5th ed., §3.8, hidden extrapolation;
        hᵢ/(1 − hᵢ) is image i's leverage in the fit without it, so a calibration of few
        images in many features is not refused everything it did not see) — or the
        interval's two ends fall in different categories."""
        y, z = self._fitted(features)
        value = self._out(y)
        level = level_of(value, self.unit, self.table)
        if self.gram_inv is None or self.sigma is None or self.max_leverage is None:
            return Estimate(level, value, None, None, None, None, loc=y)
        h = float(z @ self.gram_inv @ z)
        scale = self.sigma * float(np.sqrt(1 + 1 / max(self.n, 1) + h))
        half = t_quantile(max(self.dof, 1.0)) * scale
        low, high = sorted((self._out(y - half), self._out(y + half)))
        uncertain = None
        outside = not np.isfinite(h) or h > self.max_leverage
        if outside:
            uncertain = (
                f"outside the calibration: leverage {h:.3g} above the largest of its images "
                f"({self.max_leverage:.3g})"
            )
        worst, clearest = sorted(level_of(v, self.unit, self.table) for v in (low, high))
        span: tuple[str, str] | None = None
        if not outside and category(worst) != category(clearest):
            span = (category(clearest), category(worst))
            uncertain = f"the {INTERVAL:.0%} interval spans {span[1]} to {span[0]}"
        return Estimate(level, value, low, high, h, uncertain, outside, span, y, scale)


def fit_regression(
    features: ArrayLike,
    targets: ArrayLike,
    *,
    unit: str = "level",
    groups: Sequence[str] | None = None,
    alphas: ArrayLike | None = None,
    table: str = "us_epa",
) -> tuple[Regression, float]:
    """Ridge regression of ``targets`` (levels, or reference values in ``unit``) on the
    features, and its penalty α. α and σ for the intervals both come from data the fit did not
    see: leave one group (a day of frames) out when ``groups`` has at least 3, else leave one
    image out (scikit-learn's efficient leave-one-out; optimistic when images are
    near-duplicates: frames of one day share their weather, so leaving one out rewards a fit
    that remembers the day, and picks too small an α)."""
    from sklearn.linear_model import RidgeCV
    from sklearn.model_selection import LeaveOneGroupOut
    from sklearn.preprocessing import StandardScaler

    x = np.asarray(features, dtype=np.float64)
    t = np.asarray(targets, dtype=np.float64)
    if unit not in UNITS:
        raise ValueError(f"unit must be one of {UNITS}")
    if table not in breakpoints.TABLES or (table != "us_epa" and unit != "pm25"):
        raise ValueError(f"table {table!r} does not map {unit} to levels")
    y = np.log1p(t) if unit != "level" else t
    scaler = StandardScaler().fit(x)
    scale = np.where(scaler.scale_ > 0, scaler.scale_, 1.0)
    z = (x - scaler.mean_) / scale
    grid = np.logspace(-2, 3, 30) if alphas is None else np.asarray(alphas)
    by_day = groups_left_out(groups) is not None
    if by_day:
        days = list(LeaveOneGroupOut().split(z, y, np.asarray(groups)))
        model = RidgeCV(alphas=grid, cv=days, scoring="neg_mean_squared_error").fit(z, y)
    else:
        model = RidgeCV(alphas=grid).fit(z, y)
    alpha = float(model.alpha_)
    n, p = z.shape
    zc = z - z.mean(axis=0)  # the features are standardised: already centred
    gram_inv = np.linalg.inv(zc.T @ zc + alpha * np.eye(p))
    lev = np.einsum("ij,jk,ik->i", zc, gram_inv, zc)
    fitted = model.predict(z)
    if by_day:
        g = np.asarray(groups)
        held = np.empty(n)
        for name in set(g.tolist()):
            out = g == name
            m = RidgeCV(alphas=[alpha]).fit(z[~out], y[~out])
            held[out] = m.predict(z[out])
        residuals = y - held
        within = sum(
            float(((residuals[g == d] - residuals[g == d].mean()) ** 2).sum())
            for d in set(g.tolist())
        )
        total = float(((residuals - residuals.mean()) ** 2).sum())
        day_share = float(np.clip(1 - within / total, 0.0, 1.0)) if total > 0 else 1.0
    else:
        day_share = 1.0
        # the closed-form leave-one-out residual (hat value with the intercept's 1/n)
        residuals = (y - fitted) / np.maximum(1 - lev - 1 / n, 1e-6)
    dof = max(n - 1 - float(lev.sum()), 1.0)
    if by_day:  # σ is measured on days left out, and a day's frames err alike: its
        # independent units are the days, not the frames
        dof = min(dof, float(len(set(np.asarray(groups).tolist())) - 1))
    reg = Regression(
        mean=scaler.mean_.astype(np.float64),
        scale=scale.astype(np.float64),
        coef=np.asarray(model.coef_, dtype=np.float64),
        intercept=float(model.intercept_),
        unit=unit,
        gram_inv=gram_inv,
        n=n,
        sigma=float(np.sqrt(np.mean(residuals**2))),
        dof=dof,
        max_leverage=float(np.max(lev / np.maximum(1 - lev - 1 / n, 1e-6))),
        table=table,
        day_share=day_share,
    )
    return reg, alpha
