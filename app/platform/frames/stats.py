"""Per-channel histogram statistics of a colour image: the features every classifier starts from."""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

Roi = tuple[int, int, int, int]
"""Region of interest (x, y, w, h) [px]."""

Polygon = tuple[tuple[int, int], ...]
"""Region of interest as a polygon's vertices (x, y) [px], in order."""


def bounding_box(polygon: Polygon) -> Roi:
    """The smallest (x, y, w, h) holding every vertex's pixel."""
    xs = [x for x, _ in polygon]
    ys = [y for _, y in polygon]
    return (min(xs), min(ys), max(xs) - min(xs) + 1, max(ys) - min(ys) + 1)


def polygon_pixels(image: NDArray[np.uint8], polygon: Polygon) -> NDArray[np.uint8]:
    """The pixels of ``image`` (H, W, 3) inside ``polygon`` (edges included) as a column
    image (N, 1, 3), which every per-channel statistic takes like any other image.

    Raises ValueError when the polygon does not lie inside the image.
    """
    x, y, w, h = bounding_box(polygon)
    box = crop(image, (x, y, w, h))
    mask = np.zeros((h, w), np.uint8)
    cv2.fillPoly(mask, [np.array([(px - x, py - y) for px, py in polygon], np.int32)], 1)
    return np.ascontiguousarray(box[mask.astype(bool)][:, None, :])


@dataclass(frozen=True, slots=True)
class ChannelStats:
    """Histogram, mode and mean of each of R, G, B."""

    histograms: NDArray[np.int64]
    """Shape (3, 256): pixel counts per grey level, rows R, G, B."""
    modes: NDArray[np.int64]
    """Shape (3,): most frequent level per channel; ties go to the lowest level."""
    means: NDArray[np.float64]
    """Shape (3,): mean level per channel."""

    @property
    def pixels(self) -> int:
        return int(self.histograms[0].sum())


def crop(image: NDArray[np.uint8], roi: Roi | None) -> NDArray[np.uint8]:
    """The part of ``image`` (H, W, C) inside ``roi``; the whole image when ``roi`` is None.

    Raises ValueError when the ROI does not lie inside the image.
    """
    if roi is None:
        return image
    x, y, w, h = roi
    height, width = image.shape[:2]
    if w <= 0 or h <= 0 or x < 0 or y < 0 or x + w > width or y + h > height:
        raise ValueError(f"ROI {list(roi)} does not lie inside the {width}×{height} frame")
    return image[y : y + h, x : x + w]


_BAND_PIXELS = 1 << 20
"""Pixels of the band of rows ``channel_histograms`` splits at a time."""

_SPLIT_FROM = 1 << 19
"""Pixels from which ``channel_histograms`` splits the image into planes first."""


def channel_histograms(image: NDArray[np.uint8]) -> NDArray[np.int64]:
    """Histograms of shape (3, 256) of an RGB image of shape (H, W, 3), uint8."""
    if image.dtype != np.uint8 or image.ndim != 3 or image.shape[2] != 3:
        raise ValueError(f"expected an RGB image of shape (H, W, 3), uint8; got {image.shape}")
    if image.shape[0] == 0 or image.shape[1] == 0:
        raise ValueError("empty image")
    if image.shape[0] * image.shape[1] < _SPLIT_FROM:
        # a small region is read where the decoder left it, in the cache: splitting it first
        # would write a copy as large and read that (bench/README.md, classify)
        counts = [cv2.calcHist([image], [c], None, [256], [0, 256]).ravel() for c in range(3)]
        return np.asarray(counts).round().astype(np.int64)
    # a large one, as contiguous planes, a band of rows at a time: calcHist runs faster over a
    # plane than over one channel of the interleaved image, by more than the split costs; a
    # band's planes take 3 MiB where a 36 MP region's would take 100, split into one buffer
    height, width = image.shape[:2]
    step = max(1, _BAND_PIXELS // width)
    planes = np.empty((3, step * width), np.uint8)
    hist = np.zeros((3, 256), dtype=np.float64)  # float32, calcHist's own, is exact to 2²⁴
    for y in range(0, height, step):
        band = image[y : y + step]
        views = [plane[: band.shape[0] * width].reshape(band.shape[0], width) for plane in planes]
        cv2.split(band, views)
        for c, view in enumerate(views):
            hist[c] += cv2.calcHist([view], [0], None, [256], [0, 256]).ravel()
    return hist.round().astype(np.int64)


def channel_stats(image: NDArray[np.uint8], roi: Roi | None = None) -> ChannelStats:
    """Histogram, mode and mean of each channel of ``image`` inside ``roi``.

    The mode is the level 0–255 with the most pixels, ties to the lowest ([Fayed 2013]'s
    x̂, chapter 5 §III); the mean is x̄.
    """
    hist = channel_histograms(crop(image, roi))
    levels = np.arange(256, dtype=np.float64)
    counts = hist.sum(axis=1)
    modes = hist.argmax(axis=1)  # argmax returns the first maximum: ties go to the lowest level
    means = (hist * levels).sum(axis=1) / counts
    return ChannelStats(histograms=hist, modes=modes.astype(np.int64), means=means)
