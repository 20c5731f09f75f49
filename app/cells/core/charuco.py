"""ChArUco boards: a checkerboard whose white squares carry ArUco markers, so that every corner
found is known by its id, and a board partly out of the view, or partly hidden, still counts
(OpenCV's ``cv2.aruco.CharucoDetector``).

Not in the dissertation, which calibrates with Bouguet's checkerboard; a ChArUco board gives the
same corners (its squares' crossings) where a checkerboard must be seen whole.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

_cv: Any = cv2

MIN_CORNERS = 6
"""A view needs at least this many corners, not all on one line, to place the board (and so to
calibrate from): four fix a plane's homography, two more over-determine it."""

DICTIONARIES = tuple(n for n in dir(cv2.aruco) if n.startswith("DICT_"))
"""The predefined marker dictionaries, by OpenCV's names (``DICT_5X5_100``)."""


@dataclass(frozen=True, slots=True)
class Found:
    """The corners of one view: their ids, their places on the board (N, 3) [square units]
    and in the image (N, 1, 2) [px]."""

    ids: NDArray[np.int32]
    object_points: NDArray[np.float32]
    image_points: NDArray[np.float32]


def board(squares_x: int, squares_y: int, square: float, marker: float, dictionary: str) -> Any:
    """OpenCV's board of ``squares_x`` × ``squares_y`` squares of ``square``, markers of
    ``marker`` (< ``square``) from ``dictionary``. ValueError names what is wrong."""
    if dictionary not in DICTIONARIES:
        raise ValueError(f"dictionary {dictionary!r} is not one of OpenCV's (DICT_5X5_100, …)")
    if not 0 < marker < square:
        raise ValueError(f"marker_size {marker} must be above 0 and below square_size {square}")
    d = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, dictionary))
    needed = (squares_x * squares_y) // 2
    if needed > d.bytesList.shape[0]:
        raise ValueError(
            f"a {squares_x} × {squares_y} board needs {needed} markers; {dictionary} has "
            f"{d.bytesList.shape[0]}"
        )
    return cv2.aruco.CharucoBoard((squares_x, squares_y), square, marker, d)


def find(grey: NDArray[np.uint8], charuco: Any) -> Found | None:
    """The board's corners in the view, refined to sub-pixel by the detector, or None when
    fewer than ``MIN_CORNERS`` are found or they lie on one line."""
    corners, ids, _, _ = _cv.aruco.CharucoDetector(charuco).detectBoard(grey)
    if ids is None or len(ids) < MIN_CORNERS:
        return None
    ids = np.asarray(ids, dtype=np.int32).ravel()
    if charuco.checkCharucoCornersCollinear(ids):
        return None
    obj = np.asarray(charuco.getChessboardCorners(), dtype=np.float32)[ids]
    return Found(ids, obj, np.asarray(corners, dtype=np.float32).reshape(-1, 1, 2))


def common(a: Found, b: Found) -> tuple[Found, Found] | None:
    """The corners two views (of a pair of cameras) both found, in one order; None below
    ``MIN_CORNERS``."""
    shared, ia, ib = np.intersect1d(a.ids, b.ids, return_indices=True)
    if shared.size < MIN_CORNERS:
        return None
    return (
        Found(shared.astype(np.int32), a.object_points[ia], a.image_points[ia]),
        Found(shared.astype(np.int32), b.object_points[ib], b.image_points[ib]),
    )
