"""Image conditioning and part outlines: [Fayed 2013] chapter 3 and chapter 4 §II.

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
from scipy.spatial import cKDTree

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

    Note: not ``cv2.equalizeHist``, which maps (F − F_min)/(1 − F_min); [Fayed 2013]'s form
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
    """Whether the part is lighter than what it stands on. [Fayed 2013]'s cells are dark
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


MAX_CONCAVITY = 2.5
"""A region whose deepest dent from its convex hull is at most this deep counts as convex
[px]: the staircase of a digitised straight side dents it by about a pixel."""

PLATEAU_STEP = 1.03
"""Between two scanned levels, the largest dark region growing by more than this factor is a
step (a face, the shadow or the table joining); smaller growth is the blur's ramp."""


def _largest_region(mask: NDArray[np.uint8]) -> NDArray[np.int32] | None:
    contours, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    if not contours:
        return None
    return np.asarray(max(contours, key=cv2.contourArea), dtype=np.int32)


def concavity(region: NDArray[np.int32]) -> float:
    """The depth of the region's deepest dent from its convex hull [px]."""
    hull = cv2.convexHull(region, returnPoints=False)
    if hull is None or len(hull) < 3:
        return 0.0
    try:
        defects = cv2.convexityDefects(region, np.sort(hull, axis=0))
    except cv2.error:  # a contour that crosses itself: not a part's silhouette
        return math.inf
    return 0.0 if defects is None else float(defects.reshape(-1, 4)[:, 3].max()) / 256.0


def part_level(image: Grey, sigma: float = 1.5) -> int | None:
    """The grey level that separates a dark part from its shadow and the background [level],
    or None when no region qualifies.

    Thresholding the smoothed image (σ [px], as for the contour) at ever lighter levels, the
    largest dark region grows in steps: the part's darkest faces, the whole part, the part with
    its shadow, the table. A box's or a cylinder's silhouette is convex; a part with its cast
    shadow is dented where the shadow leaves the part, and the table reaches the image's
    border. The part is taken from the lightest run of levels whose region is convex
    (``MAX_CONCAVITY``), stays off the border and covers less than half the image: the middle
    of that run's last plateau (after its last step), away from the blur of both
    neighbouring steps. When the shadow lies along the part, the two are one convex region and
    cannot be told apart by levels; the shadow step then keeps the shadow's edge out.
    [Fayed 2013] tunes the level by hand (chapter 3 §IV).
    """
    _check_grey(image)
    smooth = np.asarray(cv2.GaussianBlur(image, (0, 0), sigma), dtype=np.uint8)
    height, width = smooth.shape
    samples: list[tuple[int, float, bool]] = []
    for level in range(int(smooth.min()), 255, 2):
        region = _largest_region((smooth <= level).astype(np.uint8))
        if region is None:
            continue
        area = float(cv2.contourArea(region))
        if area > 0.5 * smooth.size:
            break
        x, y, w, h = cv2.boundingRect(region)
        ok = (
            area >= 0.001 * smooth.size
            and x > 1
            and y > 1
            and x + w < width - 1
            and y + h < height - 1
            and concavity(region) <= MAX_CONCAVITY
        )
        samples.append((level, area, ok))
    runs: list[list[tuple[int, float, bool]]] = []
    for sample in samples:
        if sample[2] and runs and runs[-1][-1][0] == sample[0] - 2 and runs[-1][-1][2]:
            runs[-1].append(sample)
        elif sample[2]:
            runs.append([sample])
    runs = [r for r in runs if len(r) >= 3]
    if not runs:
        return None
    run = runs[-1]
    last_step = max(
        (i for i in range(1, len(run)) if run[i][1] > PLATEAU_STEP * run[i - 1][1]), default=0
    )
    plateau = run[last_step:] if len(run) - last_step >= 2 else run
    return plateau[len(plateau) // 2][0]


def suppress_shadow(
    image: Grey, *, alpha: float = 1.0, theta: float | None = None, part: int | None = None
) -> tuple[Grey, float, int]:
    """Equalise → shift (3.1) → equalise (chapter 3 §IV).

    Returns the image, the θ used, and the darkest input level the shift saturates (less
    one): the part is what lies at or below that level.

    The shift pushes the bright background and the lighter cast shadow to 255 together, so the
    shadow's border is no longer an edge; the darker part stays. [Fayed 2013] tunes θ by
    hand; when ``theta`` is None everything lighter than the part saturates: θ = 255 − α · t,
    with t the part's level (``part``, else ``part_level``) carried through the first
    equalisation. This
    assumes [Fayed 2013]'s setting: a part darker than its shadow, on a light background.
    """
    _check_grey(image)
    eq = equalize(image)
    if theta is None:
        found = part_level(image) if part is None else part
        t = otsu_level(image) if found is None else found
        below = eq[image <= t]
        theta = 255.0 - alpha * float(below.max() if below.size else t) - 1.0
    lut = cdf_of(image) * 255.0
    kept = np.nonzero(alpha * np.rint(lut) + theta < 254.5)[0]
    level = int(kept.max()) if kept.size else 0
    return equalize(shift(eq, alpha, theta)), theta, level


@dataclass(frozen=True, slots=True)
class CannyParams:
    sigma: float = 1.5
    """Gaussian smoothing σ [px] ([Fayed 2013]: 1.5)."""
    high: float | None = 0.5
    """High threshold as a fraction of the largest gradient magnitude (MATLAB's 0–1 scale; the
    dissertation: 0.5). None: chosen from the gradient distribution (``auto_canny``)."""
    low_ratio: float = 0.4
    """Low threshold as a fraction of the high one (MATLAB's default, [Fayed 2013]'s 40 %)."""


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


@dataclass(frozen=True, slots=True)
class Gradient:
    """An image smoothed with σ [px] and its Sobel derivatives, each (H, W) float32: made once
    for the sub-pixel edges and the outline test, which both look across the edges."""

    smooth: NDArray[np.float32]
    gx: NDArray[np.float32]
    gy: NDArray[np.float32]

    @classmethod
    def of(cls, image: Grey, sigma: float) -> Gradient:
        smooth = np.asarray(cv2.GaussianBlur(image.astype(np.float32), (0, 0), sigma), np.float32)
        gx = np.asarray(cv2.Sobel(smooth, cv2.CV_32F, 1, 0, ksize=3), np.float32)
        gy = np.asarray(cv2.Sobel(smooth, cv2.CV_32F, 0, 1, ksize=3), np.float32)
        return cls(smooth, gx, gy)


SAMPLE_ROW = 1024
"""Points remapped a row at a time: ``cv2.remap`` asserts its maps have fewer than 32,767 rows
(SHRT_MAX), and a large photo's part yields more edge points than that."""


def _sample(image: NDArray[np.float32], at: NDArray[np.floating]) -> NDArray[np.float32]:
    """``image`` at the points ``at`` (n, 2) (x, y), bilinear, shape (n,)."""
    xy = np.asarray(at, dtype=np.float32).reshape(-1, 2)
    n = xy.shape[0]
    rows = max(1, -(-n // SAMPLE_ROW))
    grid = np.zeros((rows * SAMPLE_ROW, 2), np.float32)
    grid[:n] = xy
    maps = grid.reshape(rows, SAMPLE_ROW, 2)
    out = cv2.remap(image, maps[:, :, 0].copy(), maps[:, :, 1].copy(), cv2.INTER_LINEAR)
    return np.asarray(out, dtype=np.float32).ravel()[:n]


def _unit(g: NDArray[np.float32]) -> NDArray[np.float32]:
    """Each row of ``g`` (n, 2) scaled to length 1 (a zero row stays zero)."""
    return np.asarray(g / np.maximum(np.linalg.norm(g, axis=1, keepdims=True), 1e-9), np.float32)


def subpixel_edges(grad: Gradient, edges: NDArray[np.uint8]) -> NDArray[np.float64]:
    """The edge pixels moved to the gradient's peak across the edge, shape (n, 2) [px].

    Canny marks whole pixels, which puts a nearly horizontal or vertical side up to half a
    pixel off, the same way along its whole length, so no line fit averages it out. Across
    the edge (along the gradient ``grad`` of the smoothed image) the magnitude is sampled one
    pixel either side, and a parabola through the three samples puts the peak (within a pixel
    of the marked one)."""
    found = cv2.findNonZero(edges)
    if found is None:
        return np.empty((0, 2))
    pts = found.reshape(-1, 2).astype(np.float32)
    magnitude = np.asarray(cv2.magnitude(grad.gx, grad.gy), np.float32)
    xi, yi = pts[:, 0].astype(int), pts[:, 1].astype(int)
    n = _unit(np.column_stack([grad.gx[yi, xi], grad.gy[yi, xi]]))
    before, here, after = (
        _sample(magnitude, pts - n),
        magnitude[yi, xi],
        _sample(magnitude, pts + n),
    )
    curvature = before - 2.0 * here + after
    step = np.where(curvature < 0, 0.5 * (before - after) / np.minimum(curvature, -1e-9), 0.0)
    return np.asarray(pts + np.clip(step, -1.0, 1.0)[:, None] * n, dtype=np.float64)


PART_SIDE = 2.0
"""How far across an edge, on its brighter side, the part is looked for [px]."""


def _on_outline(grad: Gradient, points: NDArray[np.float64], level: int) -> NDArray[np.bool_]:
    """Which edge points (n, 2) are on the part's outline: the smoothed image (``grad``)
    ``PART_SIDE`` px across the edge on its brighter side (along the gradient) lies above the
    part's ``level``. An edge between two faces of the part has the part on both sides: where
    it meets the outline at a gentle corner, or runs a pixel inside it along a face seen edge
    on, it lies within the polish's band of a side, and fitted with it the side tilts (a
    corner turning 12° moves 1/sin 12° ≈ 5 times as far as the side's end)."""
    if not len(points):
        return np.zeros(0, dtype=np.bool_)
    n = _unit(np.column_stack([_sample(grad.gx, points), _sample(grad.gy, points)]))
    brighter = _sample(grad.smooth, points + PART_SIDE * n)
    return np.asarray(brighter > level, dtype=np.bool_)


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
    line. [Fayed 2013]'s alternative, "the distance between the two farthest points is at
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
    pts = _chain_corners(order_segments(segments))
    start = np.argmin(np.hypot(pts[:, 0] - segments[0][0], pts[:, 1] - segments[0][1]))
    return np.roll(pts, -start, axis=0)


def _chain_corners_in_order(chain: list[Segment]) -> NDArray[np.float64]:
    """Corner k of a closed chain is where side k meets side k + 1 (infinite lines)."""
    corners = []
    for a, b in zip(chain, chain[1:] + chain[:1], strict=True):
        p = intersect(a, b)
        if p is None:
            raise ValueError("two adjacent sides are parallel: not a closed polygon")
        corners.append(p)
    return np.array(corners)


def _counter_clockwise(corners: NDArray[np.float64]) -> NDArray[np.float64]:
    return corners[::-1] if signed_area(corners) > 0 else corners


def _chain_corners(chain: list[Segment]) -> NDArray[np.float64]:
    """Corners of a closed chain of sides, each adjacent pair intersected as infinite lines,
    counter-clockwise as seen; shape (n, 2) [px]."""
    return _counter_clockwise(_chain_corners_in_order(chain))


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
    residual: float
    """RMS distance of the outline's edge pixels from the fitted shape [px]."""
    support: float
    """Share of the fitted shape's length with an edge pixel within ``SUPPORT_DISTANCE`` [0–1]."""
    ellipses: list[Ellipse] = field(default_factory=list)
    edges: NDArray[np.uint8] | None = None
    conditioned: NDArray[np.uint8] | None = None
    canny_thresholds: tuple[float, float] = (0.0, 0.0)
    shadow_theta: float | None = None
    part: Literal["dark", "light"] = "dark"
    """Which way round the part and its background were taken (``conditioned`` is of the
    image inverted for a light part)."""


class OutlineNotFound(ValueError):
    """The image supports no outline: no part stands out, or neither a polygon nor a curved
    shape fits its edges. The message says which, with the figures."""


@dataclass(frozen=True, slots=True)
class OutlineParams:
    stretch: bool = True
    shadow: bool = True
    """Equalise → shift → equalise before the edges (chapter 3 §IV)."""
    alpha: float = 1.0
    theta: float | None = None
    canny: CannyParams = CannyParams()
    hough_threshold: int = 15
    min_length: float | None = None
    """Shortest side kept after joining and refitting [px]; default 2.5 % of the outer
    contour's length, at least 10 px. Hough itself keeps fragments down to a third of that,
    for the joining step to mend."""
    max_gap: float = 5.0
    max_angle: float = 5.0
    max_lateral: float = 2.0
    polygon_tolerance: float = 3.0
    """An edge pixel further than this from every side is not explained by the shape [px]."""
    polygon_fraction: float = 0.9
    """Share of the outline's edge pixels the shape must explain."""
    min_support: float = 0.75
    """Share of the shape's length its edges must back."""
    max_residual: float = 1.0
    """Largest RMS distance of the edge pixels from the shape [px]."""
    part: Literal["auto", "dark", "light"] = "auto"
    """A part darker than its background ([Fayed 2013]'s), lighter, or told by
    ``part_is_light``."""


FIT_CANNY = CannyParams(sigma=0.8, high=0.2)
"""Canny for the edges the sides are fitted to: a part whose face is close to its table's
level leaves a side far weaker than the strongest edge, which sets MATLAB's scale."""

SUPPORT_DISTANCE = 1.5
"""A point of a fitted shape is backed by an edge pixel within this distance [px]."""


def _points(mask: NDArray[np.uint8]) -> NDArray[np.float64]:
    """(x, y) of the non-zero pixels, shape (n, 2)."""
    found = cv2.findNonZero(mask)
    return np.empty((0, 2)) if found is None else found.reshape(-1, 2).astype(np.float64)


def _outer_contour(base: Grey, level: int, sigma: float) -> NDArray[np.int32]:
    """The outer contour of the largest region at or below ``level`` in the smoothed image:
    the part, without its shadow. Found on the smoothed stretched image rather than the
    conditioned one, whose second equalisation spreads a noisy face of the part over the
    whole range."""
    smooth = cv2.GaussianBlur(base, (0, 0), sigma)
    mask = (smooth <= level).astype(np.uint8)
    mask = np.asarray(cv2.morphologyEx(mask, cv2.MORPH_OPEN, np.ones((3, 3), np.uint8)), np.uint8)
    contours, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    if not contours:
        raise OutlineNotFound("no region stands out from the background")
    return np.asarray(max(contours, key=cv2.contourArea), dtype=np.int32)


def _distances(points: NDArray[np.float64], segments: list[Segment]) -> NDArray[np.float64]:
    """Distance of each point from the nearest of the finite segments [px], shape (n,)."""
    if not segments:
        return np.full(len(points), np.inf)
    s = np.asarray(segments, dtype=np.float64)
    a, b = s[:, :2], s[:, 2:]
    ab = b - a
    out = np.empty(len(points))
    for i in range(0, len(points), 4096):  # bounded memory on long contours
        chunk = points[i : i + 4096]
        t = ((chunk[:, None, :] - a) * ab).sum(-1) / np.maximum((ab * ab).sum(-1), 1e-12)
        nearest = a + np.clip(t, 0, 1)[..., None] * ab
        out[i : i + 4096] = np.linalg.norm(chunk[:, None, :] - nearest, axis=-1).min(axis=1)
    return out


def _explained(
    points: NDArray[np.float64], segments: list[Segment], tol: float
) -> NDArray[np.bool_]:
    """Which points lie within ``tol`` of some segment (as a finite segment)."""
    return np.asarray(_distances(points, segments) <= tol, dtype=np.bool_)


@dataclass(frozen=True, slots=True)
class _Fit:
    explained: float
    residual: float
    support: float


def _fit(
    points: NDArray[np.float64], model: list[Segment], near_edge: NDArray[np.float32], tol: float
) -> _Fit:
    """How well a shape (as segments) fits the outline's edge pixels: the share within
    ``tol``, the RMS distance of those [px] (the pixels beyond ``tol`` are counted by the
    share, not allowed to swamp the RMS), and the share of the shape's length within
    ``SUPPORT_DISTANCE`` of an edge pixel (``near_edge``: distance to the nearest one)."""
    d = _distances(points, model)
    inside = d <= tol
    explained = float(inside.mean()) if len(d) else 0.0
    residual = float(np.sqrt(np.mean(d[inside] ** 2))) if inside.any() else math.inf
    counts = [_backing(side, near_edge) for side in model]
    backed, total = sum(b for b, _ in counts), sum(n for _, n in counts)
    return _Fit(explained, residual, backed / total if total else 0.0)


def _backing(side: Segment, near_edge: NDArray[np.float32]) -> tuple[int, int]:
    """Of ``n`` points a pixel apart along the segment, how many lie within
    ``SUPPORT_DISTANCE`` of an edge pixel (``near_edge``: distance to the nearest one); and n."""
    height, width = near_edge.shape
    x1, y1, x2, y2 = side
    n = max(2, math.ceil(math.hypot(x2 - x1, y2 - y1)))
    xi = np.rint(np.linspace(x1, x2, n)).astype(int)
    yi = np.rint(np.linspace(y1, y2, n)).astype(int)
    ok = (xi >= 0) & (yi >= 0) & (xi < width) & (yi < height)
    return int((near_edge[yi[ok], xi[ok]] <= SUPPORT_DISTANCE).sum()), n


def _sides(corners: NDArray[np.float64]) -> list[Segment]:
    """The sides of a closed polygon: side k runs from corner k − 1 to corner k."""
    return [
        (float(a[0]), float(a[1]), float(b[0]), float(b[1]))
        for a, b in zip(np.roll(corners, 1, axis=0), corners, strict=True)
    ]


def _prune(
    corners: NDArray[np.float64], near_edge: NDArray[np.float32], points: NDArray[np.float64]
) -> NDArray[np.float64]:
    """The polygon without the corners that are none, the sides polished again (``_polish`` to
    the edge ``points``) after each goes, while more than 3 remain:

    - a vertex turning less than ``MIN_TURN``: its two sides are one;
    - a side that edges (``near_edge``) back along less than ``MIN_SIDE_SUPPORT`` of its
      length, the weakest first: its neighbours meet where their lines cross. A spike out to a
      shadow's corner, or a chord across a corner's rounding, has no edge along it, though the
      polygon's length as a whole is well backed.
    """
    while len(corners) > 3:
        turns = _turns(corners)
        if float(turns.min()) < MIN_TURN:
            corners = _polish(np.delete(corners, int(np.argmin(turns)), axis=0), points)
            continue
        sides = _sides(corners)
        backing = [b / n for b, n in (_backing(side, near_edge) for side in sides)]
        k = int(np.argmin(backing))
        if backing[k] >= MIN_SIDE_SUPPORT:
            break
        del sides[k]
        try:
            met = _chain_corners_in_order(sides[1:] + sides[:1])
        except ValueError:  # the neighbours are parallel: nothing to mend
            break
        # a side of no length left between two corners that met: one corner
        apart = np.linalg.norm(met - np.roll(met, 1, axis=0), axis=1) > 1e-6
        if apart.sum() < 3:
            break
        corners = _polish(met[apart], points)
    return corners


MIN_SIDE_SUPPORT = 0.5
"""A side is backed by edges along at least this share of its length."""


def _chain_along(
    sides: list[Segment], contour: NDArray[np.float64], tol: float, min_points: float
) -> list[Segment]:
    """The sides in the order they run along the part's contour. Each contour point belongs to
    the nearest side within ``tol`` [px]; a side that owns fewer than ``min_points`` points is
    dropped (and ownership recounted), the rest are ordered by where their points lie.

    Departs from [Fayed 2013]'s nearest-endpoint chaining (§V.A, ``order_segments``),
    which goes astray when a side is missing or a fragment cuts a blurred corner: the contour
    knows the order, and a chord across a corner owns only the few points of the rounding.
    Owning by the nearest side, rather than by any side within ``tol``, keeps a short side
    between two gently turning long ones: their extensions come within ``tol`` of much of it.
    """
    n = len(contour)
    kept = list(sides)
    while kept:
        d = np.column_stack([_distances(contour, [side]) for side in kept])
        owner = np.where(d.min(axis=1) <= tol, d.argmin(axis=1), -1)
        counts = np.bincount(owner[owner >= 0], minlength=len(kept))
        weakest = int(np.argmin(counts))
        if counts[weakest] >= min_points:
            break
        kept.pop(weakest)
    if not kept:
        return []
    positions = []
    for k in range(len(kept)):
        angle = np.nonzero(owner == k)[0] / n * 2 * math.pi
        position = math.atan2(float(np.sin(angle).mean()), float(np.cos(angle).mean()))
        positions.append(position % (2 * math.pi))
    return [kept[k] for k in np.argsort(positions)]


def _line_rms(points: NDArray[np.float64]) -> tuple[float, NDArray[np.float64]]:
    """RMS distance of points from their total-least-squares line [px], and its direction."""
    centred = points - points.mean(axis=0)
    _, sv, vt = np.linalg.svd(centred, full_matrices=False)
    return float(sv[-1] / math.sqrt(len(points))), vt[0]


def _split_kinks(
    chain: list[Segment],
    contour: NDArray[np.float64],
    points: NDArray[np.float64],
    tol: float,
    min_length: float,
) -> list[Segment]:
    """Each side whose own stretch of contour two lines fit much better than one, split there
    into two, each refitted to the edge ``points`` (the split of split-and-merge). Hough
    fragments of two sides meeting at a gentle corner (10–20°) join across it into one
    compromise line; the contour shows the corner. The stretch's ends (``SPLIT_TRIM``) are
    left out: there the blur rounds it into the neighbouring sides."""
    out: list[Segment] = []
    if len(chain) < 2:
        return chain
    d = np.column_stack([_distances(contour, [side]) for side in chain])
    owner = np.where(d.min(axis=1) <= SPLIT_REACH, d.argmin(axis=1), -1)
    for i, side in enumerate(chain):
        own = np.nonzero(owner == i)[0]
        if len(own) < 2 * min_length:
            out.append(side)
            continue
        gaps = np.diff(np.append(own, own[0] + len(contour)))
        run = contour[np.roll(own, -(int(np.argmax(gaps)) + 1))]  # in contour order
        run = run[SPLIT_TRIM:-SPLIT_TRIM]
        one, _ = _line_rms(run)
        if one <= SPLIT_RMS:
            out.append(side)
            continue
        best, at = math.inf, 0
        m = round(0.4 * min_length)
        for k in range(m, len(run) - m, 2):
            (r1, d1), (r2, d2) = _line_rms(run[: k + 1]), _line_rms(run[k:])
            two = math.sqrt((r1**2 * (k + 1) + r2**2 * (len(run) - k)) / (len(run) + 1))
            turn = math.degrees(math.acos(min(1.0, abs(float(d1 @ d2)))))
            if two < best and turn >= MERGE_TURN:
                best, at = two, k
        if best > 0.5 * one:
            out.append(side)
            continue
        for lo, hi in ((run[0], run[at]), (run[at], run[-1])):
            out.append(refine((float(lo[0]), float(lo[1]), float(hi[0]), float(hi[1])), points))
    return out


SPLIT_REACH = 8.0
"""Contour points up to this far from their nearest side are its own when splitting [px]."""

SPLIT_RMS = 0.4
"""A side's contour further than this (RMS) from one line may have a corner in it [px]."""

SPLIT_TRIM = 3
"""Contour points left out at each end of a side's stretch when looking for a kink in it: the
blur rounds a corner over about as many, and a short side meeting a long one at a gentle corner
leaves only a few more beyond them."""


def _turns(corners: NDArray[np.float64]) -> NDArray[np.float64]:
    """How much the outline turns at each corner [°]."""
    d = np.diff(np.vstack([corners, corners[:1]]), axis=0)
    heading = np.degrees(np.arctan2(d[:, 1], d[:, 0]))
    return np.asarray(np.abs((heading - np.roll(heading, 1) + 180.0) % 360.0 - 180.0))


def _polygon(
    chain: list[Segment], points: NDArray[np.float64], min_side: float
) -> NDArray[np.float64] | None:
    """Corners of the chained sides. Adjacent sides turning by less than ``MERGE_TURN`` are one
    side broken by noise: they become one, refitted to the edge ``points``. A side whose edge
    between its two corners comes out shorter than ``min_side`` [px] is a chord across a
    blurred corner: dropped, its neighbours meet. None when fewer than 3 sides remain."""
    chain = list(chain)
    while len(chain) >= 3:
        headings = np.array([_angle(s) for s in chain])
        diff = np.abs(headings - np.roll(headings, 1))
        diff = np.minimum(diff, 180.0 - diff)
        k = int(np.argmin(diff))
        if diff[k] < MERGE_TURN:
            chain[k - 1] = refine(_farthest(chain[k - 1], chain[k]), points)
            chain.pop(k)
            continue
        try:
            corners = _chain_corners_in_order(chain)
        except ValueError:
            return None
        edges = np.linalg.norm(corners - np.roll(corners, 1, axis=0), axis=1)
        k = int(np.argmin(edges))  # side k runs from corner k - 1 to corner k
        if edges[k] >= min_side:
            return _counter_clockwise(corners)
        chain.pop(k)
    return None


def _polish(
    corners: NDArray[np.float64], points: NDArray[np.float64], *, rounds: int = 2
) -> NDArray[np.float64]:
    """The corners again, each side refitted (total least squares) to the edge ``points``
    within ``POLISH_BAND`` of it and between its corners, leaving out ``POLISH_TRIM`` of each
    end: near a corner the blur rounds the outline and the other side's pixels come close.
    At a gentle corner an error across a side moves the corner along it by 1/sin(turn) as
    much, so the sides are fitted to what is straight of them only. Counter-clockwise in,
    counter-clockwise out; a side with fewer than 5 pixels keeps its line."""
    n = len(corners)
    for _ in range(rounds):
        lines: list[Segment] = []
        for k in range(n):
            a, b = corners[k - 1], corners[k]  # side k runs from corner k - 1 to corner k
            length = float(np.linalg.norm(b - a))
            u = (b - a) / max(length, 1e-9)
            rel = points - a
            along = rel @ u
            across = np.abs(rel @ np.array([-u[1], u[0]]))
            trim = min(POLISH_TRIM * length, 4.0)
            near = points[(across <= POLISH_BAND) & (along >= trim) & (along <= length - trim)]
            side = (float(a[0]), float(a[1]), float(b[0]), float(b[1]))
            fitted = len(near) >= 5 and length > 1e-6
            lines.append(refine(side, near, band=POLISH_BAND) if fitted else side)
        try:
            polished = _chain_corners_in_order(lines[1:] + lines[:1])
        except ValueError:
            return corners
        corners = polished
    return corners


RIM_WIDTH = 3
"""Width of the band along the part's contour whose edge pixels the polish fits [px]."""

POLISH_BAND = 1.5
"""Edge pixels within this distance of a side are its own when polishing [px]."""

POLISH_TRIM = 0.1
"""Share of a side left out at each end when polishing (at most 5 px)."""

MERGE_TURN = 6.0
"""Adjacent sides closer in direction than this are one side [°]."""

MIN_TURN = 7.0
"""A polygon turns by at least this much at each corner [°]; gentler turns are chords of a
curve. Well-posed outlines turn by 10° or more; the margin is for the corners' own error."""

CURVED_MIN_SIDE = 0.12
"""In a curved outline, straight sides are at least this fraction of the contour's length."""


def not_standing_out(light: bool, *, given: bool) -> str:
    """Why no part was found when none stands out from its ground, in the part's own terms: it
    was looked for as lighter (or darker) than its surroundings, as given or as the image's
    levels suggested, and what to try instead."""
    shade, other = ("lighter", "dark") if light else ("darker", "light")
    how = (
        "as asked (part=" + ("light" if light else "dark") + ")"
        if given
        else ("as the image's levels suggested")
    )
    return (
        f"no part stands out: no convex region off the image's border is {shade} than its "
        f"surroundings (the part was looked for as {shade}, {how}); try part={other}, or a "
        "roi around the part"
    )


def outline(grey: Grey, params: OutlineParams = OutlineParams()) -> Outline:
    """The outline of the part in a greyscale image: corners and sides, or contour and ellipses,
    with how well the shape fits its edges; ``OutlineNotFound`` when none fits.

    Steps: a light part's image inverted (``params.part``) → stretch (4.1) → the part's level
    (``part_level``) → shadow suppression (3.1 with 4.3) → Canny → the outer contour of the
    part → Hough segments on the edges along that contour (inner edges between a part's faces
    are not its outline) → fragments joined (3.2–3.3) → each side refitted to its edge pixels
    and joined again → sides chained along the contour (``_chain_along``) → corners as the
    intersections of adjacent sides (§V.A), each side fitted again to the outline's own edge
    pixels (``_on_outline``: not those between two of the part's faces), corners that are none
    dropped (``_prune``) and its sides searched for kinks again. The polygon stands
    when its sides explain the outline's edge pixels, its length is backed by edges and every
    corner turns; otherwise, when straight sides and fitted ellipse arcs explain the contour,
    the outline is ``curved``; otherwise nothing is claimed.
    """
    _check_grey(grey)
    if min(grey.shape) < 8:
        raise ValueError(f"image too small to outline: {grey.shape[1]}×{grey.shape[0]}")
    light = params.part == "light" or (params.part == "auto" and part_is_light(grey))
    if light:  # the steps below find a dark part on a light ground: turn it round
        grey = np.asarray(cv2.bitwise_not(grey), dtype=np.uint8)
    base = stretch(grey) if params.stretch else grey
    sigma = params.canny.sigma
    level = part_level(base, sigma)
    if level is None:
        raise OutlineNotFound(not_standing_out(light, given=params.part != "auto"))
    work, theta = base, None
    if params.shadow:
        work, theta, _ = suppress_shadow(base, alpha=params.alpha, theta=params.theta, part=level)
    edges, low, high = canny(work, params.canny)
    contour_px = _outer_contour(base, level, sigma)
    contour = contour_px.reshape(-1, 2).astype(np.float64)
    perimeter = cv2.arcLength(contour_px, True)
    band = np.zeros_like(edges)
    cv2.drawContours(band, [contour_px], -1, 255, thickness=7)
    # the edges of the part itself (the stretched image, before the shadow step remaps the
    # levels around the boundary), with a lower threshold, only around the part
    x, y, w, h = cv2.boundingRect(contour_px)
    m = 12
    x0, y0 = max(0, x - m), max(0, y - m)
    box = np.ascontiguousarray(base[y0 : y + h + m, x0 : x + w + m])
    part_edges = np.zeros_like(edges)
    part_edges[y0 : y0 + box.shape[0], x0 : x0 + box.shape[1]] = canny(box, FIT_CANNY)[0]
    fit_edges = np.asarray(cv2.bitwise_and(part_edges, band), dtype=np.uint8)
    # Hough on the conditioned image's edges along the contour ([Fayed 2013]'s), joined
    # by those of the part itself: a face close to the table's level leaves a side the
    # conditioned image's Canny, scaled to its strongest edge, does not see
    outer_edges = np.asarray(
        cv2.bitwise_and(cv2.bitwise_or(edges, part_edges), band), dtype=np.uint8
    )
    min_length = params.min_length or max(15.0, 0.02 * perimeter)
    raw = hough_segments(
        outer_edges,
        threshold=params.hough_threshold,
        min_length=max(4.0, min_length / 3),
        max_gap=params.max_gap,
    )
    joined = join_fragments(raw, max_angle=params.max_angle, max_lateral=params.max_lateral)
    # each side refitted to the part's edge pixels, then joined again: refitted fragments of
    # one side now line up; only then are the short ones dropped (a short side is often
    # several fragments)
    grad = Gradient.of(box, FIT_CANNY.sigma)
    offset = np.array([x0, y0], dtype=np.float64)
    edge_points = (
        subpixel_edges(grad, part_edges[y0 : y0 + box.shape[0], x0 : x0 + box.shape[1]]) + offset
    )
    # the polish takes only the edge pixels on the contour: an inner edge a few pixels in (a
    # thin face at the rim) would pull a side off the outline
    rim = np.zeros_like(edges)
    cv2.drawContours(rim, [contour_px], -1, 255, thickness=RIM_WIDTH)
    xi = np.clip(np.rint(edge_points[:, 0]).astype(int), 0, rim.shape[1] - 1)
    yi = np.clip(np.rint(edge_points[:, 1]).astype(int), 0, rim.shape[0] - 1)
    rim_points = edge_points[rim[yi, xi] > 0]
    rim_points = rim_points[_on_outline(grad, rim_points - offset, level)]
    refitted = [refine(s, edge_points) for s in joined]
    sides = join_fragments(refitted, max_angle=params.max_angle, max_lateral=params.max_lateral)
    sides = [refine(s, edge_points) for s in sides if _length(s) >= min_length]
    simplified = cv2.approxPolyDP(contour_px, 1.0, True).reshape(-1, 2).astype(np.float64)
    # the fit is judged on the same edges the sides were fitted to, along the contour
    outline_points = rim_points
    near_edge = np.asarray(
        cv2.distanceTransform(
            np.asarray(cv2.bitwise_not(fit_edges), np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE
        ),
        dtype=np.float32,
    )
    tol = params.polygon_tolerance
    common = dict(
        contour=simplified,
        edges=edges,
        conditioned=work,
        canny_thresholds=(low, high),
        shadow_theta=theta,
        part="light" if light else "dark",
    )
    chain = _chain_along(sides, contour, tol, max(6.0, 0.4 * min_length))
    chain = _split_kinks(chain, contour, rim_points, tol, min_length)
    corners = _polygon(chain, edge_points, 0.75 * min_length)
    polygon: Outline | None = None
    polygon_bic = curved_bic = math.inf
    verdict = "fewer than 3 straight sides"
    if corners is not None:
        corners = _polish(corners, rim_points)
        corners = _prune(corners, near_edge, rim_points)
        # two sides merged as one (fragments of a short side fitted along its long neighbour)
        # show as a kink in the side's stretch of contour: split, and the corners again
        sides = _sides(corners)
        split = _split_kinks(sides, contour, rim_points, tol, min_length)
        if len(split) > len(sides):
            try:
                met = _counter_clockwise(_chain_corners_in_order(split))
            except ValueError:
                met = corners
            corners = _prune(_polish(met, rim_points), near_edge, rim_points)
        polygon_sides = _sides(corners)
        fit = _fit(outline_points, polygon_sides, near_edge, tol)
        turn = float(_turns(corners).min())
        if _fits(fit, params) and turn >= MIN_TURN:
            polygon = Outline(
                shape="polygon",
                corners=corners,
                lines=sides,
                residual=fit.residual,
                support=fit.support,
                **common,  # type: ignore[arg-type]
            )
            polygon_bic = _bic(outline_points, polygon_sides, tol, 2 * len(corners))
        verdict = (
            f"a {len(corners)}-sided polygon explains {fit.explained:.0%} of the edge pixels "
            f"(residual {fit.residual:.2f} px), {fit.support:.0%} of its length is backed by "
            f"edges, its gentlest corner turns {turn:.1f}°"
        )
    # curved: the long straight sides stay, short chords along the arcs are not sides
    straight = [s for s in sides if _length(s) >= CURVED_MIN_SIDE * perimeter]
    arcs = ~_explained(contour, straight, tol)
    ellipses = _fit_arcs(contour, arcs, rim_points)
    model = straight + _arc_segments(ellipses, contour, tol)
    fit = _fit(outline_points, model, near_edge, tol)
    curved: Outline | None = None
    if ellipses and _fits(fit, params):
        curved = Outline(
            shape="curved",
            corners=np.empty((0, 2)),
            lines=straight,
            ellipses=ellipses,
            residual=fit.residual,
            support=fit.support,
            **common,  # type: ignore[arg-type]
        )
        curved_bic = _bic(outline_points, model, tol, 5 * len(ellipses) + 4 * len(straight))
    # both fit: the one the edges favour once its parameters are paid for (a disc is also
    # a polygon of twenty chords; a box's corners are also arcs of small ellipses)
    if polygon is not None and polygon_bic <= curved_bic:
        return polygon
    if curved is not None:
        return curved
    raise OutlineNotFound(
        f"no outline fits the part's edges: {verdict}; straight sides with "
        f"{len(ellipses)} ellipse arcs explain {fit.explained:.0%} of the edge pixels "
        f"(residual {fit.residual:.2f} px), {fit.support:.0%} of their length is backed by "
        "edges"
    )


def _fits(fit: _Fit, params: OutlineParams) -> bool:
    return (
        fit.explained >= params.polygon_fraction
        and fit.support >= params.min_support
        and fit.residual <= params.max_residual
    )


def _bic(points: NDArray[np.float64], model: list[Segment], tol: float, k: int) -> float:
    """Bayesian information criterion of a shape with ``k`` parameters over the edge pixels,
    each pixel's distance capped at ``tol`` (beyond it, a pixel is not the shape's)."""
    n = max(len(points), 1)
    d = np.minimum(_distances(points, model), tol)
    rss = max(float((d**2).sum()), 1e-9)
    return n * math.log(rss / n) + k * math.log(n)


def _arc_segments(
    ellipses: list[Ellipse], contour: NDArray[np.float64], tol: float
) -> list[Segment]:
    """The parts of the ellipses that run along the contour, as short segments: an ellipse
    fitted to an arc continues where the part has no outline."""
    out: list[Segment] = []
    ring = np.hstack([contour, np.roll(contour, -1, axis=0)])
    contour_segments: list[Segment] = [(a, b, c, d) for a, b, c, d in ring.tolist()]
    for e in ellipses:
        # drawn at 16× and scaled back: ellipse2Poly rounds its points to integers
        big = cv2.ellipse2Poly(
            (round(e.center[0] * 16), round(e.center[1] * 16)),
            (round(e.axes[0] * 8), round(e.axes[1] * 8)),
            round(e.angle),
            0,
            360,
            2,
        )
        poly = np.asarray(big, dtype=np.float64).reshape(-1, 2) / 16.0
        if len(poly) < 2:
            continue
        closed = np.vstack([poly, poly[:1]])
        on = _distances(closed, contour_segments) <= tol
        for k in range(len(poly)):
            if on[k] and on[k + 1]:
                a, b = closed[k], closed[k + 1]
                out.append((float(a[0]), float(a[1]), float(b[0]), float(b[1])))
    return out


def _fit_arcs(
    contour: NDArray[np.float64], curved: NDArray[np.bool_], points: NDArray[np.float64]
) -> list[Ellipse]:
    """Ellipses fitted to each run of contour points the straight sides do not explain (runs of
    at least a tenth of the contour: a blurred corner is no arc): to the
    edge ``points`` (sub-pixel) nearest that run, the run itself when it has too few. The
    contour runs along the inside of the region's boundary, half a pixel in."""
    n = len(contour)
    if n == 0 or not curved.any():
        return []
    if curved.all():
        runs = [np.arange(n)]
    else:
        start = int(np.argmin(curved))  # begin the scan at an explained point
        order = np.roll(np.arange(n), -start)
        runs, current = [], []
        for k in order:
            if curved[k]:
                current.append(k)
            elif current:
                runs.append(np.array(current))
                current = []
        if current:
            runs.append(np.array(current))
    nearest = (
        cKDTree(contour).query(points, distance_upper_bound=3.0)[1]
        if len(points)
        else np.empty(0, dtype=int)
    )
    ellipses = []
    for run in runs:
        if len(run) < max(10, n // 10):
            continue
        own = points[np.isin(nearest, run)]
        fitted = own if len(own) >= len(run) // 2 else contour[run]
        (cx, cy), (a, b), angle = cv2.fitEllipse(fitted.astype(np.float32))
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
