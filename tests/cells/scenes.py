"""Synthetic renders with exact ground truth, made by the tests themselves."""

from __future__ import annotations

import cv2
import numpy as np

# a box seen from above-left: the outer hexagon, counter-clockwise as seen (y down)
PRISM_OUTLINE = np.array(
    [[200.0, 150.0], [200.0, 300.0], [330.0, 360.0], [450.0, 300.0], [450.0, 170.0], [320.0, 110.0]]
)
_INNER = np.array([330.0, 210.0])


def _fill(canvas: np.ndarray, pts: np.ndarray, level: float) -> None:
    # draw with 1/16-pixel precision (shift=4) so vertices sit where the truth says
    cv2.fillPoly(canvas, [np.round(pts * 16).astype(np.int32)], float(level), cv2.LINE_AA, 4)


def low_range(image: np.ndarray, lo: float = 103.0, hi: float = 170.0) -> np.ndarray:
    """Map 0–255 into [lo, hi]: the narrow range of Figure 4.1."""
    return lo + image * (hi - lo) / 255.0


def finish(image: np.ndarray, *, noise: float, blur: float, seed: int) -> np.ndarray:
    if blur:
        image = cv2.GaussianBlur(image, (0, 0), blur)
    image = image + np.random.default_rng(seed).normal(0.0, noise, image.shape)
    return np.clip(np.rint(image), 0, 255).astype(np.uint8)


def prism_scene(
    *,
    shadow: float = 0.45,
    lo: float = 103.0,
    hi: float = 170.0,
    noise: float = 1.0,
    blur: float = 1.0,
    seed: int = 0,
) -> np.ndarray:
    """A matt box on a light table, lit from the upper left, with its shadow to the lower
    right; greyscale 640×480 squeezed into [lo, hi]. ``shadow``: how much darker the shadow is
    than the table (0: none)."""
    p = PRISM_OUTLINE
    image = np.full((480, 640), 235.0)
    d = np.array([110.0, 45.0])
    shade = [p[1], p[2], p[3], p[4], p[4] + d, p[3] + d, p[2] + d, p[1] + d * 0.6]
    _fill(image, np.array(shade), 235.0 * (1.0 - shadow))
    _fill(image, np.array([p[0], p[5], p[4], _INNER]), 95.0)  # top face, lit
    _fill(image, np.array([p[0], _INNER, p[2], p[1]]), 60.0)  # front face
    _fill(image, np.array([_INNER, p[4], p[3], p[2]]), 35.0)  # side face, away from the light
    return finish(low_range(image, lo, hi), noise=noise, blur=blur, seed=seed)


def light_prism_scene(
    *, shadow: bool = True, noise: float = 1.0, blur: float = 1.0, seed: int = 0
) -> np.ndarray:
    """The same box, light grey on a dark table (a machined part on a black conveyor belt),
    its shadow darker still: the outline of ``prism_scene``, colours the other way round."""
    p = PRISM_OUTLINE
    image = np.full((480, 640), 50.0)
    d = np.array([110.0, 45.0])
    if shadow:
        shade = [p[1], p[2], p[3], p[4], p[4] + d, p[3] + d, p[2] + d, p[1] + d * 0.6]
        _fill(image, np.array(shade), 20.0)
    _fill(image, np.array([p[0], p[5], p[4], _INNER]), 235.0)  # top face, lit
    _fill(image, np.array([p[0], _INNER, p[2], p[1]]), 200.0)  # front face
    _fill(image, np.array([_INNER, p[4], p[3], p[2]]), 160.0)  # side face
    return finish(image, noise=noise, blur=blur, seed=seed)


CYLINDER = {"cx": 320.0, "top": 140.0, "bottom": 330.0, "a": 90.0, "b": 30.0}


def cylinder_scene(*, noise: float = 1.0, blur: float = 1.0, seed: int = 0) -> np.ndarray:
    """An upright cylinder seen from slightly above: two straight sides, two elliptic arcs."""
    c = CYLINDER
    image = np.full((480, 640), 235.0)
    body = np.array(
        [
            [c["cx"] - c["a"], c["top"]],
            [c["cx"] - c["a"], c["bottom"]],
            [c["cx"] + c["a"], c["bottom"]],
            [c["cx"] + c["a"], c["top"]],
        ]
    )
    _fill(image, body, 60.0)
    for y, level in ((c["bottom"], 60.0), (c["top"], 95.0)):
        cv2.ellipse(
            image,
            (int(c["cx"] * 16), int(y * 16)),
            (int(c["a"] * 16), int(c["b"] * 16)),
            0,
            0,
            360,
            level,
            -1,
            cv2.LINE_AA,
            4,
        )
    return finish(low_range(image), noise=noise, blur=blur, seed=seed)


def checkerboard_photo(
    k: np.ndarray,
    rvec: np.ndarray,
    tvec: np.ndarray,
    size: tuple[int, int],
    *,
    cols: int = 9,
    rows: int = 6,
    square: float = 25.0,
    seed: int = 0,
) -> np.ndarray:
    """A cols × rows (inner corners) board of ``square`` mm squares, at pose (rvec, tvec) of a
    distortion-free pinhole camera ``k``, on a grey width × height image: the plane's
    homography K [r1 r2 t] (Zhang's), rendered at 4× and area-averaged down, with noise. The
    board's corner (i, j) is at (i·square, j·square, 0), as ``board_points`` puts it."""
    sq = 20  # texture pixels a square; a square's width of white margin
    texture = np.kron(
        (np.indices((rows + 1, cols + 1)).sum(0) % 2) * 255, np.ones((sq, sq))
    ).astype(np.uint8)
    texture = cv2.copyMakeBorder(texture, sq, sq, sq, sq, cv2.BORDER_CONSTANT, value=255)
    r = cv2.Rodrigues(np.asarray(rvec, np.float64))[0]
    plane = k @ np.column_stack([r[:, 0], r[:, 1], np.asarray(tvec, np.float64)])
    # texture pixel centre (u, v) → board (X, Y) [mm]: inner corner 0 lies between the pixels
    # 2·sq − 1 and 2·sq
    s = square / sq
    to_board = np.array([[s, 0, -(2 * sq - 0.5) * s], [0, s, -(2 * sq - 0.5) * s], [0, 0, 1]])
    # 4× render area-averaged down: a small pixel's centre x is the big one's 4x + 1.5
    up = np.array([[4.0, 0, 1.5], [0, 4.0, 1.5], [0, 0, 1]])
    big = cv2.warpPerspective(
        texture,
        up @ plane @ to_board,
        (4 * size[0], 4 * size[1]),
        borderValue=128,
    )
    image = cv2.resize(big, size, interpolation=cv2.INTER_AREA).astype(np.float64)
    return finish(image, noise=1.0, blur=0.0, seed=seed)
