"""How a photograph is built, for the fleet model: scales, lines, repetition, layout.

A panel photo is a surface of repeated cells between straight busbars and frame lines; dust
softens the finest scale of that pattern and leaves the coarse ones. A street, a sky or a box
is built otherwise: smooth sky above, texture below, no repeated grid. These features describe
that build, not the panel's colour (which goes with its type more than with its soiling), so
the same numbers serve the clean-or-dirty model and the test of whether a photo shows a panel
at all (``fleet_training.shape_model``).

All of them are measured on the grey copy the texture features use (``fleet.texture_grey``,
long side 256 px), with OpenCV and NumPy only: about 3.3 ms for a 640×480 frame on one core of a
machine that decodes it in 2 ms (``bench/README.md``).
"""

from __future__ import annotations

import cv2
import numpy as np
from numpy.typing import NDArray

LEVELS = 4
"""Levels of the Laplacian pyramid whose band energies are measured (1, 2, 4, 8 px)."""

_ORIENTATIONS = 18
"""Bins of gradient orientation over 0–180° (10° each)."""

STRUCTURE_FEATURES = (
    tuple(f"band{k}_{stat}" for k in range(LEVELS) for stat in ("mean", "std"))
    + ("coherence_w5", "coherence_w13")
    + ("edges_20", "edges_60", "gradient_p90")
    + ("orientation_top", "orientation_top2", "orientation_entropy")
    + ("spectrum_top10", "spectrum_top50")
    + ("detail_top", "detail_bottom", "brightness_drop")
)
"""Band energies of the Laplacian pyramid (Burt & Adelson, *The Laplacian pyramid as a compact
image code*, IEEE Trans. Commun. 31(4), 1983): mean |band| and its standard deviation at each
of ``LEVELS`` octaves, over the mean grey level; the coherence of the structure tensor
(|λ₁ − λ₂| / (λ₁ + λ₂), gradient-energy weighted) over windows of 5 and 13 px: how
much the texture runs in lines; the share of pixels whose gradient exceeds 20 and 60 levels/px
and its 90th percentile over the mean grey level; the share of gradient energy in the
strongest 10° orientation and the two strongest, and the orientations' entropy [nats]; the
share of the gradient image's spectral energy in its 10 and 50 strongest frequencies (a grid
repeats: its energy sits in a few peaks); the Laplacian detail of the top and bottom thirds
over that of the whole, and the mean grey level of the top third less that of the bottom
[/255] (a sky above a street)."""


def structure_features(grey: NDArray[np.uint8]) -> NDArray[np.float64]:
    """The ``STRUCTURE_FEATURES`` of a grey image (H, W), uint8, H and W ≥ 8, shape (21,)."""
    if grey.ndim != 2 or min(grey.shape) < 8:
        raise ValueError(f"expected a grey image of at least 8×8 px; got {grey.shape}")
    g = grey.astype(np.float32)
    level = float(g.mean()) + 1.0
    gx = _f32(cv2.Sobel(g, cv2.CV_32F, 1, 0, ksize=3))
    gy = _f32(cv2.Sobel(g, cv2.CV_32F, 0, 1, ksize=3))
    magnitude = _f32(cv2.magnitude(gx, gy))
    out = [*_bands(g, level), *_coherence(gx, gy)]
    out += [
        float(np.count_nonzero(magnitude > 20) / magnitude.size),
        float(np.count_nonzero(magnitude > 60) / magnitude.size),
        _quantile(magnitude, 0.9) / level,
    ]
    out += [*_orientations(gx, gy, magnitude), *_spectrum(magnitude), *_layout(g)]
    return np.asarray(out, dtype=np.float64)


def _f32(a: object) -> NDArray[np.float32]:
    """An OpenCV result as the float32 array it is."""
    return np.asarray(a, dtype=np.float32)


def _quantile(values: NDArray[np.float32], q: float) -> float:
    """The ``q``-quantile of ``values`` (the order statistic at rank ⌊q (n − 1)⌋), by partial
    sort."""
    flat = values.ravel()
    rank = int(q * (flat.size - 1))
    return float(np.partition(flat, rank)[rank])


def _bands(g: NDArray[np.float32], level: float) -> list[float]:
    """Mean |band| and the band's standard deviation at each level of the Laplacian pyramid,
    over the mean grey level."""
    out: list[float] = []
    current = g
    for _ in range(LEVELS):
        h, w = current.shape
        if min(h, w) < 4:
            out += [0.0, 0.0]
            continue
        down = cv2.pyrDown(current)
        band = current - cv2.pyrUp(down, dstsize=(w, h))
        spread = float(cv2.meanStdDev(band)[1][0, 0])
        out += [float(cv2.mean(np.abs(band))[0]) / level, spread / level]
        current = _f32(down)
    return out


def _coherence(gx: NDArray[np.float32], gy: NDArray[np.float32]) -> list[float]:
    """The structure tensor's coherence over windows of 5 and 13 px (box windows, about the
    reach of Gaussians of σ 2 and 6 px), weighted by its trace (the gradient energy)."""
    xx, yy, xy = gx * gx, gy * gy, gx * gy
    out = []
    for size in (5, 13):
        jxx, jyy, jxy = (cv2.boxFilter(a, -1, (size, size)) for a in (xx, yy, xy))
        trace = cv2.add(jxx, jyy)
        spread = cv2.magnitude(cv2.subtract(jxx, jyy), 2.0 * jxy)
        out.append(float(cv2.sumElems(spread)[0] / (cv2.sumElems(trace)[0] + 1e-6)))
    return out


def _orientations(
    gx: NDArray[np.float32], gy: NDArray[np.float32], magnitude: NDArray[np.float32]
) -> list[float]:
    """Share of the gradient energy in the strongest orientation bin, the two strongest, and
    the entropy of the orientations [nats]."""
    angle = cv2.phase(gx, gy, angleInDegrees=True)  # 0–360°
    bins = cv2.convertScaleAbs(angle, alpha=_ORIENTATIONS / 180.0)  # rounded: 0–36
    bins = np.remainder(bins, _ORIENTATIONS)
    hist = np.bincount(bins.ravel(), weights=magnitude.ravel(), minlength=_ORIENTATIONS)
    hist = hist / (hist.sum() + 1e-9)
    top = np.sort(hist)[::-1]
    entropy = float(-(hist * np.log(hist + 1e-12)).sum())
    return [float(top[0]), float(top[:2].sum()), entropy]


def _spectrum(magnitude: NDArray[np.float32]) -> list[float]:
    """Share of the (Hann-windowed, mean-removed) gradient image's spectral energy in its 10
    and 50 strongest frequencies, the lowest 2 in each direction (either sign) left out."""
    h, w = magnitude.shape
    window = cv2.createHanningWindow((w, h), cv2.CV_32F)
    centred = cv2.multiply(magnitude - np.float32(magnitude.mean()), window)
    spectrum = cv2.dft(centred, flags=cv2.DFT_COMPLEX_OUTPUT)
    power = cv2.magnitude(spectrum[..., 0], spectrum[..., 1]) ** 2
    for rows in (slice(0, 2), slice(h - 2, h)):
        for cols in (slice(0, 2), slice(w - 2, w)):
            power[rows, cols] = 0.0
    total = float(power.sum()) + 1e-9
    flat = power.ravel()
    top = np.sort(np.partition(flat, flat.size - 50)[-50:])
    return [float(top[-10:].sum()) / total, float(top.sum()) / total]


def _layout(g: NDArray[np.float32]) -> list[float]:
    """Laplacian detail of the top and bottom thirds over that of the whole, and the mean
    grey level of the top third less the bottom's [/255]."""
    third = g.shape[0] // 3
    detail = np.abs(cv2.Laplacian(g, cv2.CV_32F))
    whole = float(detail.mean()) + 1.0
    top, bottom = g[:third], g[-third:]
    return [
        float(detail[:third].mean()) / whole,
        float(detail[-third:].mean()) / whole,
        (float(top.mean()) - float(bottom.mean())) / 255.0,
    ]
