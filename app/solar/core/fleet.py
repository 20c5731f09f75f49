"""Features of a panel photograph for the fleet model: colour, contrast and texture.

A per-panel baseline needs clean photos of that panel; a panel without one is judged by a fleet
model trained on labelled photos of many panels. Three modes are not enough across panel types
and cameras, so the fleet model sees how saturated, how contrasted and how speckled the panel
looks. Features are computed on a copy reduced to at most ``MAX_SIDE`` pixels, which keeps the
cost well under that of decoding the frame.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

MAX_SIDE = 128
"""Long side of the reduced copy the features are computed on [px]."""

FEATURES = (
    "dark_mean",
    "dark_p50",
    "dark_p90",
    "whiteness",
    "blue_fraction",
    "min_p10",
    "min_p50",
    "grey_cv",
    "speckle_fraction",
)
"""Dust is a haze: it lifts the darkest channel of every pixel (the dark channel, as in
single-image dehazing) and whitens the panel (min/max channel ratio); a clean cell is saturated
blue or black; droppings are bright specks on a darker background."""


def reduce(image: NDArray[np.uint8], max_side: int = MAX_SIDE) -> NDArray[np.uint8]:
    """Every k-th pixel in both directions, with the smallest integer k that brings the long
    side to at most ``max_side`` [px]. Sampling, not averaging: it reads 1/k² of the pixels,
    and the features are statistics over the whole panel, not its fine detail."""
    h, w = image.shape[:2]
    k = -(-max(h, w) // max_side)
    if k <= 1:
        return image
    # the middle pixel of each k×k block; a side shorter than k keeps its middle pixel
    return np.ascontiguousarray(image[min(k // 2, h // 2) :: k, min(k // 2, w // 2) :: k])


_PATCH = np.ones((7, 7), np.uint8)


def _percentiles(channel: NDArray[np.generic], qs: tuple[float, ...]) -> list[float]:
    """Percentiles of a uint8 array from its histogram (no sort) [level]."""
    cdf = np.cumsum(np.bincount(channel.ravel(), minlength=256))
    return [float(np.searchsorted(cdf, q / 100.0 * cdf[-1])) for q in qs]


def features(image: NDArray[np.uint8]) -> NDArray[np.float64]:
    """The ``FEATURES`` of an RGB image of shape (H, W, 3), uint8, as a vector of shape (9,)."""
    if image.dtype != np.uint8 or image.ndim != 3 or image.shape[2] != 3:
        raise ValueError(f"expected an RGB image of shape (H, W, 3), uint8; got {image.shape}")
    small = reduce(image)
    r, g, b = cv2.split(small)
    lo = cv2.min(cv2.min(r, g), b)
    hi = cv2.max(cv2.max(r, g), b)
    dark = cv2.erode(lo, _PATCH)  # the dark channel: min over channels and a 7×7 patch
    hsv = cv2.cvtColor(small, cv2.COLOR_RGB2HSV)
    hue, sat = hsv[..., 0], hsv[..., 1]
    blue = np.count_nonzero((hue > 90) & (hue < 130) & (sat > 60)) / hue.size  # hue is 0–180
    grey = cv2.cvtColor(small, cv2.COLOR_RGB2GRAY)
    grey_mean, grey_std = cv2.meanStdDev(grey)
    local = cv2.blur(grey, (15, 15))
    speckle = np.count_nonzero(cv2.subtract(grey, local) > 35) / grey.size
    whiteness = (lo.astype(np.float32) / (hi.astype(np.float32) + 1.0)).mean()
    d50, d90 = _percentiles(dark, (50, 90))
    m10, m50 = _percentiles(lo, (10, 50))
    out = [
        float(dark.mean()),
        d50,
        d90,
        float(whiteness),
        blue,
        m10,
        m50,
        float(grey_std[0, 0] / (grey_mean[0, 0] + 1.0)),
        speckle,
    ]
    return np.asarray(out, dtype=np.float64)


@dataclass(frozen=True, slots=True)
class LogisticModel:
    """Standardised logistic regression: p(dirty) = σ(w · (f − μ)/s + b)."""

    feature_names: tuple[str, ...]
    mean: NDArray[np.float64]
    scale: NDArray[np.float64]
    coef: NDArray[np.float64]
    intercept: float
    threshold: float = 0.5

    def probability(self, f: ArrayLike) -> NDArray[np.float64]:
        """p(needs cleaning) for feature vectors of shape (..., k)."""
        z = ((np.asarray(f, dtype=np.float64) - self.mean) / self.scale) @ self.coef
        return np.asarray(1.0 / (1.0 + np.exp(-(z + self.intercept))), dtype=np.float64)
