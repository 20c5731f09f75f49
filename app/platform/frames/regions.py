"""A camera's region drawn over its frame: where its statistics are measured."""

from __future__ import annotations

from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

REGION_EDGE_RGB = (255, 200, 0)
"""The colour the region's edge is drawn in (amber)."""


def region_corners(region: list[Any] | None, width: int, height: int) -> list[tuple[int, int]]:
    """The corners of a region, a rectangle [x, y, w, h] or a polygon [[x, y], ...] in an
    image's pixels; None: the whole ``width`` × ``height`` image."""
    if region is None:
        return [(0, 0), (width - 1, 0), (width - 1, height - 1), (0, height - 1)]
    if isinstance(region[0], list):
        return [(int(p[0]), int(p[1])) for p in region]
    x, y, w, h = (int(v) for v in region)
    return [(x, y), (x + w - 1, y), (x + w - 1, y + h - 1), (x, y + h - 1)]


def outline_region(image: NDArray[np.uint8], region: list[Any] | None) -> NDArray[np.uint8]:
    """``image`` (RGB, H × W × 3) with everything outside ``region`` darkened to a third and the
    region's edge drawn: what a camera's statistics are measured in. ``region``: as
    ``region_corners``."""
    height, width = image.shape[:2]
    polygon = np.array(region_corners(region, width, height), np.int32).reshape(-1, 1, 2)
    inside = np.zeros((height, width), np.uint8)
    cv2.fillPoly(inside, [polygon], 255)
    out = image // 3
    np.copyto(out, image, where=inside[:, :, None] > 0)
    thickness = max(2, round(min(height, width) / 300))
    cv2.polylines(out, [polygon], True, REGION_EDGE_RGB, thickness)
    return out
