"""Is a frame fit to be judged at all? Night, glare, blank and occluded frames are not.

Decided from the channel histograms alone (no second pass over the pixels), so it costs next to
nothing. The thresholds are generous: the gate is for frames no classifier should see, not for
borderline ones.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from app.core.stats import ChannelStats


@dataclass(frozen=True, slots=True)
class QualityLimits:
    night_p95: float = 45.0
    """Darker than this at the 95th percentile in every channel: night [level]."""
    glare_fraction: float = 0.20
    """More than this fraction of a channel at ≥ 250: glare or overexposure."""
    blank_std: float = 2.5
    """All channels with a standard deviation below this: blank, capped or frozen [level]."""
    grey_mean_diff: float = 0.75
    """Channel means closer than this: a greyscale (night-mode) frame [level]."""
    occluded_dark_fraction: float = 0.45
    """More than this fraction near black (< 12) in every channel, in a frame that is not dark
    overall (night is tested first): something is in front of the lens."""


DEFAULT_LIMITS = QualityLimits()

SKY_LIMITS = QualityLimits(glare_fraction=0.80, blank_std=0.5)
"""For sky cameras, whose worst air is the frame the panel limits took for a fault. Smog is a
white, even sky: on the labelled photos (``../shared/data/sky``, the sky regions of
``bench/airquality_eval.py``), the panel limits refused 5 of 90, every one of them Severe or
of the higher PM2.5 of Milan: a Severe sky in Uttar Pradesh as "blank" (its channels' spread
at most 1.4 levels) and four as "glare" (28–56 % of the region at 250 or more). Their level
was null, and the air's worst hours went unreported (and could not be calibrated). Here a sky
is blank only when flat, as a camera's fault frame is (spread under 0.5 levels in every
channel), and overexposed only when four fifths of it are at the ceiling."""


_LEVELS_SQUARED = np.arange(256, dtype=np.float64) ** 2


def unusable_reason(stats: ChannelStats, limits: QualityLimits = DEFAULT_LIMITS) -> str | None:
    """Why the frame cannot be judged, or None when it can.

    Every reading comes from one cumulative histogram and one product per channel, and the
    comparisons run on Python numbers: this runs for every frame, and NumPy's cost per call,
    not the arithmetic, is what it spends.
    """
    hist = stats.histograms
    cdf = hist.cumsum(axis=1)
    total = cdf[:, -1]
    # the level below which 95 % of a channel's pixels lie
    p95 = (cdf < 0.95 * total[:, None]).sum(axis=1).tolist()
    if max(p95) < limits.night_p95:
        return f"too dark to judge (night?): 95% of pixels below level {max(p95) + 1}"
    n = total.tolist()
    means = stats.means.tolist()
    # variance as E[x²] − x̄², clipped at 0 against rounding
    squares = (hist @ _LEVELS_SQUARED).tolist()
    std = [max(0.0, s / c - m * m) ** 0.5 for s, c, m in zip(squares, n, means, strict=True)]
    if max(std) < limits.blank_std:
        return "blank frame: no detail in any channel (lens covered or camera fault?)"
    saturated = max((c - below) / c for c, below in zip(n, cdf[:, 249].tolist(), strict=True))
    if saturated > limits.glare_fraction:
        return f"glare: {100 * saturated:.0f}% of the region is saturated"
    if (
        max(means) - min(means) < limits.grey_mean_diff
        and int(np.abs(hist[0] - hist[1]).sum()) < 0.02 * n[0]
    ):
        return "greyscale frame (camera in night mode?)"
    dark = min(below / c for c, below in zip(n, cdf[:, 11].tolist(), strict=True))
    if dark > limits.occluded_dark_fraction:
        return f"occluded: {100 * dark:.0f}% of the region is black"
    return None
