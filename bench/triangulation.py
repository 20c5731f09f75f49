"""Triangulation accuracy and speed, by simulation.

Accuracy: a 4-camera cross (f = 800 px, ax = 0.30, ay = 0.20 m), 20,000 points at each depth,
σ = 0.5 px Gaussian pixel noise, seeded. RMS 3-D error [mm] of each single pair's depth (with
X, Y from that pair), the plain mean of the ten estimates (eq. 4.47), the inverse-variance
weighted mean, the least-squares / ML solution on all eight coordinates, and two-view epipolar
triangulation (``cv2.triangulatePoints`` on cameras 1 and 2, the dissertation's competitor).
Speed: the same, timed; and a calibrated 4-view rig with distortion, 100,000 points, against
``cv2.triangulatePoints`` on 2 views.

    python bench/triangulation.py
"""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from app.cells.core.triangulation import (  # noqa: E402
    PAIRS,
    CrossRig,
    View,
    project_views,
    triangulate_cross,
    triangulate_views,
)

RIG = CrossRig(f=800.0, ax=0.30, ay=0.20, cx=320.0, cy=240.0)
N = 20_000


def rms_mm(p: np.ndarray, truth: np.ndarray) -> float:
    ok = np.isfinite(p).all(axis=1)
    return float(np.sqrt(np.mean(np.sum((p[ok] - truth[ok]) ** 2, axis=1))) * 1000)


def epipolar(obs: np.ndarray) -> np.ndarray:
    k = np.array([[RIG.f, 0, RIG.cx], [0, -RIG.f, RIG.cy], [0, 0, 1.0]])  # v down, Y up
    p1 = k @ np.hstack([np.eye(3), [[-RIG.ax / 2], [0], [0]]])
    p2 = k @ np.hstack([np.eye(3), [[RIG.ax / 2], [0], [0]]])
    x = cv2.triangulatePoints(p1, p2, obs[:, 0].T.copy(), obs[:, 1].T.copy())
    return (x[:3] / x[3]).T


def main() -> None:
    rng = np.random.default_rng(7)
    print(
        "| depth [m] | "
        + " | ".join(f"pair {i + 1}–{j + 1} {a}" for i, j, a in PAIRS)
        + " | mean (4.47) | weighted | least squares | epipolar 1–2 |"
    )
    print("|---" * (len(PAIRS) + 5) + "|")
    for depth in (0.5, 1.0, 2.0, 4.0, 8.0):
        truth = np.column_stack(
            [
                rng.uniform(-0.2, 0.2, N) * depth,
                rng.uniform(-0.15, 0.15, N) * depth,
                np.full(N, depth),
            ]
        )
        obs = RIG.project(truth) + rng.normal(0, 0.5, (N, 4, 2))
        r = triangulate_cross(RIG, obs, method="mean")
        singles = []
        n = RIG.normalised(obs)
        c = RIG.centres
        for k, (i, j, _) in enumerate(PAIRS):
            z = r.z_estimates[:, k]
            x = 0.5 * ((n[:, i, 0] * z + c[i, 0]) + (n[:, j, 0] * z + c[j, 0]))
            y = 0.5 * ((n[:, i, 1] * z + c[i, 1]) + (n[:, j, 1] * z + c[j, 1]))
            singles.append(rms_mm(np.column_stack([x, y, z]), truth))
        cols = [
            rms_mm(triangulate_cross(RIG, obs, method=m).points, truth)
            for m in ("mean", "weighted", "least_squares")
        ]
        cols.append(rms_mm(epipolar(obs), truth))
        print(f"| {depth} | " + " | ".join(f"{v:.1f}" for v in singles + cols) + " |")

    truth = np.column_stack(
        [rng.uniform(-0.4, 0.4, N), rng.uniform(-0.3, 0.3, N), rng.uniform(1, 4, N)]
    )
    obs = RIG.project(truth) + rng.normal(0, 0.5, (N, 4, 2))
    print("\ntime for 20,000 points (median of 5):")
    for name, fn in (
        ("cross, mean (4.47)", lambda: triangulate_cross(RIG, obs, method="mean")),
        ("cross, weighted", lambda: triangulate_cross(RIG, obs, method="weighted")),
        ("cross, least squares", lambda: triangulate_cross(RIG, obs, method="least_squares")),
        ("epipolar 1–2 (cv2)", lambda: epipolar(obs)),
    ):
        ts = []
        for _ in range(5):
            t = time.perf_counter()
            fn()
            ts.append(time.perf_counter() - t)
        print(f"  {name:24s} {np.median(ts) * 1000:8.1f} ms")

    k = np.array([[800.0, 0, 320], [0, 800, 240], [0, 0, 1]])
    dist = np.array([-0.1, 0.01, 0, 0, 0.0])
    views = []
    for i in range(4):
        r = cv2.Rodrigues(np.radians([0.0, (i - 1.5) * 8, 0.0]))[0]
        views.append(View(k, dist, r, -r @ np.array([(i - 1.5) * 0.3, 0.05 * i, 0.0])))
    m = 100_000
    pts = np.column_stack(
        [rng.uniform(-0.5, 0.5, m), rng.uniform(-0.4, 0.4, m), rng.uniform(2, 5, m)]
    )
    o = project_views(views, pts) + rng.normal(0, 0.3, (m, 4, 2))
    res = triangulate_views(views, o)  # compiles the per-point loop once per process (numba)
    p1 = k @ np.hstack([views[0].R, views[0].t[:, None]])
    p2 = k @ np.hstack([views[1].R, views[1].t[:, None]])

    def undistort(i: int) -> np.ndarray:
        return cv2.undistortPoints(o[:, i].reshape(-1, 1, 2), k, dist, P=k).reshape(-1, 2)

    und = [undistort(0), undistort(1)]

    def cv2_linear() -> None:
        cv2.triangulatePoints(p1, p2, und[0].T.copy(), und[1].T.copy())

    def cv2_with_undistortion() -> None:
        a, b = undistort(0), undistort(1)
        cv2.triangulatePoints(p1, p2, a.T.copy(), b.T.copy())

    def median_ms(fn: object) -> float:
        ts = []
        for _ in range(5):
            t = time.perf_counter()
            fn()  # type: ignore[operator]
            ts.append(time.perf_counter() - t)
        return float(np.median(ts)) * 1000

    ours = median_ms(lambda: triangulate_views(views, o))
    theirs = median_ms(cv2_linear)
    theirs_raw = median_ms(cv2_with_undistortion)
    print(
        f"\ncalibrated rig, 100,000 points (median of 5): ours on 4 views from raw pixels "
        f"(undistort, linear, Gauss–Newton, RANSAC gate, RMS) {ours:.0f} ms, RMS error "
        f"{rms_mm(res.points, pts):.1f} mm; cv2.triangulatePoints on 2 views, linear only: "
        f"{theirs:.0f} ms on pre-undistorted points, {theirs_raw:.0f} ms with the undistortion; "
        f"ratio ours / cv2 {ours / theirs:.2f} ({ours / theirs_raw:.2f})"
    )
    cold_start()


COLD = """
import time
t0 = time.perf_counter()
import numpy as np
from app.cells.core.triangulation import View, project_views, triangulate_views
t1 = time.perf_counter()
k = np.array([[800.0, 0, 320], [0, 800, 240], [0, 0, 1]])
views = [View(k, np.array([-0.1, 0.01, 0, 0, 0.0]), np.eye(3), np.array([-x, 0.0, 0.0]))
         for x in (0.0, 0.1, 0.2, 0.3)]
rng = np.random.default_rng(0)
pts = np.column_stack([rng.uniform(-0.3, 0.3, N), rng.uniform(-0.2, 0.2, N), rng.uniform(1, 3, N)])
obs = project_views(views, pts) + rng.normal(0, 0.3, (N, 4, 2))
t2 = time.perf_counter()
triangulate_views(views, obs)
t3 = time.perf_counter()
triangulate_views(views, obs)
t4 = time.perf_counter()
print(t1 - t0, t3 - t2, t4 - t3)
"""


def cold_start(runs: int = 5) -> None:
    """The first triangulation in a fresh process, each run its own interpreter (numba's disk
    cache warm from the runs before)."""
    root = str(Path(__file__).resolve().parents[1])
    print(f"\nfirst call in a fresh process (median of {runs} processes)")
    print("| points × views | import [s] | first call [s] | second call [s] |")
    print("|---|---|---|---|")
    for n in (10, 1_000, 10_000):
        rows = []
        for _ in range(runs + 1):  # the first run fills numba's cache, if it is empty
            out = subprocess.run(
                [sys.executable, "-c", f"N = {n}\n" + COLD],
                cwd=root,
                capture_output=True,
                text=True,
                check=True,
            )
            rows.append([float(x) for x in out.stdout.split()])
        imp, first, second = np.median(np.array(rows[1:]), axis=0)
        print(f"| {n:,} × 4 | {imp:.2f} | {first:.3f} | {second:.3f} |")


if __name__ == "__main__":
    main()
