"""Image conditioning and part outlines: dissertation chapter 3 and chapter 4 §II.

Under poor light a part's grey levels span a narrow range and its cast shadow makes a false
edge. The pipeline restores the range (stretch 4.1, equalisation 4.2–4.3), pushes the shadow
into the background (equalise → shift 3.1 → equalise, chapter 3 §IV), finds edges (Canny) and
line segments (probabilistic Hough), joins fragments (3.2–3.3) and intersects adjacent sides
into the outline's corners (chapter 3 §V.A), counter-clockwise as seen in the image.

Image coordinates: x right, y down, pixel centres at integers [px]. Arrays: greyscale (H, W)
uint8, colour (H, W, 3) uint8 RGB.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

Grey = NDArray[np.uint8]
Segment = tuple[float, float, float, float]
"""(x1, y1, x2, y2) [px]."""


def _check_grey(image: NDArray[np.uint8]) -> None:
    if image.dtype != np.uint8 or image.ndim != 2:
        raise ValueError(f"expected a greyscale image of shape (H, W), uint8; got {image.shape}")


def luma(image: NDArray[np.uint8]) -> Grey:
    """Y = 0.299 R + 0.587 G + 0.114 B (chapter 4 §II), rounded, of an RGB image (H, W, 3)."""
    if image.dtype != np.uint8 or image.ndim != 3 or image.shape[2] != 3:
        raise ValueError(f"expected an RGB image of shape (H, W, 3), uint8; got {image.shape}")
    y = image.astype(np.float32) @ np.array([0.299, 0.587, 0.114], np.float32)
    return np.asarray(np.clip(np.rint(y), 0, 255), dtype=np.uint8)


def _apply_lut(image: NDArray[np.uint8], lut: NDArray[np.float64]) -> Grey:
    table = np.clip(np.rint(lut), 0, 255).astype(np.uint8)
    return np.asarray(cv2.LUT(image, table), dtype=np.uint8)


def stretch(image: NDArray[np.uint8]) -> NDArray[np.uint8]:
    """Dynamic-range stretch Y = (y − y_min)/(y_max − y_min) · 255 (eq. 4.1).

    Greyscale, or each channel of an RGB image on its own. A constant image (y_max = y_min) has
    no range to stretch: ValueError.
    """
    if image.ndim == 3:
        return np.dstack([stretch(np.ascontiguousarray(image[..., c])) for c in range(3)])
    _check_grey(image)
    lo, hi = int(image.min()), int(image.max())
    if hi == lo:
        raise ValueError(f"the image is constant (level {lo}): no dynamic range to stretch")
    levels = np.arange(256, dtype=np.float64)
    return _apply_lut(image, (levels - lo) / (hi - lo) * 255.0)  # eq. 4.1


def equalize(image: NDArray[np.uint8]) -> NDArray[np.uint8]:
    """Histogram equalisation Y = 255 · F(y) (eqs. 4.2–4.3, m = 256), F the empirical CDF.

    Note: not ``cv2.equalizeHist``, which maps (F − F_min)/(1 − F_min); the dissertation's form
    leaves the darkest level at 255 · F(y_min), close to zero.
    """
    if image.ndim == 3:
        return np.dstack([equalize(np.ascontiguousarray(image[..., c])) for c in range(3)])
    _check_grey(image)
    return _apply_lut(image, 255.0 * cdf_of(image))  # eq. 4.3


def cdf_of(image: Grey) -> NDArray[np.float64]:
    """Empirical CDF F(y) of a greyscale image, shape (256,)."""
    hist = cv2.calcHist([image], [0], None, [256], [0, 256]).ravel().astype(np.float64)
    return np.asarray(np.cumsum(hist) / image.size, dtype=np.float64)


def shift(image: NDArray[np.uint8], alpha: float, theta: float) -> NDArray[np.uint8]:
    """The image shift y' = α y + θ (eq. 3.1), clipped to 0–255."""
    if not (math.isfinite(alpha) and math.isfinite(theta)) or alpha <= 0:
        raise ValueError(f"need α > 0 and finite θ; got α={alpha}, θ={theta}")
    levels = np.arange(256, dtype=np.float64)
    if image.ndim == 3:
        return np.dstack(
            [shift(np.ascontiguousarray(image[..., c]), alpha, theta) for c in range(3)]
        )
    _check_grey(image)
    return _apply_lut(image, alpha * levels + theta)


def otsu_level(image: Grey) -> int:
    """Otsu's threshold of a greyscale image [level]."""
    level, _ = cv2.threshold(image, 0, 255, cv2.THRESH_BINARY | cv2.THRESH_OTSU)
    return int(level)


BORDER = 0.03
"""The band along the image's edges taken for the background, as a fraction of its short side."""


def part_is_light(image: Grey) -> bool:
    """Whether the part is lighter than what it stands on. The dissertation's cells are dark
    parts on a light table, and every later step looks for the part among the dark levels; a
    light part on a dark conveyor was outlined as the table. What runs along the image's edges
    is background: the part is light when that band's median lies below Otsu's level."""
    band = max(1, round(BORDER * min(image.shape)))
    edges = np.concatenate(
        [
            image[:band].ravel(),
            image[-band:].ravel(),
            image[band:-band, :band].ravel(),
            image[band:-band, -band:].ravel(),
        ]
    )
    return float(np.median(edges)) < otsu_level(image)


MIN_SOLIDITY = 0.96
"""A region whose area is at least this fraction of its convex hull's counts as convex."""


def part_level(image: Grey) -> int:
    """The grey level that separates the part from its shadow and the background.

    Thresholding at ever darker levels, the largest dark region shrinks in steps: background
    gone (part and shadow left), shadow gone (the part), then the lighter faces of the part
    itself. Each step is a plateau of levels over which the region's area hardly changes. A
    prismatic part or a cylinder has a convex silhouette, while a part missing a face usually
    does not; the part is taken as the darkest convex plateau that keeps at least 60 % of the
    largest convex one's area, and the middle of that plateau is returned (away from the noise
    of both neighbours). Done on a 1/4-size copy; Otsu's level when nothing qualifies.
    """
    small = image[::4, ::4]
    top = otsu_level(small)
    samples: list[tuple[int, float, float]] = []
    for level in range(top, int(small.min()), -1):
        mask = (small <= level).astype(np.uint8)
        contours, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
        if not contours:
            break
        region = max(contours, key=cv2.contourArea)
        area = cv2.contourArea(region)
        if area < 0.002 * mask.size:
            break
        solidity = area / max(cv2.contourArea(cv2.convexHull(region)), 1e-9)
        samples.append((level, area, solidity))
    plateaus: list[list[tuple[int, float, float]]] = []
    for sample in samples:
        if plateaus and sample[1] >= 0.97 * plateaus[-1][0][1]:
            plateaus[-1].append(sample)
        else:
            plateaus.append([sample])
    convex = [
        p for p in plateaus if len(p) >= 8 and float(np.median([s[2] for s in p])) >= MIN_SOLIDITY
    ]
    if not convex:
        return top
    largest = max(p[0][1] for p in convex)
    darkest = [p for p in convex if p[0][1] >= 0.6 * largest][-1]
    return darkest[len(darkest) // 2][0]


def suppress_shadow(
    image: Grey, *, alpha: float = 1.0, theta: float | None = None
) -> tuple[Grey, float, int]:
    """Equalise → shift (3.1) → equalise (chapter 3 §IV).

    Returns the image, the θ used, and the darkest input level the shift saturates (less
    one): the part is what lies at or below that level.

    The shift pushes the bright background and the lighter cast shadow to 255 together, so the
    shadow's border is no longer an edge; the darker part stays. The dissertation tunes θ by
    hand; when ``theta`` is None everything lighter than the part saturates: θ = 255 − α · t,
    with t the part's level (``part_level``) carried through the first equalisation. This
    assumes the dissertation's setting: a part darker than its shadow, on a light background.
    """
    _check_grey(image)
    eq = equalize(image)
    if theta is None:
        t = part_level(image)
        below = eq[image <= t]
        theta = 255.0 - alpha * float(below.max() if below.size else t) - 1.0
    lut = cdf_of(image) * 255.0
    kept = np.nonzero(alpha * np.rint(lut) + theta < 254.5)[0]
    level = int(kept.max()) if kept.size else 0
    return equalize(shift(eq, alpha, theta)), theta, level


@dataclass(frozen=True, slots=True)
class CannyParams:
    sigma: float = 1.5
    """Gaussian smoothing σ [px] (the dissertation: 1.5)."""
    high: float | None = 0.5
    """High threshold as a fraction of the largest gradient magnitude (MATLAB's 0–1 scale; the
    dissertation: 0.5). None: chosen from the gradient distribution (``auto_canny``)."""
    low_ratio: float = 0.4
    """Low threshold as a fraction of the high one (MATLAB's default, the dissertation's 40 %)."""


def canny(
    image: Grey, params: CannyParams = CannyParams()
) -> tuple[NDArray[np.uint8], float, float]:
    """Canny edges with MATLAB-style normalised thresholds mapped onto OpenCV's.

    MATLAB's ``edge(I, 'canny', T, σ)`` smooths with a Gaussian of σ, takes the gradient
    magnitude, scales it to 0–1 by its maximum, and uses T as the high and 0.4 T as the low
    threshold. OpenCV thresholds the unscaled L2 Sobel magnitude of its input, so: smooth with
    the same Gaussian, compute that magnitude's maximum M, and pass T·M and 0.4 T·M.
    Returns (edges 0/255, low, high) with the thresholds in OpenCV's units.
    """
    _check_grey(image)
    blurred = cv2.GaussianBlur(image, (0, 0), params.sigma)
    gx = cv2.Sobel(blurred, cv2.CV_32F, 1, 0, ksize=3)
    gy = cv2.Sobel(blurred, cv2.CV_32F, 0, 1, ksize=3)
    magnitude = np.asarray(cv2.magnitude(gx, gy), dtype=np.float32)
    top = float(magnitude.max())
    if top == 0.0:
        raise ValueError("the image has no gradient anywhere: nothing to outline")
    if params.high is None:
        high = auto_high(magnitude)
    else:
        high = params.high * top
    low = params.low_ratio * high
    edges = cv2.Canny(blurred, low, high, L2gradient=True)
    return np.asarray(edges, dtype=np.uint8), low, high


def auto_high(magnitude: NDArray[np.float32]) -> float:
    """High Canny threshold from the gradient distribution: Otsu's split of the non-zero
    magnitudes (edges against texture and noise), in magnitude units."""
    nonzero = magnitude[magnitude > 0]
    top = float(nonzero.max())
    scaled = np.clip(nonzero / top * 255.0, 0, 255).astype(np.uint8).reshape(-1, 1)
    return otsu_level(scaled) / 255.0 * top


def hough_segments(
    edges: NDArray[np.uint8],
    *,
    threshold: int = 20,
    min_length: float = 15.0,
    max_gap: float = 3.0,
) -> list[Segment]:
    """Probabilistic Hough line segments (ρ = 1 px, θ = 1°)."""
    lines = cv2.HoughLinesP(
        edges, 1, np.pi / 180, threshold, minLineLength=min_length, maxLineGap=max_gap
    )
    if lines is None:
        return []
    return [tuple(float(v) for v in line) for line in lines.reshape(-1, 4)]  # type: ignore[misc]


def _angle(s: Segment) -> float:
    return math.degrees(math.atan2(s[3] - s[1], s[2] - s[0])) % 180.0


def _length(s: Segment) -> float:
    return math.hypot(s[2] - s[0], s[3] - s[1])


def _line_distance(s: Segment, x: float, y: float) -> float:
    """Distance of (x, y) from the infinite line through segment s [px]."""
    dx, dy = s[2] - s[0], s[3] - s[1]
    return abs(dy * (x - s[0]) - dx * (y - s[1])) / math.hypot(dx, dy)


def collinear(a: Segment, b: Segment, *, max_angle: float = 5.0, max_lateral: float = 2.0) -> bool:
    """Two fragments of one line: |θ₁ − θ₂| ≤ 5° (eq. 3.2) and lateral distance ≤ 2 px (3.3).

    The lateral distance is that of the shorter fragment's endpoints from the longer one's
    line. The dissertation's alternative, "the distance between the two farthest points is at
    most the combined length plus the gap", holds for any two segments by the triangle
    inequality, so it cannot decide alone; the angle and lateral tests are used.
    """
    diff = abs(_angle(a) - _angle(b))
    if min(diff, 180.0 - diff) > max_angle:  # eq. 3.2
        return False
    longer, shorter = (a, b) if _length(a) >= _length(b) else (b, a)
    lateral = max(
        _line_distance(longer, shorter[0], shorter[1]),
        _line_distance(longer, shorter[2], shorter[3]),
    )
    return lateral <= max_lateral  # eq. 3.3


def _farthest(a: Segment, b: Segment) -> Segment:
    pts = [(a[0], a[1]), (a[2], a[3]), (b[0], b[1]), (b[2], b[3])]
    best = max(
        ((p, q) for i, p in enumerate(pts) for q in pts[i + 1 :]),
        key=lambda pq: math.hypot(pq[0][0] - pq[1][0], pq[0][1] - pq[1][1]),
    )
    return (best[0][0], best[0][1], best[1][0], best[1][1])


def join_fragments(
    segments: list[Segment], *, max_angle: float = 5.0, max_lateral: float = 2.0
) -> list[Segment]:
    """Replace every pair of collinear fragments by the segment joining their farthest points
    (chapter 3 §V.B), until no pair is left. The longest segments are considered first."""
    out = sorted(segments, key=_length, reverse=True)
    merged = True
    while merged:
        merged = False
        for i in range(len(out)):
            for j in range(i + 1, len(out)):
                if collinear(out[i], out[j], max_angle=max_angle, max_lateral=max_lateral):
                    joined = _farthest(out[i], out[j])
                    out = [s for k, s in enumerate(out) if k not in (i, j)] + [joined]
                    out.sort(key=_length, reverse=True)
                    merged = True
                    break
            if merged:
                break
    return out


def refine(segment: Segment, points: NDArray[np.float64], *, band: float = 2.0) -> Segment:
    """The segment re-fitted (total least squares) to the edge points within ``band`` px of its
    line and within its extent; unchanged when fewer than 5 points qualify. Hough lines are
    quantised to 1 px and 1°; the fit recovers the sub-pixel line."""
    x1, y1, x2, y2 = segment
    d = np.array([x2 - x1, y2 - y1])
    length = float(np.hypot(*d))
    u = d / length
    rel = points - np.array([x1, y1])
    along = rel @ u
    across = np.abs(rel @ np.array([-u[1], u[0]]))
    near = points[(across <= band) & (along >= -0.05 * length) & (along <= 1.05 * length)]
    if len(near) < 5:
        return segment
    vx, vy, x0, y0 = cv2.fitLine(near.astype(np.float32), cv2.DIST_L2, 0, 0.01, 0.01).ravel()
    v, p0 = np.array([vx, vy], dtype=np.float64), np.array([x0, y0], dtype=np.float64)
    a = p0 + v * ((np.array([x1, y1]) - p0) @ v)
    b = p0 + v * ((np.array([x2, y2]) - p0) @ v)
    return (float(a[0]), float(a[1]), float(b[0]), float(b[1]))


def intersect(a: Segment, b: Segment) -> tuple[float, float] | None:
    """Intersection of the infinite lines through a and b; None when (nearly) parallel."""
    x1, y1, x2, y2 = a
    x3, y3, x4, y4 = b
    den = (x1 - x2) * (y3 - y4) - (y1 - y2) * (x3 - x4)
    if abs(den) < 1e-9 * max(_length(a) * _length(b), 1.0):
        return None
    p = x1 * y2 - y1 * x2
    q = x3 * y4 - y3 * x4
    return ((p * (x3 - x4) - (x1 - x2) * q) / den, (p * (y3 - y4) - (y1 - y2) * q) / den)


def order_segments(segments: list[Segment]) -> list[Segment]:
    """Chain the sides of a polygon: from the end of each segment to the nearest endpoint of a
    segment not yet used, which then runs from that endpoint (chapter 3 §V.A)."""
    if not segments:
        return []
    rest = list(segments[1:])
    chain = [segments[0]]
    while rest:
        ex, ey = chain[-1][2], chain[-1][3]
        best, flip, best_d = 0, False, math.inf
        for k, s in enumerate(rest):
            for reverse, (px, py) in ((False, (s[0], s[1])), (True, (s[2], s[3]))):
                d = math.hypot(px - ex, py - ey)
                if d < best_d:
                    best, flip, best_d = k, reverse, d
        s = rest.pop(best)
        chain.append((s[2], s[3], s[0], s[1]) if flip else s)
    return chain


def signed_area(points: ArrayLike) -> float:
    """Shoelace area in image coordinates (y down): negative for counter-clockwise as seen."""
    p = np.asarray(points, dtype=np.float64)
    x, y = p[:, 0], p[:, 1]
    return float(0.5 * (x @ np.roll(y, -1) - np.roll(x, -1) @ y))


def corners_from_segments(segments: list[Segment]) -> NDArray[np.float64]:
    """The polygon's corners from incomplete sides (chapter 3 §V.A), shape (n, 2) [px].

    Sides are chained by nearest endpoints, adjacent sides intersected as infinite lines, and
    the corners returned counter-clockwise as seen in the image (y down), starting with the
    corner nearest the first segment's start point.
    """
    if len(segments) < 3:
        raise ValueError(f"a polygon needs at least 3 sides; got {len(segments)} segments")
    chain = order_segments(segments)
    corners = []
    for a, b in zip(chain, chain[1:] + chain[:1], strict=True):
        p = intersect(a, b)
        if p is None:
            raise ValueError("two adjacent sides are parallel: not a closed polygon")
        corners.append(p)
    pts = np.array(corners)
    if signed_area(pts) > 0:  # clockwise as seen: reverse
        pts = pts[::-1]
    start = np.argmin(np.hypot(pts[:, 0] - segments[0][0], pts[:, 1] - segments[0][1]))
    return np.roll(pts, -start, axis=0)


@dataclass(frozen=True, slots=True)
class Ellipse:
    center: tuple[float, float]
    axes: tuple[float, float]
    """Full lengths of the two axes [px]."""
    angle: float
    """Rotation of the first axis [°]."""


@dataclass(frozen=True, slots=True)
class Outline:
    shape: Literal["polygon", "curved"]
    corners: NDArray[np.float64]
    """Polygon corners, counter-clockwise as seen, shape (n, 2) [px]; empty for curved."""
    lines: list[Segment]
    contour: NDArray[np.float64]
    """The outer contour, simplified, shape (m, 2) [px]."""
    ellipses: list[Ellipse] = field(default_factory=list)
    edges: NDArray[np.uint8] | None = None
    conditioned: NDArray[np.uint8] | None = None
    canny_thresholds: tuple[float, float] = (0.0, 0.0)
    shadow_theta: float | None = None
    part: Literal["dark", "light"] = "dark"
    """Which way round the part and its background were taken (``conditioned`` is of the
    image inverted for a light part)."""


@dataclass(frozen=True, slots=True)
class OutlineParams:
    stretch: bool = True
    shadow: bool = True
    """Equalise → shift → equalise before the edges (chapter 3 §IV)."""
    alpha: float = 1.0
    theta: float | None = None
    canny: CannyParams = CannyParams()
    hough_threshold: int = 20
    min_length: float | None = None
    """Shortest side kept after joining [px]; default 4 % of the outer contour's length. Hough
    itself keeps fragments down to a quarter of that, for the joining step to mend."""
    max_gap: float = 5.0
    max_angle: float = 5.0
    max_lateral: float = 2.0
    polygon_tolerance: float = 3.0
    """A contour point further than this from every side is not explained by the polygon [px]."""
    polygon_fraction: float = 0.9
    """Fraction of contour points the sides must explain for the outline to be a polygon."""
    part: Literal["auto", "dark", "light"] = "auto"
    """A part darker than its background (the dissertation's), lighter, or told by
    ``part_is_light``."""


def _points(mask: NDArray[np.uint8]) -> NDArray[np.float64]:
    """(x, y) of the non-zero pixels, shape (n, 2)."""
    found = cv2.findNonZero(mask)
    return np.empty((0, 2)) if found is None else found.reshape(-1, 2).astype(np.float64)


def _outer_contour(base: Grey, level: int | None, sigma: float) -> NDArray[np.int32]:
    """The outer contour of the largest region at or below ``level`` (Otsu's when None) in the
    smoothed image: the part, without its shadow when ``level`` comes from the shadow step.
    Found on the smoothed stretched image rather than the conditioned one, whose second
    equalisation spreads a noisy face of the part over the whole range."""
    smooth = cv2.GaussianBlur(base, (0, 0), sigma)
    level = otsu_level(np.asarray(smooth, dtype=np.uint8)) if level is None else level
    mask = (smooth <= level).astype(np.uint8)
    mask = np.asarray(cv2.morphologyEx(mask, cv2.MORPH_OPEN, np.ones((3, 3), np.uint8)), np.uint8)
    contours, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    if not contours:
        raise ValueError("no object found: no region stands out from the background")
    return np.asarray(max(contours, key=cv2.contourArea), dtype=np.int32)


def _explained(
    contour: NDArray[np.float64], segments: list[Segment], tol: float
) -> NDArray[np.bool_]:
    """Which contour points lie within ``tol`` of some segment (as a finite segment)."""
    if not segments:
        return np.zeros(len(contour), dtype=bool)
    s = np.asarray(segments, dtype=np.float64)
    a, b = s[:, :2], s[:, 2:]
    ab = b - a
    t = ((contour[:, None, :] - a) * ab).sum(-1) / np.maximum((ab * ab).sum(-1), 1e-12)
    nearest = a + np.clip(t, 0, 1)[..., None] * ab
    d = np.linalg.norm(contour[:, None, :] - nearest, axis=-1)
    return np.asarray(d.min(axis=1) <= tol, dtype=np.bool_)


def outline(grey: Grey, params: OutlineParams = OutlineParams()) -> Outline:
    """The outline of the part in a greyscale image: corners and sides, or contour and ellipses.

    Steps: a light part's image inverted (``params.part``) → stretch (4.1) → optional shadow
    suppression (3.1 with 4.3) → Canny → the outer contour of the part → Hough segments on the
    edges along that contour (inner edges between a part's faces are not its outline) →
    fragments joined (3.2–3.3) → short sides dropped → corners (§V.A). When the straight sides
    do not explain the contour (a cylinder's elliptic arcs), the outline is ``curved``: the
    contour, the straight sides, and ellipses fitted to the arcs.
    """
    _check_grey(grey)
    if min(grey.shape) < 8:
        raise ValueError(f"image too small to outline: {grey.shape[1]}×{grey.shape[0]}")
    light = params.part == "light" or (params.part == "auto" and part_is_light(grey))
    if light:  # the steps below find a dark part on a light ground: turn it round
        grey = np.asarray(cv2.bitwise_not(grey), dtype=np.uint8)
    base = stretch(grey) if params.stretch else grey
    work = base
    theta, level = None, None
    if params.shadow:
        work, theta, level = suppress_shadow(work, alpha=params.alpha, theta=params.theta)
    edges, low, high = canny(work, params.canny)
    contour_px = _outer_contour(base, level, params.canny.sigma)
    contour = contour_px.reshape(-1, 2).astype(np.float64)
    perimeter = cv2.arcLength(contour_px, True)
    band = np.zeros_like(edges)
    cv2.drawContours(band, [contour_px], -1, 255, thickness=7)
    outer_edges = np.asarray(cv2.bitwise_and(edges, band), dtype=np.uint8)
    min_length = params.min_length or max(8.0, 0.04 * perimeter)
    raw = hough_segments(
        outer_edges,
        threshold=params.hough_threshold,
        min_length=max(4.0, min_length / 4),
        max_gap=params.max_gap,
    )
    sides = join_fragments(raw, max_angle=params.max_angle, max_lateral=params.max_lateral)
    sides = [s for s in sides if _length(s) >= min_length]
    # fit each side to the edges of the part itself (the stretched image, before the shadow
    # step remaps the levels around the boundary)
    if params.shadow:  # only around the part: a quarter of the work of the whole frame
        x, y, w, h = cv2.boundingRect(contour_px)
        m = 12
        x0, y0 = max(0, x - m), max(0, y - m)
        box = np.ascontiguousarray(base[y0 : y + h + m, x0 : x + w + m])
        edge_points = _points(canny(box, params.canny)[0]) + np.array([x0, y0], dtype=np.float64)
    else:
        edge_points = _points(edges)
    sides = [refine(s, edge_points) for s in sides]
    simplified = cv2.approxPolyDP(contour_px, 1.0, True).reshape(-1, 2).astype(np.float64)
    common = dict(
        lines=sides,
        contour=simplified,
        edges=edges,
        conditioned=work,
        canny_thresholds=(low, high),
        shadow_theta=theta,
        part="light" if light else "dark",
    )
    if len(sides) >= 3:
        try:
            corners: NDArray[np.float64] | None = corners_from_segments(sides)
        except ValueError:
            corners = None
        outline_points = _points(outer_edges)
        if corners is not None and _is_polygon(corners, outline_points, params):
            return Outline(shape="polygon", corners=corners, **common)  # type: ignore[arg-type]
    # curved: the long straight sides stay, short chords along the arcs are not sides
    straight = [s for s in sides if _length(s) >= CURVED_MIN_SIDE * perimeter]
    common["lines"] = straight
    arcs = ~_explained(contour, straight, params.polygon_tolerance)
    return Outline(
        shape="curved",
        corners=np.empty((0, 2)),
        ellipses=_fit_arcs(contour, arcs),
        **common,  # type: ignore[arg-type]
    )


MIN_TURN = 12.0
"""A polygon turns by at least this much at each corner [°]; smaller turns are chords of a
curve."""


def _is_polygon(
    corners: NDArray[np.float64], points: NDArray[np.float64], params: OutlineParams
) -> bool:
    """Do the completed sides explain the outline's edge points, with real corners between?"""
    closed = np.vstack([corners, corners[:1]])
    sides = [tuple(closed[i]) + tuple(closed[i + 1]) for i in range(len(corners))]
    explained = _explained(points, sides, params.polygon_tolerance)
    if explained.mean() < params.polygon_fraction:
        return False
    d = np.diff(closed, axis=0)
    heading = np.degrees(np.arctan2(d[:, 1], d[:, 0]))
    turn = np.abs((np.diff(np.append(heading, heading[0])) + 180.0) % 360.0 - 180.0)
    return bool(turn.min() >= MIN_TURN)


CURVED_MIN_SIDE = 0.12
"""In a curved outline, straight sides are at least this fraction of the contour's length."""


def _fit_arcs(contour: NDArray[np.float64], curved: NDArray[np.bool_]) -> list[Ellipse]:
    """Ellipses fitted to each run of contour points the straight sides do not explain."""
    n = len(contour)
    if n == 0 or not curved.any():
        return []
    if curved.all():
        runs = [contour]
    else:
        start = int(np.argmin(curved))  # begin the scan at an explained point
        order = np.roll(np.arange(n), -start)
        runs, current = [], []
        for k in order:
            if curved[k]:
                current.append(contour[k])
            elif current:
                runs.append(np.array(current))
                current = []
        if current:
            runs.append(np.array(current))
    ellipses = []
    for run in runs:
        if len(run) < max(10, n // 20):
            continue
        (cx, cy), (a, b), angle = cv2.fitEllipse(run.astype(np.float32))
        ellipses.append(Ellipse((float(cx), float(cy)), (float(a), float(b)), float(angle)))
    return ellipses


def crop(
    image: NDArray[np.uint8], roi: tuple[int, int, int, int] | None
) -> tuple[NDArray[np.uint8], tuple[int, int]]:
    """The region of interest and its offset (x, y), to map results back to the full image."""
    if roi is None:
        return image, (0, 0)
    x, y, w, h = roi
    height, width = image.shape[:2]
    if w <= 0 or h <= 0 or x < 0 or y < 0 or x + w > width or y + h > height:
        raise ValueError(f"ROI {list(roi)} does not lie inside the {width}×{height} image")
    return image[y : y + h, x : x + w], (x, y)
