"""The laser dot: one undisputed common point in every view (chapter 4 §II).

A dot is a small, bright, saturated-red blob. Each view may show several candidates (a red
label, a reflection); the combination — one candidate per view — that the rig triangulates with
the smallest reprojection error is the dot.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable
from dataclasses import dataclass
from typing import Literal

import cv2
import numpy as np
from numpy.typing import NDArray

MAX_CANDIDATES = 4
"""Per view, the brightest this many blobs are considered."""

SATURATED = 250
"""A channel at or above this is saturated."""

MIN_PLATEAU = 9
"""Saturated pixels from which a blob's centroid is the plateau's [px]: fewer are a peak
that only touches saturation, better located by its excess."""

MAX_RMS_PX = 2.0
"""A dot's views agree to this reprojection RMS [px]. Measured on renders of the dot (σ 1.5
px) at exposures from half to twice the nominal, PNG and JPEG quality 60–95: 0.02–1.11 px
(the worst a dim dot at quality 60, its chroma halved and blocky). Views over-exposed until
the dot had vanished (2.5–3 times, the table white) gave red patches of the part instead,
whose best choice reprojected at 3.5–39 px."""


Colour = Literal["red", "green", "blue"]
_FIRST: dict[str, list[int]] = {"green": [1, 0, 2], "blue": [2, 1, 0]}


def as_red(rgb: NDArray[np.uint8], colour: Colour) -> NDArray[np.uint8]:
    """The image with the laser's channel first, so that the dot's and the grid's steps,
    written for [Fayed 2013]'s red laser, read a green (532 nm) or blue one as red. The
    other two stay the channels the excess is taken over."""
    if colour == "red":
        return rgb
    return np.ascontiguousarray(rgb[..., _FIRST[colour]])


@dataclass(frozen=True, slots=True)
class Spot:
    u: float
    v: float
    """Sub-pixel centroid [px], intensity-weighted."""
    area: int
    """[px]"""
    strength: float
    """Sum of the centroid's weights over the blob."""


def find_spots(
    rgb: NDArray[np.uint8], *, min_excess: float = 30.0, max_area: int = 2000
) -> list[Spot]:
    """Red blobs in an RGB image, the most intense first (at most ``MAX_CANDIDATES``).

    The red excess E = R − max(G, B), smoothed, marks red. A blob is a connected region of
    pixels that are red (E ≥ ``min_excess``) or whose R is saturated, with at least one red
    pixel: a dot bright enough to saturate all three channels at its centre has no excess
    there, only in the ring around it. Its centroid is weighted by E above half the blob's
    peak (or above ``min_excess``, whichever is higher: a weight that falls to zero where
    the blob ends), so that it does not depend on the exposure; where R is saturated over a
    plateau of ``MIN_PLATEAU`` pixels or more, by the brightness R + G + B, smoothed, above
    its lowest on the plateau instead (the excess is flat or falls there). Blobs larger than
    ``max_area`` [px] are not dots. Ranked by peak excess, not by summed excess, which a
    large dull-red patch would win.
    """
    if rgb.dtype != np.uint8 or rgb.ndim != 3 or rgb.shape[2] != 3:
        raise ValueError(f"expected an RGB image (H, W, 3), uint8; got {rgb.shape}")
    r = rgb[..., 0]
    excess = cv2.GaussianBlur(
        r.astype(np.float32) - np.maximum(rgb[..., 1], rgb[..., 2]), (0, 0), 1.0
    )
    saturated = r >= SATURATED
    n, blobs = cv2.connectedComponents(
        ((excess >= min_excess) | saturated).astype(np.uint8), connectivity=8
    )
    if n <= 1:
        return []
    # statistics over the blobs' own pixels (a dot is a few dozen of an image's millions)
    ys, xs = np.nonzero(blobs)
    label: NDArray[np.intp] = np.asarray(blobs[ys, xs], dtype=np.intp)
    e = excess[ys, xs].astype(np.float64)
    peak = np.zeros(n)
    np.maximum.at(peak, label, e)
    weight = np.maximum(e - np.maximum(0.5 * peak, min_excess)[label], 0.0)
    sat = saturated[ys, xs]
    plateau = np.bincount(label, weights=sat, minlength=n)
    if (plateau >= MIN_PLATEAU).any():
        brightness = cv2.GaussianBlur(rgb.astype(np.float32).sum(axis=2), (0, 0), 1.0)
        b = brightness[ys, xs].astype(np.float64)
        lowest = np.full(n, np.inf)
        np.minimum.at(lowest, label[sat], b[sat])
        on = plateau[label] >= MIN_PLATEAU
        weight[on] = np.where(sat[on], b[on] - lowest[label[on]] + 1.0, 0.0)
    area = np.bincount(label, minlength=n)
    total = np.bincount(label, weights=weight, minlength=n)
    with np.errstate(invalid="ignore", divide="ignore"):
        u = np.bincount(label, weights=weight * xs, minlength=n) / total
        v = np.bincount(label, weights=weight * ys, minlength=n) / total
    found = [
        (peak[k], Spot(float(u[k]), float(v[k]), int(area[k]), float(total[k])))
        for k in range(1, n)
        if peak[k] >= min_excess and area[k] <= max_area and total[k] > 0
    ]
    found.sort(key=lambda f: f[0], reverse=True)
    return [spot for _, spot in found[:MAX_CANDIDATES]]


@dataclass(frozen=True, slots=True)
class Dot:
    point: NDArray[np.float64]
    pixels: list[tuple[float, float] | None]
    reprojection_rms: float


Triangulator = Callable[[NDArray[np.float64]], tuple[NDArray[np.float64], NDArray[np.float64]]]
"""(N, V, 2) observations → ((N, 3) points, (N,) reprojection RMS [px])."""


def locate(
    candidates: list[list[Spot]],
    triangulate: Triangulator,
    *,
    min_views: int = 2,
    max_rms: float = MAX_RMS_PX,
) -> Dot:
    """The most consistent choice of one spot per view (views without spots left out).

    Raises ValueError naming the views without a dot when fewer than ``min_views`` have one,
    and when no choice of spots reprojects within ``max_rms`` [px]: red spots that are not
    one point in space.
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
    if rms[best] > max_rms:
        raise ValueError(
            f"the red spots found in the views do not meet in one point (the best choice "
            f"reprojects at {rms[best]:.2g} px, more than {max_rms:g}): no laser dot"
        )
    pixels: list[tuple[float, float] | None] = [None] * v
    for i, s in zip(seen, combos[best], strict=True):
        pixels[i] = (s.u, s.v)
    return Dot(points[best], pixels, float(rms[best]))
