"""The laser dot: one undisputed common point in every view (chapter 4 §II).

A dot is a small, bright, saturated-red blob. Each view may show several candidates (a red
label, a reflection); the combination — one candidate per view — that the rig triangulates with
the smallest reprojection error is the dot.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable
from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

MAX_CANDIDATES = 4
"""Per view, the brightest this many blobs are considered."""


@dataclass(frozen=True, slots=True)
class Spot:
    u: float
    v: float
    """Sub-pixel centroid [px], intensity-weighted."""
    area: int
    """[px]"""
    strength: float
    """Sum of the red excess over the blob."""


def find_spots(
    rgb: NDArray[np.uint8], *, min_red: int = 150, min_excess: int = 60, max_area: int = 2000
) -> list[Spot]:
    """Red blobs in an RGB image, strongest first: R ≥ ``min_red`` and R − max(G, B) ≥
    ``min_excess``; centroids weighted by the red excess."""
    if rgb.dtype != np.uint8 or rgb.ndim != 3 or rgb.shape[2] != 3:
        raise ValueError(f"expected an RGB image (H, W, 3), uint8; got {rgb.shape}")
    r = rgb[..., 0].astype(np.int16)
    excess = r - np.maximum(rgb[..., 1], rgb[..., 2]).astype(np.int16)
    mask = ((r >= min_red) & (excess >= min_excess)).astype(np.uint8)
    n, labels, stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=8)
    spots = []
    for k in range(1, n):
        area = int(stats[k, cv2.CC_STAT_AREA])
        if area > max_area:
            continue
        ys, xs = np.nonzero(labels == k)
        w = excess[ys, xs].astype(np.float64)
        spots.append(
            Spot(
                float((xs * w).sum() / w.sum()),
                float((ys * w).sum() / w.sum()),
                area,
                float(w.sum()),
            )
        )
    return sorted(spots, key=lambda s: s.strength, reverse=True)[:MAX_CANDIDATES]


@dataclass(frozen=True, slots=True)
class Dot:
    point: NDArray[np.float64]
    pixels: list[tuple[float, float] | None]
    reprojection_rms: float


Triangulator = Callable[[NDArray[np.float64]], tuple[NDArray[np.float64], NDArray[np.float64]]]
"""(N, V, 2) observations → ((N, 3) points, (N,) reprojection RMS [px])."""


def locate(candidates: list[list[Spot]], triangulate: Triangulator, *, min_views: int = 2) -> Dot:
    """The most consistent choice of one spot per view (views without spots left out).

    Raises ValueError naming the views without a dot when fewer than ``min_views`` have one.
    """
    seen = [i for i, c in enumerate(candidates) if c]
    if len(seen) < min_views:
        missing = [i + 1 for i, c in enumerate(candidates) if not c]
        raise ValueError(
            f"laser dot not found in camera(s) {', '.join(map(str, missing))}: "
            f"it must be seen by at least {min_views}"
        )
    v = len(candidates)
    combos = list(itertools.product(*[candidates[i] for i in seen]))
    obs = np.full((len(combos), v, 2), np.nan)
    for n, combo in enumerate(combos):
        for i, s in zip(seen, combo, strict=True):
            obs[n, i] = (s.u, s.v)
    points, rms = triangulate(obs)
    rms = np.where(np.isfinite(rms), rms, np.inf)
    best = int(np.argmin(rms))
    pixels: list[tuple[float, float] | None] = [None] * v
    for i, s in zip(seen, combos[best], strict=True):
        pixels[i] = (s.u, s.v)
    return Dot(points[best], pixels, float(rms[best]))
