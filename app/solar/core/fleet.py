"""Features of a panel photograph for the fleet model, and the fleet model itself.

A per-panel baseline needs clean photos of that panel; a panel without one is judged by a fleet
model trained on labelled photos of many panels. Three modes are not enough across panel types
and cameras, so the fleet model sees how saturated, how contrasted, how speckled and how
textured the panel looks: haze and dust features on a copy reduced to at most ``MAX_SIDE``
pixels, grey-level co-occurrence (GLCM) and local binary pattern (LBP) texture and colour
statistics (scikit-image, OpenCV) on a copy area-averaged to ``TEXTURE_SIDE``.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.special import expit
from skimage.feature import graycomatrix, graycoprops

from app.solar.core.structure import STRUCTURE_FEATURES, structure_features

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
HAZE_FEATURES = FEATURES

_GLCM_PROPS = ("contrast", "homogeneity", "energy", "correlation", "dissimilarity")
_GLCM_DISTANCES = (1, 3)
TEXTURE_FEATURES = (
    tuple(f"glcm_{p}_d{d}" for p in _GLCM_PROPS for d in _GLCM_DISTANCES)
    + tuple(f"lbp_{k}" for k in range(10))
    + tuple(
        f"{space}_{stat}_{c}"
        for space, channels in (("hsv", "hsv"), ("lab", "lab"))
        for stat in ("mean", "std")
        for c in channels
    )
    + tuple(f"lab_p{q}_{c}" for q in (10, 90) for c in "lab")
    + tuple(f"lbp24r3_{k}" for k in range(26))
    + STRUCTURE_FEATURES
)
"""Texture: GLCM contrast, homogeneity, energy, correlation and dissimilarity at 1 and 3 px
(averaged over 4 directions, 32 grey levels); the 10-bin histogram of uniform LBP (8
neighbours, radius 1); colour: HSV and CIELAB means and standard deviations, CIELAB 10th and
90th percentiles; the 26-bin histogram of uniform LBP at the coarser scale of 24 neighbours,
radius 3 px (Ojala, Pietikäinen & Mäenpää, *Multiresolution gray-scale and rotation invariant
texture classification with local binary patterns*, IEEE PAMI 24(7), 2002: the operators
LBP^riu2 of (8, 1) and (24, 3)); last the ``STRUCTURE_FEATURES`` (``core.structure``): band
energies, lines, repetition, layout. The coarse scale is meant for a cell's grid and busbars,
which a dust film softens; one pixel's neighbours see finer speckle. What each group earns on
panels the model never saw: ``bench/fleet_eval.py --groups``."""

ALL_FEATURES = HAZE_FEATURES + TEXTURE_FEATURES
"""What ``features`` computes, in its order; a model uses those it names."""

TEXTURE_SIDE = 256
"""Long side of the area-averaged copy the texture is measured on [px]: texture is a matter of
scale, so every larger photo is brought to one."""
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
    """The ``ALL_FEATURES`` of an RGB image of shape (H, W, 3), uint8, as a vector."""
    return np.concatenate([haze_features(image), texture_features(image)])


def texture_features(image: NDArray[np.uint8]) -> NDArray[np.float64]:
    """The ``TEXTURE_FEATURES`` of an RGB image of shape (H, W, 3), uint8."""
    small = texture_scale(image)
    grey = np.asarray(cv2.cvtColor(small, cv2.COLOR_RGB2GRAY), dtype=np.uint8)
    glcm = graycomatrix(
        grey // 8,
        distances=list(_GLCM_DISTANCES),
        angles=[0.0, np.pi / 4, np.pi / 2, 3 * np.pi / 4],
        levels=32,
        symmetric=True,
        normed=True,
    )
    co = [graycoprops(glcm, prop).mean(axis=1) for prop in _GLCM_PROPS]  # per distance
    fine, coarse = (lbp_histogram(grey, p, r) for p, r in ((8, 1), (24, 3)))
    hsv_mean, hsv_std = cv2.meanStdDev(cv2.cvtColor(small, cv2.COLOR_RGB2HSV))
    lab = cv2.cvtColor(small, cv2.COLOR_RGB2LAB)
    lab_mean, lab_std = cv2.meanStdDev(lab)
    planes = cv2.split(lab)
    lab_p = [[_percentile(np.asarray(c, np.uint8), q) for c in planes] for q in (10, 90)]
    colour = [a.ravel() for a in (hsv_mean, hsv_std, lab_mean, lab_std)] + lab_p
    out = np.concatenate(
        [np.concatenate(co), fine, np.concatenate(colour), coarse, structure_features(grey)]
    )
    return np.asarray(np.nan_to_num(out, nan=0.0), dtype=np.float64)  # a flat image: no texture


def _percentile(channel: NDArray[np.uint8], q: float) -> float:
    """The ``q``-th percentile of a uint8 plane, linearly interpolated between the order
    statistics as NumPy's default, from its histogram [level]."""
    counts = np.bincount(channel.ravel(), minlength=256)
    cdf = np.cumsum(counts)
    position = q / 100.0 * (cdf[-1] - 1)  # 0-based rank
    lo = int(np.searchsorted(cdf, np.floor(position) + 1))
    hi = int(np.searchsorted(cdf, np.ceil(position) + 1))
    return float(lo + (hi - lo) * (position - np.floor(position)))


def texture_scale(image: NDArray[np.uint8]) -> NDArray[np.uint8]:
    """``image`` (H, W, 3) area-averaged to a long side of ``TEXTURE_SIDE`` px; never enlarged,
    since enlarging invents texture."""
    h, w = image.shape[:2]
    k = min(1.0, TEXTURE_SIDE / max(h, w))
    size = (max(8, round(w * k)), max(8, round(h * k)))
    return np.asarray(cv2.resize(image, size, interpolation=cv2.INTER_AREA), dtype=np.uint8)


def texture_grey(image: NDArray[np.uint8]) -> NDArray[np.uint8]:
    """The grey image (BT.601 luma) that the texture features of ``image`` are measured on."""
    return np.asarray(cv2.cvtColor(texture_scale(image), cv2.COLOR_RGB2GRAY), dtype=np.uint8)


def lbp_histogram(grey: NDArray[np.uint8], points: int, radius: float) -> NDArray[np.float64]:
    """Share of the pixels of each of the ``points`` + 2 codes of uniform, rotation-invariant
    LBP (``points`` neighbours on a circle of ``radius`` px, bilinearly interpolated), shape
    (points + 2,), over the pixels at least ⌈radius⌉ from the border.

    The operator LBP^riu2 of Ojala et al. (2002), eq. 10 there: the number of neighbours at
    least as bright as the centre when the circle's bits change at most twice, else
    points + 1. Each neighbour is the whole image interpolated at the neighbour's sub-pixel
    offset by a 2×2 correlation (OpenCV's ``filter2D``), then shifted by its whole pixels: a
    few vectorised passes, not a loop per pixel. scikit-image's ``local_binary_pattern``
    gives the same histogram (``tests/solar/test_fleet.py``) at about five times the time;
    as there, the offsets are rounded to 5 decimals, so that cos 90° is 0."""
    g = grey.astype(np.float32)
    h, w = g.shape
    r = int(np.ceil(radius))
    # a neighbour equal to the centre must count as equal: float32 weights summing to 1 − 6e-8
    # would leave it a hair below
    centre = g[r : h - r, r : w - r] - np.float32(1e-3)
    ones: NDArray[np.uint8] = np.zeros(centre.shape, np.uint8)
    changes: NDArray[np.uint8] = np.zeros(centre.shape, np.uint8)
    bits: list[NDArray[np.uint8]] = []
    for k in range(points):
        angle = 2.0 * np.pi * k / points
        dy, dx = np.round(-radius * np.sin(angle), 5), np.round(radius * np.cos(angle), 5)
        y0, x0 = int(np.floor(dy)), int(np.floor(dx))
        fy, fx = dy - y0, dx - x0
        weights = np.array(
            [[(1 - fy) * (1 - fx), (1 - fy) * fx], [fy * (1 - fx), fy * fx]], dtype=np.float32
        )
        shifted = np.asarray(cv2.filter2D(g, -1, weights, anchor=(0, 0)))  # value at (y+fy, x+fx)
        neighbour = shifted[r + y0 : h - r + y0, r + x0 : w - r + x0]
        bits.append(np.asarray(cv2.compare(neighbour, centre, cv2.CMP_GE), np.uint8) // 255)
        ones = np.asarray(cv2.add(ones, bits[-1]), np.uint8)
        if k:
            changes = np.asarray(cv2.add(changes, cv2.absdiff(bits[-1], bits[-2])), np.uint8)
    changes = np.asarray(cv2.add(changes, cv2.absdiff(bits[0], bits[-1])), np.uint8)
    codes = np.where(changes <= 2, ones, np.uint8(points + 1))
    counts = np.bincount(codes.ravel(), minlength=points + 2)[: points + 2]
    return np.asarray(counts / codes.size, dtype=np.float64)


def haze_features(image: NDArray[np.uint8]) -> NDArray[np.float64]:
    """The ``HAZE_FEATURES`` of an RGB image of shape (H, W, 3), uint8, shape (9,)."""
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
        """p(needs cleaning) for ``ALL_FEATURES`` vectors of shape (..., K)."""
        z = ((pick(f, self.feature_names) - self.mean) / self.scale) @ self.coef
        return _sigmoid(z + self.intercept)

    def condition(self, f: ArrayLike) -> str:
        """clean or dirty: the linear model tells no more."""
        return "dirty" if float(self.probability(f)) >= self.threshold else "clean"

    def doubt(self, f: ArrayLike) -> str | None:
        """Why its answer on one frame is not to be trusted (``undecided``), or None: it kept
        no training photos, so it cannot tell a frame unlike them."""
        return undecided(float(self.probability(f)), self.threshold)


def pick(f: ArrayLike, names: tuple[str, ...]) -> NDArray[np.float64]:
    """The columns ``names`` of ``ALL_FEATURES`` vectors (..., K) [or of vectors of just
    those, as older models' callers pass]."""
    x = np.asarray(f, dtype=np.float64)
    if x.shape[-1] == len(names):
        return x
    return np.asarray(x[..., [ALL_FEATURES.index(n) for n in names]], dtype=np.float64)


def _sigmoid(z: NDArray[np.float64] | float) -> NDArray[np.float64]:
    """The logistic function, without overflow for large |z| (SciPy's expit)."""
    return np.asarray(expit(np.asarray(z, dtype=np.float64)), dtype=np.float64)


@dataclass(frozen=True, slots=True)
class Head:
    """A standardised logistic regression on the same features: p = σ(w · (f − μ)/s + b)."""

    coef: NDArray[np.float64]
    intercept: float

    def probability(self, z: NDArray[np.float64]) -> NDArray[np.float64]:
        return _sigmoid(z @ self.coef + self.intercept)


COLOUR_FEATURES = tuple(n for n in TEXTURE_FEATURES if n.startswith(("hsv_", "lab_")))
"""The HSV and CIELAB statistics among the texture features."""

SNOW_FEATURES = HAZE_FEATURES + COLOUR_FEATURES + STRUCTURE_FEATURES
"""What the snow head reads: how white, how covered, how built; not the fine texture."""

SHAPE_FEATURES = HAZE_FEATURES + STRUCTURE_FEATURES
"""What tells a panel photo from a photo of something else (``Shape``): how hazy and how
built, not the colours that go with a panel's type."""


@dataclass(frozen=True, slots=True)
class Shape:
    """What the panel photos a model learnt from look like, as a test that a frame shows a
    panel: the Mahalanobis distance √((z − μ)ᵀ P (z − μ)) of its standardised
    ``SHAPE_FEATURES`` z from theirs (μ, and P the inverse of their shrunk covariance), over
    ``limit``, which a photo like them exceeds with probability of about 5 %
    (``fleet_training.shape_model``)."""

    mean: NDArray[np.float64]
    scale: NDArray[np.float64]
    location: NDArray[np.float64]
    precision: NDArray[np.float64]
    limit: float

    def distance(self, f: ArrayLike) -> float:
        """The distance of one ``ALL_FEATURES`` vector (K,) from the training photos."""
        z = (pick(f, SHAPE_FEATURES) - self.mean) / self.scale - self.location
        return float(np.sqrt(max(0.0, float(z @ self.precision @ z))))


@dataclass(frozen=True, slots=True)
class KernelModel:
    """Needs cleaning or not: a support-vector machine with a Gaussian (RBF) kernel on the
    standardised features, f(z) = Σᵢ αᵢ exp(−γ ‖zᵢ − z‖²) + b, its decision turned into a
    probability by Platt's sigmoid σ(a f + c) fitted to cross-validated decisions. Optional
    heads tell snow from the rest and droppings from dust (``condition``)."""

    feature_names: tuple[str, ...]
    mean: NDArray[np.float64]
    scale: NDArray[np.float64]
    support: NDArray[np.float64]
    """(n_sv, K) standardised support vectors."""
    dual: NDArray[np.float64]
    """(n_sv,) αᵢ (the dual coefficients, signed)."""
    intercept: float
    gamma: float
    platt: tuple[float, float]
    snow: Head | None = None
    bird_drop: Head | None = None
    threshold: float = 0.5
    training: NDArray[np.float64] | None = None
    """(n, K) standardised features of the photos it learnt from (None: a model from before
    they were kept, which cannot tell a photo unlike them)."""
    reach: float | None = None
    """How far from every training photo a frame may lie (standard units) and still be among
    them: a conformal rank of their distances to their nearest other photo, or for the
    oldest models the largest of them. Models fitted since keep ``shape`` instead."""
    shape: Shape | None = None
    """What its panel photos look like, to doubt frames of no panel (None: a model from
    before, which has ``reach`` instead)."""
    snow_floor: float | None = None
    """A frame it would send to brushing is doubted from this p(snow) up (the lowest p(snow)
    of a held-out snow photo, ``fleet_training._snow_floor``); None: from 0.5 − ``band``."""
    band: float = 0.2
    """A calibrated p(needs cleaning) within this of ``threshold`` is "not sure" (chosen on
    its training photos, ``fleet_training.choose_band``; 0.2 for models from before)."""

    def standardised(self, f: ArrayLike) -> NDArray[np.float64]:
        return (pick(f, self.feature_names) - self.mean) / self.scale

    def decision(self, f: ArrayLike) -> NDArray[np.float64]:
        z = np.atleast_2d(self.standardised(f))
        d2 = ((z[:, None, :] - self.support[None]) ** 2).sum(-1)
        out = np.exp(-self.gamma * d2) @ self.dual + self.intercept
        return np.asarray(out if np.ndim(f) > 1 else out[0], dtype=np.float64)

    def probability(self, f: ArrayLike) -> NDArray[np.float64]:
        """p(needs cleaning), Platt-calibrated."""
        a, c = self.platt
        return _sigmoid(a * self.decision(f) + c)

    def condition(self, f: ArrayLike) -> str:
        """snow, clean, dust or bird_drop (dust when the model learnt no droppings)."""
        z = self.standardised(f)
        if self.snow is not None and float(self.snow.probability(z)) >= 0.5:
            return "snow"
        if float(self.probability(f)) < self.threshold:
            return "clean"
        if self.bird_drop is None:
            return "dust"
        return "bird_drop" if float(self.bird_drop.probability(z)) >= 0.5 else "dust"

    def doubt(self, f: ArrayLike) -> str | None:
        """Why the model's clean-or-dirty answer on one frame is not to be trusted, or None.

        Three reasons: the frame does not look like the panel photos the model learnt from
        (``shape``, or for older models further from every one than ``reach``); its p(snow) is
        within ``band`` below 0.5 (at 0.5 and above it is snow), or when it would be sent to
        brushing at or above ``snow_floor``; or its p(needs cleaning) is
        within ``band`` of the threshold, where the two classes' photos mix
        (``bench/fleet_eval.py``, folds grouped by panel)."""
        if self.shape is not None:
            far = self.shape.distance(f)
            if far > self.shape.limit:
                return (
                    f"unlike the panel photos the fleet model learnt from (is a panel in view?): "
                    f"its build lies {far:.1f} from theirs, beyond {self.shape.limit:.1f}"
                )
        z = self.standardised(f)
        old = self.shape is None and self.training is not None and self.reach is not None
        if old and self.training is not None and len(self.training):
            nearest = float(np.sqrt(((self.training - z) ** 2).sum(axis=1)).min())
            if self.reach is not None and nearest > self.reach:
                return (
                    f"unlike every photo the fleet model learnt from: the nearest lies "
                    f"{nearest:.1f} standard units away, beyond its reach of {self.reach:.1f}"
                )
        p = float(self.probability(f))
        if self.snow is not None:
            p_snow = float(self.snow.probability(z))
            low = 0.5 - self.band
            if self.snow_floor is not None and p >= self.threshold:
                low = min(low, self.snow_floor)
            if low <= p_snow < 0.5:  # brushing a snow-covered panel is no cleaning
                return (
                    f"the fleet model is not sure the panel is free of snow: p(snow) {p_snow:.2f}"
                )
        return undecided(p, self.threshold, self.band)


UNSURE = 0.2
"""The not-sure band of models trained before the band was chosen on their photos."""


def undecided(p: float, threshold: float, band: float = UNSURE) -> str | None:
    """The reason a fleet answer of p(needs cleaning) ``p`` is "not sure" (within ``band`` of
    ``threshold``), or None."""
    if abs(p - threshold) < band:
        return (
            f"the fleet model is not sure: p(needs cleaning) {p:.2f}, within {band:.2f} "
            f"of its threshold {threshold:.2f}"
        )
    return None
