"""Is a frame fit to be judged at all? Night, glare, blank and occluded frames are not.

Decided from the channel histograms (no second pass over the pixels), so it costs next to
nothing; only a sky camera's test for foliage looks at pixels, a subsample of ~5,000. The
thresholds are generous: the gate is for frames no classifier should see, not for borderline
ones.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from app.platform.frames.stats import ChannelStats


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
    foliage_fraction: float | None = None
    """More than this fraction of the region's pixels green before red and blue (by
    ``FOLIAGE_MARGIN`` levels each): leaves in front of the lens or grown into the view. None:
    not tested (a panel camera's view may well be green)."""


DEFAULT_LIMITS = QualityLimits()

SKY_LIMITS = QualityLimits(glare_fraction=0.80, blank_std=0.5, foliage_fraction=0.25)
"""For sky cameras, whose worst air is the frame the panel limits took for a fault. Smog is a
white, even sky: on the labelled photos (``../shared/data/sky``, the sky regions of
``bench/airquality_eval.py``), the panel limits refused 5 of 90, every one of them Severe or
of the higher PM2.5 of Milan: a Severe sky in Uttar Pradesh as "blank" (its channels' spread
at most 1.4 levels) and four as "glare" (28–56 % of the region at 250 or more). Their level
was null, and the air's worst hours went unreported (and could not be calibrated). Here a sky
is blank only when flat, as a camera's fault frame is (spread under 0.5 levels in every
channel), and overexposed only when four fifths of it are at the ceiling.

A sky is not green: in those 90 regions at most 4.1 % of the pixels are green before red and
blue (``obstruction_reason``), against 40–60 % in the band of trees below Milan's skyline
(rows 70–92 %) in nine of its 16 frames, 27 % in one, 0.5–14 % in the six others (bare
branches in January–March). A sky region more than a quarter green is foliage, not air."""


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


FOLIAGE_MARGIN = 8
"""A pixel is foliage when its green exceeds both its red and its blue by more than this."""
_SAMPLES = 5_000
"""Pixels looked at for the foliage test: a regular subsample of larger regions."""


def obstruction_reason(
    region: NDArray[np.uint8], limits: QualityLimits = DEFAULT_LIMITS
) -> str | None:
    """Why the region (RGB, (H, W, 3), or a polygon's pixels as (N, 1, 3)) is not the view it
    should be, beyond what the histograms tell (``unusable_reason``), or None.

    The joint test of a pixel's channels needs the pixels, not the histograms: it looks at a
    regular subsample of about ``_SAMPLES`` of them, so it costs the same for any region. For a
    region declared as sky only: a whole street view may well be a fifth trees.
    """
    if limits.foliage_fraction is None or region.size == 0:
        return None
    h, w = region.shape[:2]
    step = max(1, int((h * w / _SAMPLES) ** 0.5))
    sample = region[:: step * step] if w == 1 else region[::step, ::step]
    px = sample.reshape(-1, 3).astype(np.int16)
    green = px[:, 1] - FOLIAGE_MARGIN
    share = float(np.count_nonzero((green > px[:, 0]) & (green > px[:, 2]))) / len(px)
    if share > limits.foliage_fraction:
        return f"obstructed: {100 * share:.0f}% of the region is foliage"
    return None
