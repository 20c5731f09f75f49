"""Is a frame fit to be judged at all? Night, glare, blank and occluded frames are not.

Decided from the channel histograms alone (no second pass over the pixels), so it costs next to
nothing. The thresholds are generous: the gate is for frames no classifier should see, not for
borderline ones.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

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


def _percentile(hist: NDArray[np.int64], q: float) -> NDArray[np.int64]:
    """Per-channel level below which a fraction ``q`` of the pixels lie; hist (3, 256)."""
    cdf = np.cumsum(hist, axis=1)
    target = q * cdf[:, -1:]
    return np.asarray((cdf < target).sum(axis=1), dtype=np.int64)


def unusable_reason(stats: ChannelStats, limits: QualityLimits = DEFAULT_LIMITS) -> str | None:
    """Why the frame cannot be judged, or None when it can."""
    hist = stats.histograms
    total = hist.sum(axis=1).astype(np.float64)
    levels = np.arange(256, dtype=np.float64)
    means = stats.means
    std = np.sqrt((hist * (levels - means[:, None]) ** 2).sum(axis=1) / total)
    p95 = _percentile(hist, 0.95)
    if (p95 < limits.night_p95).all():
        return f"too dark to judge (night?): 95% of pixels below level {int(p95.max()) + 1}"
    if (std < limits.blank_std).all():
        return "blank frame: no detail in any channel (lens covered or camera fault?)"
    saturated = hist[:, 250:].sum(axis=1) / total
    if saturated.max() > limits.glare_fraction:
        return f"glare: {100 * saturated.max():.0f}% of the region is saturated"
    spread = means.max() - means.min()
    if spread < limits.grey_mean_diff and np.abs(hist[0] - hist[1]).sum() < 0.02 * total[0]:
        return "greyscale frame (camera in night mode?)"
    dark = hist[:, :12].sum(axis=1) / total
    if dark.min() > limits.occluded_dark_fraction:
        return f"occluded: {100 * dark.min():.0f}% of the region is black"
    return None
