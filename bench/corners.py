"""Checkerboard corners in large photos: detection on a scaled copy against the full image.

Renders the test suite's board (tests/cells/test_calibration.py: 9×6 inner corners in
perspective, rendered at 4× and area-averaged, exact corners) at several photo sizes, the
same with sensor grain (uniform 0–15 grey levels), and an image of noise (no board) of each
size, and times ``app.cells.core.calibration.find_corners`` as it
is (boards looked for at ``DETECT_SIDE`` px, corners refined at full size) against the same
function searching the full image (``DETECT_SIDE`` raised above the size), side by side in one
run. Reports the time and the corner error against the exact corners [px].

    python bench/corners.py [--sizes 640x480,2000x1500,4000x3000]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from app.cells.core import calibration
from tests.factories.cells import rendered_board  # noqa: E402


def timed(image: np.ndarray, side: int) -> tuple[float, np.ndarray | None]:
    calibration.DETECT_SIDE = side
    start = time.perf_counter()
    found = calibration.find_corners(image, 9, 6)
    return time.perf_counter() - start, found


def error(found: np.ndarray | None, truth: np.ndarray) -> str:
    if found is None:
        return "not found"
    d = np.linalg.norm(found.reshape(-1, 2)[:, None] - truth[None], axis=2).min(axis=1)
    return f"{np.median(d):.3f} / {d.max():.3f}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", default="640x480,2000x1500,4000x3000")
    args = parser.parse_args()
    scaled = calibration.DETECT_SIDE
    print(
        "| image | search | board: time | error median / max [px] "
        "| grainy board: time | error median / max [px] | noise: time |"
    )
    print("|---|---|---|---|---|---|---|")
    for size in args.sizes.split(","):
        w, h = (int(v) for v in size.split("x"))
        board, truth = rendered_board(w, h)
        grain = np.random.default_rng(2).integers(0, 16, (h, w), dtype=np.uint8)
        grainy = np.minimum(board.astype(np.int16) + grain, 255).astype(np.uint8)
        noise = np.random.default_rng(1).integers(0, 256, (h, w), dtype=np.uint8)
        for name, side in (("scaled copy", scaled), ("full image", 10**9)):
            if max(w, h) <= scaled and side != scaled:
                continue  # the same search
            t_board, found = timed(board, side)
            t_grainy, found_grainy = timed(grainy, side)
            t_noise, _ = timed(noise, side)
            print(
                f"| {w}×{h} | {name} | {t_board:.2f} s | {error(found, truth)} "
                f"| {t_grainy:.2f} s | {error(found_grainy, truth)} | {t_noise:.2f} s |",
                flush=True,
            )
    calibration.DETECT_SIDE = scaled


if __name__ == "__main__":
    main()
