"""The laser grid: surface area and volume of an irregular part (chapter 4, Applications).

The laser's second mode projects a grid of squares; on the part each square lands as an
irregular quadrilateral whose corners the cameras locate in 3-D. [Fayed 2013] stops at the
idea ("divides the luggage into small sections and computes the volume of each small section");
this module makes it a measurement:

1. **Nodes in each view** (:func:`detect`). The lines are the red excess R − max(G, B) above
   that of the surface they fall on (a white top-hat), so a reddish part does not pass for
   line when the exposure saturates the lines' red. An opening with a horizontal (vertical)
   segment keeps the roughly horizontal (vertical) lines; where both survive is a node. Each
   node is refined to sub-pixel accuracy by fitting the two lines through it (column- and
   row-wise centroids) and intersecting them. Consecutive nodes along a line are neighbours
   when the line runs unbroken between them.
2. **Correspondence** (:func:`match`). The grid is periodic, so a node's partner in another view
   is ambiguous along the epipolar line. Every candidate pair within ``tol_px`` of the epipolar
   line is triangulated and projected into the other views; the candidate that the most views
   confirm (then the smallest error) wins, a view that shows grid there but no node counting
   against it. With three or more views a wrong pair is confirmed only by coincidence — except
   on a grid square to the rig's baselines, where whole-cell shifts fit every view: ties are
   broken by continuity, grown from the laser dot, and reported.
3. **Labels** (:func:`label`). Image neighbours become 3-D neighbours when the two points are
   about one cell apart in space, so a link across a depth step (where one view can show a line
   running on unbroken) is dropped. A breadth-first walk gives every node its (row, column); the
   laser dot, a grid node, is (0, 0). Each connected surface gets its own labels.
4. **Measurement** (:func:`measure`). The base plane is given, or fitted (RANSAC) to the nodes
   with no node behind it. Nodes higher than ``tol`` above it, corners of a cell wholly above
   it, are on the part; where a laser line runs on past the part's last node (the node at the
   very edge is often lost), a node is put where the line says. Each grid cell
   contributes the part of it that is on the part (marching squares): where the surface is
   continuous the boundary is where the height crosses zero; at a step it is where the laser line
   on the part ends, traced in the images (:func:`trace`). Sums over cells give the measured
   surface area (3-D area of the part's surface the grid covers), the footprint, the volume above
   the base plane (each triangle's footprint times its mean height), and the side area (the
   walls from the boundary down to the base plane).
"""

from __future__ import annotations

import heapq
import math
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field

import cv2
import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from app.cells.core.triangulation import (
    CrossRig,
    RigArrays,
    View,
    behind,
    lens_centres,
    project_views,
    triangulate_cross,
    triangulate_views,
    undistort,
)

Triangulator = Callable[[NDArray[np.float64]], tuple[NDArray[np.float64], NDArray[np.float64]]]
"""(N, V, 2) pixels (NaN: not seen) → ((N, 3) points, (N,) reprojection RMS [px])."""

OPEN_LENGTH = 9
"""Length of the segment that separates horizontal from vertical lines [px]: longer than a
line is wide, shorter than a line tilted by 15° runs along one pixel row."""

SPLIT_PX = 0.3
"""A node whose two arms of one line are further apart than this [px] is not a clean crossing
(one arm belongs to another surface); it is left out of that view."""


@dataclass(frozen=True, slots=True)
class Geometry:
    """A rig as the grid needs it: per view x_cam = R X + t and a focal length [px] for
    converting normalised errors to pixels; ``normalise`` maps (N, 2) pixels of view k to
    undistorted normalised coordinates."""

    R: NDArray[np.float64]
    t: NDArray[np.float64]
    f: NDArray[np.float64]
    normalise: Callable[[int, NDArray[np.float64]], NDArray[np.float64]]
    triangulate: Triangulator
    project: Callable[[NDArray[np.float64]], NDArray[np.float64]]
    """(N, 3) points → (N, V, 2) pixels."""

    @property
    def centres(self) -> NDArray[np.float64]:
        return lens_centres(self.R, self.t)


@dataclass(frozen=True, slots=True)
class Nodes:
    """The grid seen by one camera."""

    uv: NDArray[np.float64]
    """(K, 2) sub-pixel node positions [px]."""
    links: NDArray[np.int64]
    """(L, 3): node i, node j, family (0: j is i's right neighbour on a row line, 1: j is below
    i on a column line)."""
    excess: NDArray[np.float32]
    """The smoothed red excess, for tracing line ends."""
    level: float
    """Typical line brightness in ``excess``."""
    cell: float = 0.0
    """Median distance between neighbouring nodes [px]."""
    scale: int = 1
    """The reduction the nodes were found at (``detect``): their error in the image's pixels
    grows with it, and so do the pixel tolerances of matching and labelling."""


_BACKGROUND_KERNEL = cv2.getStructuringElement(cv2.MORPH_RECT, (OPEN_LENGTH, OPEN_LENGTH))


def _excess(rgb: NDArray[np.uint8]) -> NDArray[np.float32]:
    """The lines' red excess above the surface they fall on: R − max(G, B), smoothed, less its
    morphological opening by a square wider than a line (a white top-hat). A reddish surface
    (cardboard, wood) has an excess of its own, and a bright exposure saturates R on the
    lines, so on such a surface the lines stand only a little above it: one threshold for the
    whole image would take the surface for lines."""
    r = rgb[..., 0].astype(np.float32)
    e = r - np.maximum(rgb[..., 1], rgb[..., 2]).astype(np.float32)
    smooth = cv2.GaussianBlur(np.maximum(e, 0), (0, 0), 0.8)
    return np.asarray(
        cv2.morphologyEx(smooth, cv2.MORPH_TOPHAT, _BACKGROUND_KERNEL), dtype=np.float32
    )


def _patches(image: NDArray[np.float32], centres: NDArray[np.int64], r: int) -> NDArray[np.float32]:
    """(K, 2r+1, 2r+1) windows of ``image`` around integer (x, y) centres, zero outside."""
    padded = np.pad(image, r)
    off = np.arange(-r, r + 1)
    ys = centres[:, 1, None, None] + r + off[None, :, None]
    xs = centres[:, 0, None, None] + r + off[None, None, :]
    return np.asarray(padded[ys, xs], dtype=np.float32)


def _fit_lines(w: NDArray[np.float32], r: int) -> tuple[NDArray[np.float64], ...]:
    """Per window, fit y = a + b·dx to the weighted row centroid of each column (|dx| > 2):
    returns (a, b, ok). Twice more, the centroids use only rows within 2 px of the line, and
    columns more than 0.75 px off it are dropped: a neighbouring line on another surface (a
    step's other side) must not pull the fit."""
    off = np.arange(-r, r + 1, dtype=np.float64)
    k = len(w)
    a = np.zeros(k)
    b = np.zeros(k)
    band = np.ones((k, 2 * r + 1, 2 * r + 1), bool)
    keep = np.ones((k, 2 * r + 1), bool)
    ok = np.zeros(k, bool)
    stray = np.zeros(k, bool)
    for sweep in range(3):
        ww = np.where(band, w, 0.0)
        cols = ww.sum(axis=1)  # (K, 2r+1): weight of each column
        with np.errstate(invalid="ignore", divide="ignore"):
            ybar = (ww * off[None, :, None]).sum(axis=1) / cols
        use = (cols > 0) & (np.abs(off)[None, :] > 2) & keep
        wt = np.where(use, cols, 0.0)
        ybar = np.where(use, ybar, 0.0)
        s0 = wt.sum(axis=1)
        s1 = (wt * off).sum(axis=1)
        s2 = (wt * off**2).sum(axis=1)
        sy = (wt * ybar).sum(axis=1)
        sxy = (wt * off * ybar).sum(axis=1)
        det = s0 * s2 - s1**2
        ok = (use.sum(axis=1) >= 2) & (det > 1e-9 * np.maximum(s0, 1) ** 2)
        with np.errstate(invalid="ignore", divide="ignore"):
            b = np.where(ok, (s0 * sxy - s1 * sy) / det, 0.0)
            # one arm only (the other cut by a shadow or an edge): the slope would be
            # extrapolated from a few columns; take the grid's typical slope instead
            one_sided = ~(use & (off < 0)).any(axis=1) | ~(use & (off > 0)).any(axis=1)
            both_sides = ok & ~one_sided
            typical = float(np.median(b[both_sides])) if both_sides.any() else 0.0
            b = np.where(one_sided, typical, b)
            ok |= one_sided & (s0 > 0)
            a = np.where(ok, (sy - b * s1) / np.where(s0 > 0, s0, 1), 0.0)
        line = a[:, None] + b[:, None] * off[None, :]  # (K, 2r+1): the line's y at each column
        band = np.abs(off[None, :, None] - line[:, None, :]) <= 2.0
        if sweep == 1:
            keep = np.abs(ybar - line) <= 0.75
            stray = (use & ~keep).any(axis=1)
    # the two arms must be one line: a crossing next to a step can have one arm on the other
    # surface, a fraction of a pixel aside, which would bias the node along the parallax
    resid = np.where(use, ybar - b[:, None] * off[None, :], 0.0)
    left, right = use & (off < 0), use & (off > 0)
    with np.errstate(invalid="ignore", divide="ignore"):
        a_left = (resid * wt * left).sum(axis=1) / (wt * left).sum(axis=1)
        a_right = (resid * wt * right).sum(axis=1) / (wt * right).sum(axis=1)
    split = left.any(axis=1) & right.any(axis=1) & (np.abs(a_left - a_right) > SPLIT_PX)
    split |= stray
    return a, b, (ok & ~split).astype(np.float64)


def _sample(image: NDArray[np.float32], pts: NDArray[np.float64]) -> NDArray[np.float64]:
    """Bilinear samples of ``image`` at (..., 2) points (x, y); 0 outside."""
    if pts.size == 0:  # OpenCV refuses an empty map
        return np.zeros(pts.shape[:-1])
    flat = pts.reshape(-1, 2).astype(np.float32)
    out = cv2.remap(
        image,
        flat[:, 0].reshape(-1, 1),
        flat[:, 1].reshape(-1, 1),
        cv2.INTER_LINEAR,
        borderMode=cv2.BORDER_CONSTANT,
        borderValue=0.0,
    )
    return np.asarray(out, dtype=np.float64).reshape(pts.shape[:-1])


MAX_CELL_PX = 16.0
"""Cells larger than this [px] are found in a reduced copy of the image: the kernels above
(``OPEN_LENGTH``, the top-hat's square, the node windows) are sized for lines a few pixels wide
and cells of 9–16 px, and a long lens or a large sensor makes both wider."""

REDUCED_CELL_PX = 14.0
"""The cell size [px] the reduced copy aims at."""

MIN_REDUCED_SIDE = 100
"""A copy is not reduced below this many pixels on its short side."""


def _reduced(rgb: NDArray[np.uint8], k: int) -> NDArray[np.uint8]:
    """The image reduced by the whole factor ``k`` (pixel areas averaged)."""
    if k == 1:
        return rgb
    h, w = rgb.shape[:2]
    return np.asarray(cv2.resize(rgb, (w // k, h // k), interpolation=cv2.INTER_AREA))


def _agree(fine: Nodes, k: int, coarse: Nodes) -> bool:
    """The nodes found at reduction ``k`` and at ``2k`` say the same cell (within 15 %) and
    as many nodes (the finer at least 80 % of the coarser): the finer scale is no worse."""
    if fine.cell <= 0 or coarse.cell <= 0:
        return fine.cell > 0 and len(coarse.uv) == 0
    same_cell = abs(fine.cell - 2 * coarse.cell) <= 0.15 * 2 * coarse.cell
    return same_cell and len(fine.uv) >= 0.8 * len(coarse.uv)


def detect(rgb: NDArray[np.uint8], *, min_excess: float = 40.0) -> Nodes:
    """The grid's nodes in one RGB image (H, W, 3), uint8, and the line links between them.

    The grid's cell size is not known in advance: lines too wide for the kernels are not found
    at full size, and what is found there (a few stray crossings) says the wrong cell. So the
    image is also searched reduced by 2, 4, …, until two successive scales agree (``_agree``);
    the cell they measure sets the reduction the nodes come from: none for cells up to
    ``MAX_CELL_PX``, else the whole factor that brings them to about ``REDUCED_CELL_PX``. The
    nodes are returned in the image's own pixels, and ``excess`` is the reduced copy's,
    enlarged again, for tracing line ends."""
    if rgb.dtype != np.uint8 or rgb.ndim != 3 or rgb.shape[2] != 3:
        raise ValueError(f"expected an RGB image (H, W, 3), uint8; got {rgb.shape}")
    found = {1: _detect(rgb, min_excess)}
    k = 1
    while min(rgb.shape[:2]) // (2 * k) >= MIN_REDUCED_SIDE:
        found[2 * k] = _detect(_reduced(rgb, 2 * k), min_excess)
        if _agree(found[k], k, found[2 * k]):
            break
        k *= 2
    cell = found[k].cell * k  # [px of the image]
    if cell <= MAX_CELL_PX:
        return found[1]
    k = math.ceil(cell / REDUCED_CELL_PX)
    reduced = found.get(k) or _detect(_reduced(rgb, k), min_excess)
    if len(reduced.uv) == 0:
        return found[1]
    h, w = rgb.shape[:2]
    excess = cv2.resize(reduced.excess, (w, h), interpolation=cv2.INTER_LINEAR)
    # pixel centres: reduced pixel i covers the image's pixels k·i … k·i + k − 1
    return Nodes(
        (reduced.uv + 0.5) * k - 0.5,
        reduced.links,
        np.asarray(excess, dtype=np.float32),
        reduced.level,
        reduced.cell * k,
        k,
    )


def _detect(rgb: NDArray[np.uint8], min_excess: float) -> Nodes:
    e = _excess(rgb)
    empty = Nodes(np.zeros((0, 2)), np.zeros((0, 3), np.int64), e, 0.0)
    bright = e[e > min_excess / 2]
    if bright.size < 50:
        return empty
    level = float(np.percentile(bright, 90))
    if level < min_excess:
        return empty
    mask = (e > 0.35 * level).astype(np.uint8)
    horizontal = cv2.morphologyEx(mask, cv2.MORPH_OPEN, np.ones((1, OPEN_LENGTH), np.uint8))
    vertical = cv2.morphologyEx(mask, cv2.MORPH_OPEN, np.ones((OPEN_LENGTH, 1), np.uint8))
    _, _, stats, centroids = cv2.connectedComponentsWithStats(cv2.bitwise_and(horizontal, vertical))
    keep = stats[1:, cv2.CC_STAT_AREA] >= 2
    seeds = centroids[1:][keep]
    if len(seeds) < 4:
        return empty
    nn, _ = cKDTree(seeds).query(seeds, k=2)
    cell = float(np.median(nn[:, 1]))
    r = int(np.clip(round(0.4 * cell), 3, 8))
    centre = np.rint(seeds).astype(np.int64)
    eh = e * horizontal.astype(np.float32)
    ev = e * vertical.astype(np.float32)
    a, b, ok_h = _fit_lines(_patches(eh, centre, r), r)  # row line: dy = a + b dx
    c, d, ok_v = _fit_lines(np.swapaxes(_patches(ev, centre, r), 1, 2), r)  # column: dx = c + d dy
    both = (ok_h > 0) & (ok_v > 0) & (np.abs(1 - b * d) > 0.1)
    with np.errstate(invalid="ignore", divide="ignore"):
        dy = np.where(both, (a + b * c) / (1 - b * d), 0.0)
        dx = np.where(both, c + d * dy, 0.0)
    # a refinement that leaves the window is a bad fit; a split or one-line node is no node
    good = both & (np.abs(dx) <= r) & (np.abs(dy) <= r)
    uv = (centre + np.column_stack([dx, dy]))[good]
    b, d, ok_h, ok_v = b[good], d[good], ok_h[good], ok_v[good]
    if len(uv) < 4:
        return empty
    slopes = np.column_stack([np.where(ok_h > 0, b, 0.0), np.where(ok_v > 0, d, 0.0)])
    links = _links(uv, slopes, e, level, cell)
    return Nodes(uv, links, e, level, cell)


def _links(
    uv: NDArray[np.float64],
    slopes: NDArray[np.float64],
    e: NDArray[np.float32],
    level: float,
    cell: float,
) -> NDArray[np.int64]:
    """Each node's next node along its row line (to the right) and its column line (down): the
    nearest node about a cell ahead, close to the line's fitted direction, joined by unbroken
    line. ``slopes``: (K, 2) dy/dx of the row line and dx/dy of the column line."""
    out = []
    k = min(9, len(uv))
    dist, idx = cKDTree(uv).query(uv, k=k)
    delta = uv[idx] - uv[:, None, :]  # (K, k, 2)
    for family in (0, 1):
        if family == 0:
            direction = np.column_stack([np.ones(len(uv)), slopes[:, 0]])
        else:
            direction = np.column_stack([slopes[:, 1], np.ones(len(uv))])
        direction /= np.linalg.norm(direction, axis=1, keepdims=True)
        along = np.einsum("nkj,nj->nk", delta, direction)
        across = np.abs(
            delta[..., 0] * direction[:, None, 1] - delta[..., 1] * direction[:, None, 0]
        )
        ok = (along > 0.6 * cell) & (along < 1.6 * cell) & (across < 0.25 * along)
        best = np.argmin(np.where(ok, along, np.inf), axis=1)
        has = ok[np.arange(len(uv)), best]
        i = np.flatnonzero(has)
        j = idx[i, best[has]]
        s = np.linspace(0.15, 0.85, 8)
        pts = uv[i, None, :] + s[None, :, None] * (uv[j] - uv[i])[:, None, :]
        unbroken = _sample(e, pts).min(axis=1) > 0.3 * level
        out.append(np.column_stack([i[unbroken], j[unbroken], np.full(unbroken.sum(), family)]))
    return np.concatenate(out).astype(np.int64)


def _skew(v: NDArray[np.float64]) -> NDArray[np.float64]:
    return np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])


def _linear_pairs(
    geo: Geometry, i: int, j: int, xi: NDArray[np.float64], xj: NDArray[np.float64]
) -> NDArray[np.float64]:
    """Two-view linear triangulation of normalised points (N, 2) in views i and j."""
    rows = []
    for k, x in ((i, xi), (j, xj)):
        r, t = geo.R[k], geo.t[k]
        for axis in (0, 1):
            a = x[:, axis, None] * r[2][None] - r[axis][None]
            b = t[axis] - x[:, axis] * t[2]
            rows.append((a, b))
    a = np.stack([r[0] for r in rows], axis=1)  # (N, 4, 3)
    b = np.stack([r[1] for r in rows], axis=1)  # (N, 4)
    ata = np.einsum("nki,nkj->nij", a, a) + np.eye(3) * 1e-12
    atb = np.einsum("nki,nk->ni", a, b)
    return np.asarray(np.linalg.solve(ata, atb[..., None])[..., 0], dtype=np.float64)


def _project(geo: Geometry, points: NDArray[np.float64]) -> tuple[NDArray[np.float64], ...]:
    """(N, 3) → normalised (N, V, 2) × f (pixel-scaled) and depth (N, V)."""
    cam = np.einsum("vij,nj->nvi", geo.R, points) + geo.t[None]
    z = cam[..., 2]
    with np.errstate(invalid="ignore", divide="ignore"):
        q = cam[..., :2] / z[..., None] * geo.f[None, :, None]
    return q, z


@dataclass(frozen=True, slots=True)
class Matches:
    index: NDArray[np.int64]
    """(M, V) node index in each view, −1 where the view lacks the node."""
    tied: float
    """Fraction of nodes whose candidates tied: high when the grid is aligned with the rig's
    baselines, where whole-cell shifts fit every view."""

    @property
    def warnings(self) -> list[str]:
        if self.tied < TIED_WARNING:
            return []
        return [
            f"{self.tied:.0%} of the grid's nodes matched more than one way: the grid looks "
            "aligned with the rig's baselines; rotate the laser 5–15° about its axis, or depths "
            "seen by fewer than all cameras may be whole cells off"
        ]


TIED_WARNING = 0.2

REACH = 3.0
"""How far a laser line is traced beyond a node on the part's edge [cells]."""

LINK_RANGE = (0.6, 1.35)
"""Image neighbours are 3-D neighbours when their distance is within this range of a typical
cell at their distance from the rig."""


def match(
    nodes: list[Nodes],
    geo: Geometry,
    *,
    origin: NDArray[np.float64] | None = None,
    tol_px: float = 1.5,
) -> Matches:
    """Corresponding nodes across views: (M, V) node indices, −1 where a view lacks the node.

    ``tol_px`` is for nodes found at full size; it grows with the coarsest view's ``scale``.
    Each view in turn is the reference for its nodes not matched yet; a match needs the
    confirmation of ``min(3, V)`` views, less one for each view that contradicts it (it falls
    among that view's nodes but on none of them). A grid aligned with the rig's baselines is
    periodic along them: a shift of whole cells can be confirmed by every view. Such ties are
    broken by continuity (:func:`_choose`), grown from the laser dot (``origin``, a 3-D point)
    and from the nodes that had one candidate only."""
    tol_px *= max((n.scale for n in nodes), default=1)
    v = len(nodes)
    q = [
        geo.normalise(k, n.uv) * geo.f[k] if len(n.uv) else np.zeros((0, 2))
        for k, n in enumerate(nodes)
    ]
    trees = [cKDTree(x) if len(x) else None for x in q]
    spacing = [
        float(np.median(np.linalg.norm(x[n.links[:, 1]] - x[n.links[:, 0]], axis=1)))
        if len(n.links)
        else 0.0
        for x, n in zip(q, nodes, strict=True)
    ]
    used = [np.zeros(len(n.uv), bool) for n in nodes]
    need = min(3, v)
    found: list[NDArray[np.int64]] = []
    anchors: list[dict[int, NDArray[np.float64]]] = [{} for _ in range(v)]
    ties = looked = 0
    for ref in range(v):
        free = np.flatnonzero(~used[ref])
        if len(free) == 0:
            continue
        cand_a, cand_k, cand_b = [], [], []
        xr = q[ref][free] / geo.f[ref]
        hr = np.column_stack([xr, np.ones(len(xr))])
        for k in range(v):
            if k == ref or len(q[k]) == 0:
                continue
            r_rel = geo.R[k] @ geo.R[ref].T
            t_rel = geo.t[k] - r_rel @ geo.t[ref]
            lines = hr @ (_skew(t_rel) @ r_rel).T  # epipolar lines in view k, (A, 3)
            norm = np.hypot(lines[:, 0], lines[:, 1])
            hk = np.column_stack([q[k] / geo.f[k], np.ones(len(q[k]))])
            for start in range(0, len(free), 512):
                sl = slice(start, start + 512)
                dist = np.abs(lines[sl] @ hk.T) / norm[sl, None] * geo.f[k]
                a_idx, b_idx = np.nonzero(dist < tol_px)
                cand_a.append(a_idx + start)
                cand_b.append(b_idx)
                cand_k.append(np.full(len(a_idx), k))
        if not cand_a:
            continue
        ca, ck, cb = (np.concatenate(x) for x in (cand_a, cand_k, cand_b))
        if len(ca) == 0:
            continue
        points = np.empty((len(ca), 3))
        for k in np.unique(ck):
            sel = ck == k
            points[sel] = _linear_pairs(geo, ref, int(k), xr[ca[sel]], q[k][cb[sel]] / geo.f[k])
        proj, depth = _project(geo, points)
        support = np.zeros((len(ca), v), bool)
        nearest = np.full((len(ca), v), -1)
        missed = np.zeros((len(ca), v), bool)
        err = np.zeros(len(ca))
        for k in range(v):
            if trees[k] is None:
                continue
            finite = np.isfinite(proj[:, k]).all(axis=1) & (depth[:, k] > 0)
            dist = np.full(len(ca), np.inf)
            idx = np.full(len(ca), -1)
            if finite.any():
                dk, ik = trees[k].query(proj[finite, k])  # type: ignore[union-attr]
                dist[finite], idx[finite] = dk, ik
            hit = dist < tol_px
            support[:, k] = hit
            nearest[:, k] = np.where(hit, idx, -1)
            err += np.where(hit, dist**2, 0.0)
            # inside the grid this view sees, yet no node there: the view contradicts the
            # candidate (a view where it falls outside the grid, or far from any node, is
            # merely blind to it)
            missed[:, k] = ~hit & (dist < 1.5 * spacing[k])
        front = (depth > 0).all(axis=1) | (depth[np.arange(len(ca)), ck] > 0) & (depth[:, ref] > 0)
        score = np.where(front, support.sum(axis=1) - missed.sum(axis=1), 0)
        order, tied = _choose(
            nodes[ref], free, ca, points, score, err, nearest, need, anchors[ref], origin
        )
        ties += tied
        looked += len(free)
        taken = [u.copy() for u in used]
        for n in order:
            a = free[ca[n]]
            row = nearest[n].copy()
            row[ref] = a
            if any(row[k] >= 0 and taken[k][row[k]] for k in range(v)):
                continue
            for k in range(v):
                if row[k] >= 0:
                    taken[k][row[k]] = True
                    anchors[k][int(row[k])] = points[n]
            found.append(row)
        used = taken
    return Matches(np.array(found, dtype=np.int64).reshape(-1, v), ties / max(looked, 1))


def _choose(
    ref: Nodes,
    free: NDArray[np.int64],
    ca: NDArray[np.int64],
    points: NDArray[np.float64],
    score: NDArray[np.int64],
    err: NDArray[np.float64],
    nearest: NDArray[np.int64],
    need: int,
    known: dict[int, NDArray[np.float64]],
    origin: NDArray[np.float64] | None,
) -> tuple[list[int], int]:
    """The order in which to accept candidates, and how many nodes had tied options.

    A node's options are its confirmed candidates whose mean squared error per view is within a
        factor of 4 (+0.25 px²) of its best: not only those with the most views, since at the edge
        of a view's field the true node can be seen by fewer views than a shifted one. Starting from
        the laser dot (or, without it, from nodes with one option) and the nodes matched already,
        the choice grows along the reference view's grid lines, nearest first: each node takes the
        option nearest its chosen neighbour. On a periodic grid a whole-cell shift can fit every
        view equally well; the shifted option is far from the neighbours, the true one is not. What
        growth does not reach is taken best first (most views, then smallest error); a node's next
        candidate stands in when its choice loses a conflict over another view's node."""
    confirmed = score >= need
    mean = err / np.maximum(score, 1)  # squared error per confirming view [px²]
    least = np.full(len(free), np.inf)
    np.minimum.at(least, ca[confirmed], mean[confirmed])
    viable = np.flatnonzero(confirmed & (mean <= 4 * least[ca] + 0.25))
    options: dict[int, list[int]] = {}
    for n in viable:
        options.setdefault(int(ca[n]), []).append(int(n))
    local = {int(a): i for i, a in enumerate(free)}
    position = dict(known)  # reference-view node → its 3-D point
    chosen: dict[int, int] = {}
    order: list[int] = []

    def settle(i: int, n: int) -> None:
        chosen[i] = n
        order.append(n)
        position[int(free[i])] = points[n]

    if origin is not None and len(viable):
        near = viable[np.argmin(np.linalg.norm(points[viable] - origin, axis=1))]
        settle(int(ca[near]), int(near))
    elif not position:
        for i, cands in options.items():
            if len(cands) == 1:
                settle(i, cands[0])
    neighbours: dict[int, list[int]] = {}
    for i, j, _ in ref.links:
        neighbours.setdefault(int(i), []).append(int(j))
        neighbours.setdefault(int(j), []).append(int(i))
    heap: list[tuple[float, int, int]] = []

    def offer(a: int) -> None:
        for b in neighbours.get(a, []):
            i = local.get(b)
            if i is None or i in chosen or i not in options:
                continue
            d = [float(np.linalg.norm(points[n] - position[a])) for n in options[i]]
            k = int(np.argmin(d))
            heapq.heappush(heap, (d[k], i, options[i][k]))

    for a in list(position):
        offer(a)
    while heap:
        _, i_next, n_next = heapq.heappop(heap)
        if i_next in chosen:
            continue
        settle(i_next, n_next)
        offer(int(free[i_next]))
    dropped = {m for i, n in chosen.items() for m in options[i] if m != n}
    ranked = np.flatnonzero(score >= need)
    ranked = ranked[np.lexsort((err[ranked], -score[ranked]))]
    # ties proper: two candidates with the most views fitting equally well (0.05 px² apart)
    best = np.zeros(len(free), np.int64)
    np.maximum.at(best, ca, score)
    close = np.flatnonzero(confirmed & (score == best[ca]) & (mean <= least[ca] + 0.05))
    # (one match found through several partner views is one candidate, not a tie)
    distinct = {(int(ca[n]), tuple(nearest[n].tolist())) for n in close}
    tied = int((np.bincount([i for i, _ in distinct], minlength=len(free)) > 1).sum())
    return order + [int(n) for n in ranked if int(n) not in dropped], tied


@dataclass(slots=True)
class Labelled:
    """Matched nodes with 3-D points and grid labels."""

    points: NDArray[np.float64]
    """(M, 3)."""
    rms: NDArray[np.float64]
    """(M,) reprojection RMS [px]."""
    index: NDArray[np.int64]
    """(M, V) node index in each view, −1 if not seen."""
    labels: NDArray[np.int64]
    """(M, 2) (row, column) within the node's surface."""
    surface: NDArray[np.int64]
    """(M,) connected surface of each node; −1: isolated."""
    cell: float
    """Median distance between 3-D neighbours [world units]."""
    conflicts: int = 0
    origin: int | None = None
    """The node labelled (0, 0) by the dot, when one was given."""
    warnings: list[str] = field(default_factory=list)


def label(
    nodes: list[Nodes],
    matches: Matches,
    geo: Geometry,
    *,
    origin: NDArray[np.float64] | None = None,
    max_rms_px: float = 2.0,
) -> Labelled:
    """Triangulate the matched nodes and label them (row, column) by walking 3-D neighbours.

    ``origin``: the laser dot's 3-D point; the surface it lands on is labelled from it.
    ``max_rms_px`` is for nodes found at full size; it grows with the coarsest view's
    ``scale``."""
    coarsest = max((n.scale for n in nodes), default=1)
    max_rms_px *= coarsest
    index = matches.index
    v = len(nodes)
    obs = np.full((len(index), v, 2), np.nan)
    for k in range(v):
        seen = index[:, k] >= 0
        obs[seen, k] = nodes[k].uv[index[seen, k]]
    points, rms = geo.triangulate(obs) if len(obs) else (np.zeros((0, 3)), np.zeros(0))
    # a node cut by an occluding edge in one view is displaced there: with 3+ views, leave out
    # the view whose removal halves the error (typical errors are ~0.1 px)
    many = (np.isfinite(obs).all(axis=-1).sum(axis=1) >= 3) & (rms > 0.25 * coarsest)
    if many.any():
        best_rms, best_drop = rms[many].copy(), np.full(many.sum(), -1)
        for k in range(v):
            trial = obs[many].copy()
            trial[:, k] = np.nan
            _, r_k = geo.triangulate(trial)
            better = np.isfinite(r_k) & (r_k < 0.5 * best_rms)
            best_rms[better], best_drop[better] = r_k[better], k
        rows = np.flatnonzero(many)[best_drop >= 0]
        index = index.copy()
        index[rows, best_drop[best_drop >= 0]] = -1
        obs[rows, best_drop[best_drop >= 0]] = np.nan
        if len(rows):
            points[rows], rms[rows] = geo.triangulate(obs[rows])
    # a node needs as many confirming views as matching asked for (a pair alone can be a
    # coincidence of the periodic grid)
    views = np.isfinite(obs).all(axis=-1).sum(axis=1)
    good = np.isfinite(points).all(axis=1) & (rms <= max_rms_px) & (views >= min(3, v))
    points, rms, index = points[good], rms[good], index[good]
    m = len(points)
    where = [np.full(len(n.uv), -1) for n in nodes]
    for k in range(v):
        seen = index[:, k] >= 0
        where[k][index[seen, k]] = np.flatnonzero(seen)
    votes: dict[tuple[int, int, int], int] = {}
    for k, n in enumerate(nodes):
        if len(n.links) == 0:
            continue
        i, j = where[k][n.links[:, 0]], where[k][n.links[:, 1]]
        ok = (i >= 0) & (j >= 0)
        for a, b, fam in zip(i[ok], j[ok], n.links[ok, 2], strict=True):
            votes[(int(a), int(b), int(fam))] = votes.get((int(a), int(b), int(fam)), 0) + 1
    links = np.array(list(votes), dtype=np.int64).reshape(-1, 3)
    lengths = np.linalg.norm(points[links[:, 1]] - points[links[:, 0]], axis=1)
    cell = float(np.median(lengths)) if len(lengths) else float("nan")
    # a link across a depth step is far longer than a cell in 3-D, however regular it looks.
    # Cells grow with the distance from the rig: compare each link with the median cell
    # scaled to its distance
    reach = np.linalg.norm(
        0.5 * (points[links[:, 0]] + points[links[:, 1]]) - geo.centres.mean(axis=0), axis=1
    )
    if len(lengths):
        scale = float(np.median(lengths / reach))
        ratio = lengths / (scale * reach)
        links = links[(ratio > LINK_RANGE[0]) & (ratio < LINK_RANGE[1])]
    step = np.array([[0, 1], [1, 0]])
    adjacency: list[list[tuple[int, int, int]]] = [[] for _ in range(m)]
    for a, b, fam in links:
        dr, dc = step[fam]
        adjacency[a].append((b, dr, dc))
        adjacency[b].append((a, -dr, -dc))
    labels = np.zeros((m, 2), np.int64)
    surface = np.full(m, -1)
    conflicts = 0
    warnings: list[str] = list(matches.warnings)
    start_node: int | None = None
    if origin is not None and m:
        d = np.linalg.norm(points - origin, axis=1)
        start_node = int(np.argmin(d))
        if d[start_node] > 0.3 * cell:
            warnings.append(
                f"the laser dot is {d[start_node]:.4g} from the nearest grid node "
                f"({d[start_node] / cell:.2f} cells): labels start from that node"
            )
    seeds = ([start_node] if start_node is not None else []) + sorted(
        range(m), key=lambda n: -len(adjacency[n])
    )
    next_surface = 0
    for seed in seeds:
        if surface[seed] >= 0 or not adjacency[seed]:
            continue
        surface[seed] = next_surface
        queue = deque([seed])
        owner: dict[tuple[int, int], int] = {(0, 0): seed}
        while queue:
            a = queue.popleft()
            for b, dr, dc in adjacency[a]:
                lab = (int(labels[a, 0] + dr), int(labels[a, 1] + dc))
                if surface[b] >= 0:
                    conflicts += int(surface[b] != next_surface or tuple(labels[b]) != lab)
                    continue
                if lab in owner:
                    conflicts += 1
                    continue
                surface[b] = next_surface
                labels[b] = lab
                owner[lab] = b
                queue.append(b)
        next_surface += 1
    if conflicts:
        warnings.append(f"{conflicts} grid links disagreed with the labels and were ignored")
    return Labelled(points, rms, index, labels, surface, cell, conflicts, start_node, warnings)


def trace(nodes: Nodes, a: NDArray[np.float64], prev: NDArray[np.float64]) -> float | None:
    """Where the laser line that runs from ``prev`` through node ``a`` ends beyond ``a``, in
    units of the cell ``a − prev`` (both in pixels of this view): the line's half-brightness
    point; None when the line runs on past ``REACH`` cells (this view cannot tell). Past one
    cell is allowed: the nodes at the part's very edge are often lost (their crossings cut)."""
    d = a - prev
    length = float(np.hypot(*d))
    if length < 1:
        return None
    normal = np.array([-d[1], d[0]]) / length
    s = np.arange(-0.8, REACH + 0.2, 0.25 / length)
    offsets = np.array([-1.0, 0.0, 1.0])
    pts = a[None, None] + s[:, None, None] * d[None, None] + offsets[None, :, None] * normal
    profile = _sample(nodes.excess, pts).max(axis=1)
    inside = (s > -0.75) & (s < -0.25)
    ref = float(np.median(profile[inside]))
    if ref <= 0:
        return None
    beyond = np.flatnonzero((s > 0.15) & (profile < 0.5 * ref))
    if len(beyond) == 0 or s[beyond[0]] > REACH:
        return None
    k = int(beyond[0])
    # interpolate the half-brightness crossing between samples k − 1 and k
    p0, p1 = profile[k - 1], profile[k]
    frac = (p0 - 0.5 * ref) / (p0 - p1) if p0 != p1 else 0.0
    return float(s[k - 1] + frac * (s[k] - s[k - 1]))


def fit_base_plane(
    points: NDArray[np.float64], towards: NDArray[np.float64], tol: float, *, seed: int = 0
) -> NDArray[np.float64]:
    """The support surface: among planes through three nodes, the one with the most nodes
    within ``tol`` and (almost) none behind it, refined by least squares on its inliers.
    Returns [a, b, c, d], unit normal towards ``towards`` (the cameras)."""
    n = len(points)
    if n < 3:
        raise ValueError("fewer than 3 grid points: no base plane")
    rng = np.random.default_rng(seed)
    trials = rng.integers(0, n, size=(400, 3))
    p0, p1, p2 = points[trials[:, 0]], points[trials[:, 1]], points[trials[:, 2]]
    normal = np.cross(p1 - p0, p2 - p0)
    norm = np.linalg.norm(normal, axis=1)
    ok = norm > 1e-12
    normal = normal[ok] / norm[ok, None]
    p0 = p0[ok]
    flip = np.einsum("ij,ij->i", towards[None] - p0, normal) < 0
    normal[flip] *= -1
    offset = -np.einsum("ij,ij->i", normal, p0)
    dist = points @ normal.T + offset[None]  # (n, trials)
    inliers = (np.abs(dist) < tol).sum(axis=0)
    behind = (dist < -3 * tol).sum(axis=0)
    score = np.where(behind <= 0.02 * n, inliers, -1)
    best = int(np.argmax(score))
    if score[best] < 3:
        raise ValueError("no plane has the grid points on one side: give the base plane")
    inl = points[np.abs(dist[:, best]) < tol]
    centre = inl.mean(axis=0)
    _, _, vt = np.linalg.svd(inl - centre, full_matrices=False)  # not U: n × n
    nrm = vt[2] if vt[2] @ normal[best] > 0 else -vt[2]
    return np.append(nrm, -nrm @ centre)


@dataclass(frozen=True, slots=True)
class Measurement:
    surface_area: float
    """3-D area of the part's surface the grid covers [units²]."""
    side_area: float
    """Area of the walls from the part's boundary down to the base plane [units²]."""
    footprint_area: float
    """Area of the part's outline on the base plane [units²]."""
    volume: float
    """Between the part's surface and the base plane [units³]."""
    base_plane: NDArray[np.float64]
    """[a, b, c, d], a X + b Y + c Z + d = 0, unit normal towards the cameras."""
    height_max: float
    """The part's height: the 98th percentile of its nodes' heights, so that a stray node does
    not set it [units]."""
    part_nodes: int
    boundary_traced: int
    """Boundary crossings placed by a traced line end (the rest: at mid-cell)."""
    boundary_guessed: int


_CORNERS = ((0, 0), (0, 1), (1, 1), (1, 0))  # a cell's corners in order, (row, column)


def measure(
    grid: Labelled,
    nodes: list[Nodes],
    geo: Geometry,
    *,
    base_plane: NDArray[np.float64] | None = None,
    tol: float | None = None,
) -> Measurement:
    """Area and volume of what stands on the base plane (module docstring, step 4)."""
    pts = grid.points
    if base_plane is None:
        plane_tol = 0.1 * grid.cell
        plane = fit_base_plane(pts, geo.centres.mean(axis=0), plane_tol)
    else:
        plane = np.asarray(base_plane, dtype=np.float64)
        norm = np.linalg.norm(plane[:3])
        if not np.isfinite(plane).all() or norm == 0:
            raise ValueError("the base plane needs a non-zero normal")
        plane = plane / norm
        if plane[:3] @ geo.centres.mean(axis=0) + plane[3] < 0:
            plane = -plane
    normal, offset = plane[:3], plane[3]
    height = pts @ normal + offset
    if tol is None:
        tol = 0.15 * grid.cell
    lookup = {
        (int(s), int(r), int(c)): i
        for i, (s, (r, c)) in enumerate(zip(grid.surface, grid.labels, strict=True))
        if s >= 0
    }
    # on the part: above ``tol`` and a corner of at least one cell wholly above it (an
    # opening of the mask): a node next to a step, pulled up by the step's other side in
    # some views, is a lone node or a one-node-wide chain; a part narrower than a cell is
    # below the grid's resolution anyway
    high = height > tol
    on = np.zeros(len(pts), bool)
    for (s, r, c), i in lookup.items():
        if not high[i]:
            continue
        for dr, dc in ((0, 0), (-1, 0), (0, -1), (-1, -1)):
            cell_nodes = [lookup.get((s, r + dr + a, c + dc + b)) for a, b in _CORNERS]
            if all(j is not None and high[j] for j in cell_nodes):
                on[i] = True
                break
    # each node's pixel in each view (NaN: not seen), for tracing line ends
    pix = np.full((len(pts), len(nodes), 2), np.nan)
    for k, n in enumerate(nodes):
        seen = grid.index[:, k] >= 0
        pix[seen, k] = n.uv[grid.index[seen, k]]
    pts_list = list(pts)
    height_list = list(height)
    on_list = list(on)
    pix_list = list(pix)

    def traces(a: int, prev: int) -> list[float]:
        out = []
        for k, n in enumerate(nodes):
            pa, pp = pix_list[a][k], pix_list[prev][k]
            if np.isfinite(pa).all() and np.isfinite(pp).all():
                t = trace(n, pa, pp)
                if t is not None:
                    out.append(t)
        return out

    # a line that runs on past the next node, which is missing (its crossing cut at the very
    # edge), puts a node there: where the line says, on the part's surface, seen where it
    # projects (again from the new node: its own line may run on too)
    for _ in range(int(REACH)):
        added = []
        for (s, r, c), a in list(lookup.items()):
            if not on_list[a]:
                continue
            for dr, dc in ((0, 1), (0, -1), (1, 0), (-1, 0)):
                prev = lookup.get((s, r - dr, c - dc))
                if (s, r + dr, c + dc) in lookup or prev is None or not on_list[prev]:
                    continue
                ts = traces(a, prev)
                if ts and min(ts) >= 1.0:
                    added.append(((s, r + dr, c + dc), 2 * pts_list[a] - pts_list[prev]))
        if not added:
            break
        for key, p in added:
            if key in lookup:
                continue
            lookup[key] = len(pts_list)
            pts_list.append(p)
            height_list.append(float(p @ normal + offset))
            on_list.append(True)
            pix_list.append(geo.project(p[None])[0])
    pts = np.array(pts_list)
    height = np.array(height_list)
    on = np.array(on_list)
    traced = guessed = 0

    def node(s: int, r: int, c: int) -> int | None:
        return lookup.get((s, r, c))

    def crossing(s: int, r: int, c: int, dr: int, dc: int) -> NDArray[np.float64]:
        """The boundary point between on-node (r, c) and its neighbour (r + dr, c + dc)."""
        nonlocal traced, guessed
        a = lookup[(s, r, c)]
        b = node(s, r + dr, c + dc)
        if b is not None and height[b] <= 0 < height[a]:  # continuous surface: height's zero
            t = height[a] / (height[a] - height[b])
            return np.asarray(pts[a] + t * (pts[b] - pts[a]), dtype=np.float64)
        prev = node(s, r - dr, c - dc)
        if prev is None or not on[prev]:
            if b is not None:  # continuous but above zero at both ends of the threshold
                guessed += 1
                return np.asarray(0.5 * (pts[a] + pts[b]), dtype=np.float64)
            guessed += 1
            return np.asarray(pts[a], dtype=np.float64).copy()
        ts = traces(a, prev)
        if ts:
            traced += 1
            # a view where the line runs on over another surface overshoots: the shortest
            t = float(np.clip(min(ts), 0.0, 1.0))
        else:
            guessed += 1
            t = 0.5
        return np.asarray(pts[a] + t * (pts[a] - pts[prev]), dtype=np.float64)

    def foot(p: NDArray[np.float64]) -> NDArray[np.float64]:
        return np.asarray(p - (p @ normal + offset) * normal, dtype=np.float64)

    area = side = footprint = volume = 0.0
    cells = {
        (s, r + dr, c + dc)
        for (s, r, c), i in lookup.items()
        if on[i]
        for dr in (-1, 0)
        for dc in (-1, 0)
    }
    for s, r, c in cells:
        corners = [node(s, r + dr, c + dc) for dr, dc in _CORNERS]
        flags = [i is not None and bool(on[i]) for i in corners]
        if not any(flags):
            continue
        polygon: list[NDArray[np.float64]] = []
        cut: list[int] = []  # positions in the polygon of boundary points
        for k in range(4):
            (r0, c0), (r1, c1) = _CORNERS[k], _CORNERS[(k + 1) % 4]
            corner = corners[k]
            if flags[k]:
                assert corner is not None
                polygon.append(pts[corner])
            if flags[k] != flags[(k + 1) % 4]:
                if flags[k]:
                    p = crossing(s, r + r0, c + c0, r1 - r0, c1 - c0)
                else:
                    p = crossing(s, r + r1, c + c1, r0 - r1, c0 - c1)
                cut.append(len(polygon))
                polygon.append(p)
        poly = np.array(polygon)
        h = np.maximum(poly @ normal + offset, 0.0)
        feet = np.array([foot(p) for p in poly])
        for k in range(1, len(poly) - 1):
            tri = [0, k, k + 1]
            area += 0.5 * float(np.linalg.norm(np.cross(poly[k] - poly[0], poly[k + 1] - poly[0])))
            fa = 0.5 * abs(float(np.cross(feet[k] - feet[0], feet[k + 1] - feet[0]) @ normal))
            footprint += fa
            volume += fa * float(h[tri].mean())
        # walls: the chord between two consecutive boundary points of this cell
        for k in range(len(cut)):
            i0, i1 = cut[k], cut[(k + 1) % len(cut)]
            if len(cut) >= 2 and (i1 == (i0 + 1) % len(poly)):
                width = float(np.linalg.norm(feet[i1] - feet[i0]))
                side += width * 0.5 * float(h[i0] + h[i1])
    return Measurement(
        surface_area=area,
        side_area=side,
        footprint_area=footprint,
        volume=volume,
        base_plane=plane,
        height_max=float(np.percentile(height[on], 98)) if on.any() else 0.0,
        part_nodes=int(on.sum()),
        boundary_traced=traced,
        boundary_guessed=guessed,
    )


def _in_front(r: NDArray[np.float64], t: NDArray[np.float64], tri: Triangulator) -> Triangulator:
    """``tri``, with NaN for a point behind any camera that saw it (or at its lens, by the
    triangulators' one rule, ``triangulation.behind``): a laser spot lies in front of the rig,
    so such a point is a wrong match (of noise, or of two different spots). The calibrated
    rig's triangulator already refuses a point behind a view it used; this also refuses one
    behind a view its RANSAC set aside, since a candidate match must hold in every view that
    saw its spot."""

    def checked(obs: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        points, rms = tri(obs)
        seen = np.asarray(np.isfinite(obs).all(axis=2), dtype=np.bool_)
        back = behind(points, r, t, seen)
        return np.where(back[:, None], np.nan, points), np.where(back, np.nan, rms)

    return checked


def cross_geometry(rig: CrossRig) -> Geometry:
    """The 4-camera cross as a :class:`Geometry` (its frame: X right, Y up, Z forward, so each
    camera's y axis, pointing down, is −Y: R = diag(1, −1, 1), a reflection)."""
    r = np.tile(np.diag([1.0, -1.0, 1.0]), (4, 1, 1))
    c = rig.centres
    t = np.column_stack([-c[:, 0], c[:, 1], np.zeros(4)])

    def normalise(k: int, uv: NDArray[np.float64]) -> NDArray[np.float64]:
        return np.column_stack([(uv[:, 0] - rig.cx) / rig.f, (uv[:, 1] - rig.cy) / rig.f])

    def tri(obs: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        few = np.isfinite(obs).all(axis=-1).sum(axis=1) < 2
        safe = np.where(few[:, None, None], rig.project(np.array([[0.0, 0.0, 1.0]]))[0], obs)
        with np.errstate(all="ignore"):
            res = triangulate_cross(rig, safe)
        points = np.where(few[:, None], np.nan, res.points)
        return points, np.where(few, np.nan, res.reprojection_rms)

    return Geometry(r, t, np.full(4, rig.f), normalise, _in_front(r, t, tri), rig.project)


def views_geometry(views: list[View]) -> Geometry:
    """Calibrated cameras (distortion removed by OpenCV) as a :class:`Geometry`."""

    def tri(obs: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        res = triangulate_views(views, obs)
        return res.points, res.reprojection_rms

    rig = RigArrays.of(views)
    return Geometry(
        rig.rs,
        rig.ts,
        rig.fs,
        lambda k, uv: undistort(views[k], uv),
        _in_front(rig.rs, rig.ts, tri),
        lambda points: project_views(views, points),
    )
