"""Camera calibration on OpenCV's stereo sample (``../shared/data/calibration/opencv_stereo``):
the service's corner finding (``app.cells.core.calibration.find_corners``) beside the classic
detector with OpenCV's sample refinement (an 11-pixel half-window), same views, same fit. Then
the same two on a family of boards rendered through a known camera (``tests.factories.
rendered_views``, seeds 100-129, six random poses each; no threshold was chosen on them), and
whether two cameras 120 mm apart number one board alike (150 poses, any roll, seed 7).

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
        fits[side] = C.fit_intrinsics([obj] * len(points[side]), points[side], (640, 480))
        f = fits[side]
        worst = f.per_view_rms.max() / np.median(f.per_view_rms)
        print(
            f"| {name} | {side} | {len(points[side])} | {f.rms:.4f} | {f.loo_rms:.4f} | "
            f"{f.K[0, 0]:.2f} | {f.K[1, 1]:.2f} | {f.K[0, 2]:.2f} | {f.K[1, 2]:.2f} | "
            f"{worst:.2f} |"
        )
    pose = C.stereo(
        [obj] * len(VIEWS), points["left"], points["right"], fits["left"], fits["right"]
    )
    print(
        f"| {name} | stereo | | {pose.rms:.4f} | {pose.loo_rms:.4f} | baseline "
        f"{pose.baseline:.3f} | rotation {pose.rotation_deg:.2f}° | | | |"
    )


def family(name: str, find: Finder) -> None:
    from tests.factories.cells import K_RENDER, rendered_views

    rms, err, found = [], [], 0
    for seed in range(100, 130):
        views = [cv2.imdecode(np.frombuffer(b, np.uint8), 0) for b in rendered_views(6, seed=seed)]
        points = [p for p in (find(g) for g in views) if p is not None]
        found += len(points)
        fit = C.fit_intrinsics([C.board_points(9, 6, 25.0)] * len(points), points, (640, 480))
        rms.append(fit.rms)
        err.append(abs(fit.K[0, 0] / K_RENDER[0, 0] - 1) * 100)
    print(
        f"| {name} | {found}/180 | {np.median(rms):.3f} / {max(rms):.3f} | "
        f"{np.median(err):.3f} / {max(err):.3f} |"
    )


def numbering() -> None:
    from tests.cells.scenes import checkerboard_photo

    k = np.array([[800.0, 0, 320], [0, 800, 240], [0, 0, 1]])
    rng = np.random.default_rng(7)
    obj = C.board_points(9, 6, 25.0)
    alike = apart = missed = 0
    for trial in range(150):
        tilt = rng.normal(0, 0.35, 2)
        roll = cv2.Rodrigues(np.array([0.0, 0.0, rng.uniform(0, 2 * np.pi)]))[0]
        r = cv2.Rodrigues(np.array([tilt[0], tilt[1], 0.0]))[0] @ roll
        rvec = cv2.Rodrigues(r)[0].ravel()
        left = -r @ np.array([100.0, 62.5, 0]) + np.array([*rng.normal(0, 20, 2), 650.0])
        right = left + np.array([-120.0, 0, 0])
        starts = []
        for n, t in enumerate((left, right)):
            found = C.find_corners(
                checkerboard_photo(k, rvec, t, (640, 480), seed=2 * trial + n), 9, 6
            )
            if found is None:
                break
            first = cv2.projectPoints(obj[:1], rvec, t, k, None)[0].ravel()
            starts.append(
                np.linalg.norm(found[0, 0] - first) < np.linalg.norm(found[-1, 0] - first)
            )
        if len(starts) < 2:
            missed += 1
        elif starts[0] == starts[1]:
            alike += 1
        else:
            apart += 1
    print(f"\npairs numbered alike {alike}, differently {apart}, board not found in one {missed}")


def one_megapixel() -> None:
    """20 views of a 1 MP camera (1152 × 864, rendered, seed 0) calibrated as the service does
    (corners, fit, each view held out), on one core (``cv2.setNumThreads(1)``), with the
    sector-based detector's flags as they are and with ``CALIB_CB_ACCURACY`` added."""
    import time

    from tests.cells.scenes import checkerboard_photo

    cv2.setNumThreads(1)
    k = np.array([[1000.0, 0.0, 576.0], [0.0, 1000.0, 432.0], [0.0, 0.0, 1.0]])
    rng = np.random.default_rng(0)
    centre = np.array([100.0, 62.5, 0.0])
    images = []
    for i in range(20):
        r = cv2.Rodrigues(rng.normal(0, 0.3, 3))[0]
        t = -r @ centre + np.array([0.0, 0.0, 600.0]) + rng.normal(0, [30, 30, 60])
        photo = checkerboard_photo(k, cv2.Rodrigues(r)[0].ravel(), t, (1152, 864), seed=i)
        images.append(photo.astype(np.uint8))
    plain = C.SB_FLAGS
    print("\n| detector flags | CPU s (one core) | views | RMS [px] | held out [px] |")
    print("|---|---|---|---|---|")
    for name, flags in (
        ("NORMALIZE_IMAGE, EXHAUSTIVE (the service's)", plain),
        ("and ACCURACY", plain | cv2.CALIB_CB_ACCURACY),
    ):
        C.SB_FLAGS = flags
        start = time.process_time()
        found = [C.find_corners(g, 9, 6) for g in images]
        pts = [f for f in found if f is not None]
        fit = C.fit_intrinsics([C.board_points(9, 6, 25.0)] * len(pts), pts, (1152, 864))
        took = time.process_time() - start
        print(f"| {name} | {took:.2f} | {len(pts)} | {fit.rms:.4f} | {fit.loo_rms:.4f} |")
    C.SB_FLAGS = plain
    cv2.setNumThreads(-1)


if __name__ == "__main__":
    if not DATA.exists():
        sys.exit(f"no data at {DATA}")
    print(
        "| corners | camera | views | RMS [px] | held out [px] | fx | fy | cx | cy "
        "| worst view / median |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|")
    run("classic, 11 px half-window", classic)
    run("service (SB, adaptive window)", service)
    print()
    print("| corners | views found | RMS median / worst [px] | fx error median / worst [%] |")
    print("|---|---|---|---|")
    family("classic, 11 px half-window", classic)
    family("service (SB, adaptive window)", service)
    numbering()
    one_megapixel()
