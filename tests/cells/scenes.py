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


# --- a family of box scenes: random pose, size, light, contrast, range, noise and blur -------

_BOX_FACES = ((0, 1, 2, 3), (4, 5, 6, 7), (0, 1, 5, 4), (1, 2, 6, 5), (2, 3, 7, 6), (3, 0, 4, 7))
"""Vertex indices of the box's faces: bottom, top, then the four sides."""


class BoxScene:
    """One render of the family and its exact truth.

    ``image`` (480, 640) uint8; ``corners`` the outline's corners (the convex hull of the
    projected box), counter-clockwise as seen, shape (n, 2) [px]; ``light_part`` whether the
    part is lighter than its table; ``lo``/``hi`` the grey range; ``shadow`` its strength (how
    much darker than the table, 0–0.45); ``noise`` σ [levels]; ``blur`` σ [px]."""

    def __init__(self, **kw: object) -> None:
        self.__dict__.update(kw)

    image: np.ndarray
    corners: np.ndarray
    light_part: bool
    lo: float
    hi: float
    shadow: float
    noise: float
    blur: float
    min_turn: float
    min_side: float


def _hull_ccw(points: np.ndarray) -> np.ndarray:
    hull = cv2.convexHull(points.astype(np.float32)).reshape(-1, 2).astype(np.float64)
    x, y = hull[:, 0], hull[:, 1]
    if 0.5 * (x @ np.roll(y, -1) - np.roll(x, -1) @ y) > 0:  # clockwise as seen (y down)
        hull = hull[::-1]
    return hull


def _turns_and_sides(poly: np.ndarray) -> tuple[float, float]:
    d = np.diff(np.vstack([poly, poly[:1]]), axis=0)
    heading = np.degrees(np.arctan2(d[:, 1], d[:, 0]))
    turn = np.abs((np.diff(np.append(heading, heading[0])) + 180.0) % 360.0 - 180.0)
    return float(turn.min()), float(np.linalg.norm(d, axis=1).min())


def box_scene(
    seed: int,
    *,
    size: tuple[int, int] = (640, 480),
    min_turn: float = 10.0,
    min_side: float = 25.0,
) -> BoxScene:
    """A box on a table seen by a pinhole camera from a random pose, lit from a random
    direction, its shadow cast on the table; the part dark on a light table or light on a dark
    one; squeezed into a random grey range (103–170 … 0–255), blurred (σ 0.5–1.5 px) and with
    Gaussian noise (σ 0–2 levels). Rendered at 4× and area-averaged down, so the truth is exact
    to the antialiasing. Draws poses until the outline is well posed: every corner turns by at
    least ``min_turn`` [°] and every side is at least ``min_side`` [px] long. The part is at
    least 30 % darker (or lighter) than its shadow and table: the setting the method assumes."""
    rng = np.random.default_rng(seed)
    width, height = size
    k = np.array([[800.0, 0, width / 2 - 0.5], [0, 800.0, height / 2 - 0.5], [0, 0, 1]])
    while True:
        dims = rng.uniform([60, 60, 30], [160, 160, 120])  # mm: width, depth, height
        yaw = rng.uniform(0, np.pi)
        c, s = np.cos(yaw), np.sin(yaw)
        base = np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]]) * dims[:2] / 2
        base = base @ np.array([[c, s], [-s, c]])
        box = np.vstack(
            [np.column_stack([base, np.zeros(4)]), np.column_stack([base, np.full(4, dims[2])])]
        )
        box[:, :2] += rng.uniform(-40, 40, 2)
        # the camera looks at the table's origin from a tilt of 0–50° off vertical
        tilt, azimuth = np.radians(rng.uniform(0, 50)), rng.uniform(0, 2 * np.pi)
        distance = rng.uniform(700, 1100)
        eye = distance * np.array(
            [np.sin(tilt) * np.cos(azimuth), np.sin(tilt) * np.sin(azimuth), np.cos(tilt)]
        )
        forward = -eye / np.linalg.norm(eye)
        up = np.array([0.0, 1.0, 0.0]) if abs(forward[1]) < 0.9 else np.array([1.0, 0, 0])
        right = np.cross(forward, up)
        right /= np.linalg.norm(right)
        down = np.cross(forward, right)
        r = np.vstack([right, down, forward])
        t = -r @ eye
        roll = rng.uniform(-np.pi, np.pi)
        rz = np.array(
            [[np.cos(roll), -np.sin(roll), 0], [np.sin(roll), np.cos(roll), 0], [0, 0, 1]]
        )
        r, t = rz @ r, rz @ t

        def project(points: np.ndarray, r: np.ndarray = r, t: np.ndarray = t) -> np.ndarray:
            cam = points @ r.T + t
            uv = cam @ k.T
            return uv[:, :2] / uv[:, 2:]

        # light: elevation 35–70°, any azimuth; the shadow is the box projected along it
        elevation, light_az = np.radians(rng.uniform(35, 70)), rng.uniform(0, 2 * np.pi)
        light = np.array(
            [
                np.cos(elevation) * np.cos(light_az),
                np.cos(elevation) * np.sin(light_az),
                np.sin(elevation),
            ]
        )
        on_table = box[4:] - np.outer(box[4:, 2] / light[2], light)
        shade = _hull_ccw(project(np.vstack([box[:4], on_table])))
        outline = _hull_ccw(project(box))
        turn, side = _turns_and_sides(outline)
        inside = np.vstack([outline, shade])
        margin = 12
        if (
            turn >= min_turn
            and side >= min_side
            and inside[:, 0].min() > margin
            and inside[:, 1].min() > margin
            and inside[:, 0].max() < width - 1 - margin
            and inside[:, 1].max() < height - 1 - margin
        ):
            break

    light_part = bool(rng.random() < 0.5)
    strength = float(rng.uniform(0.0, 0.45)) if rng.random() < 0.8 else 0.0
    if light_part:
        table = rng.uniform(25, 80)
        albedo = rng.uniform(170, 250)
        floor = table * 1.3 + 20
    else:
        table = rng.uniform(190, 250)
        albedo = rng.uniform(50, min(130, 0.7 * table * (1 - strength)))
        floor = 8.0
    ambient = rng.uniform(0.35, 0.55)
    # Lambertian faces with an ambient share, drawn far to near (painter's order)
    centre = box.mean(axis=0)
    order = sorted(
        range(6),
        key=lambda f: -np.linalg.norm((box[list(_BOX_FACES[f])].mean(0)) @ r.T + t),
    )
    scale = 4.0
    big = np.full((height * 4, width * 4), table, dtype=np.float32)

    def fill(pts: np.ndarray, level: float) -> None:
        sub = np.round((pts * scale + 1.5) * 16).astype(np.int32)
        cv2.fillPoly(big, [sub], float(level), cv2.LINE_8, 4)

    fill(shade, table * (1.0 - strength))
    camera_centre = -r.T @ t
    for f in order:
        quad = box[list(_BOX_FACES[f])]
        normal = quad.mean(0) - centre
        normal /= np.linalg.norm(normal)
        if (camera_centre - quad.mean(0)) @ normal <= 0:
            continue  # faces away from the camera
        level = albedo * (ambient + (1 - ambient) * max(0.0, float(normal @ light)))
        fill(project(quad), max(level, floor) if light_part else min(level, 255.0))
    image = cv2.resize(big, size, interpolation=cv2.INTER_AREA).astype(np.float64)
    lo = float(rng.uniform(0, 103))
    hi = float(rng.uniform(170, 255))
    noise = float(rng.uniform(0, 2))
    blur = float(rng.uniform(0.5, 1.5))
    image = finish(low_range(image, lo, hi), noise=noise, blur=blur, seed=seed)
    turn, side = _turns_and_sides(outline)
    return BoxScene(
        image=image,
        corners=outline,
        light_part=light_part,
        lo=lo,
        hi=hi,
        shadow=strength,
        noise=noise,
        blur=blur,
        min_turn=turn,
        min_side=side,
    )


def corner_error(found: np.ndarray, truth: np.ndarray) -> float:
    """The largest distance of a found corner from its true one [px], the polygons matched by
    rotation (both counter-clockwise); inf when the counts differ."""
    if found.shape != truth.shape:
        return float("inf")
    return min(
        float(np.linalg.norm(np.roll(found, -k, axis=0) - truth, axis=1).max())
        for k in range(len(found))
    )
