"""Camera calibration on OpenCV's stereo sample (``../shared/data/calibration/opencv_stereo``):
the service's corner finding (``app.cells.core.calibration.find_corners``) beside the classic
detector with OpenCV's sample refinement (an 11-pixel half-window), same views, same fit. Then
the same two on a family of boards rendered through a known camera (``tests.factories.
rendered_views``, seeds 100-129, six random poses each; no threshold was chosen on them).

    python bench/calibration.py
"""

from __future__ import annotations

import sys
from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from app.cells.core import calibration as C  # noqa: E402

DATA = ROOT.parent / "shared" / "data" / "calibration" / "opencv_stereo"
VIEWS = [f"{i:02d}" for i in range(1, 15) if i != 10]
Finder = Callable[[np.ndarray], np.ndarray | None]


def classic(grey: np.ndarray) -> np.ndarray | None:
    ok, corners = cv2.findChessboardCorners(grey, (9, 6))
    if not ok:
        return None
    criteria = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 30, 0.001)
    return cv2.cornerSubPix(grey, corners, (11, 11), (-1, -1), criteria)


def service(grey: np.ndarray) -> np.ndarray | None:
    return C.find_corners(grey, 9, 6)


def run(name: str, find: Finder) -> None:
    points: dict[str, list[np.ndarray]] = {}
    obj = C.board_points(9, 6, 1.0)
    fits = {}
    for side in ("left", "right"):
        found = [
            find(cv2.imread(str(DATA / f"{side}{n}.jpg"), cv2.IMREAD_GRAYSCALE)) for n in VIEWS
        ]
        points[side] = [p for p in found if p is not None]
        fits[side] = C.calibrate([obj] * len(points[side]), points[side], (640, 480))
        f = fits[side]
        worst = f.per_view_rms.max() / np.median(f.per_view_rms)
        print(
            f"| {name} | {side} | {len(points[side])} | {f.rms:.4f} | {f.K[0, 0]:.2f} | "
            f"{f.K[1, 1]:.2f} | {f.K[0, 2]:.2f} | {f.K[1, 2]:.2f} | {worst:.2f} |"
        )
    pose = C.stereo(
        [obj] * len(VIEWS), points["left"], points["right"], fits["left"], fits["right"]
    )
    print(
        f"| {name} | stereo | | {pose.rms:.4f} | baseline {pose.baseline:.3f} | "
        f"rotation {pose.rotation_deg:.2f}° | | | |"
    )


def family(name: str, find: Finder) -> None:
    from tests.factories import K_RENDER, rendered_views

    rms, err, found = [], [], 0
    for seed in range(100, 130):
        views = [cv2.imdecode(np.frombuffer(b, np.uint8), 0) for b in rendered_views(6, seed=seed)]
        points = [p for p in (find(g) for g in views) if p is not None]
        found += len(points)
        fit = C.calibrate([C.board_points(9, 6, 25.0)] * len(points), points, (640, 480))
        rms.append(fit.rms)
        err.append(abs(fit.K[0, 0] / K_RENDER[0, 0] - 1) * 100)
    print(
        f"| {name} | {found}/180 | {np.median(rms):.3f} / {max(rms):.3f} | "
        f"{np.median(err):.3f} / {max(err):.3f} |"
    )


if __name__ == "__main__":
    if not DATA.exists():
        sys.exit(f"no data at {DATA}")
    print("| corners | camera | views | RMS [px] | fx | fy | cx | cy | worst view / median |")
    print("|---|---|---|---|---|---|---|---|---|")
    run("classic, 11 px half-window", classic)
    run("service (SB, adaptive window)", service)
    print()
    print("| corners | views found | RMS median / worst [px] | fx error median / worst [%] |")
    print("|---|---|---|---|")
    family("classic, 11 px half-window", classic)
    family("service (SB, adaptive window)", service)
