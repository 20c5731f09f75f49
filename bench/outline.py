"""Outline pipeline: time per 640×480 image, and corner error against exact ground truth.

Renders the test suite's prism scene (tests/cells/scenes.py: a matt box, its cast shadow,
Gaussian noise and blur) at several dynamic ranges and shadow strengths, runs
``app.cells.core.imaging.outline`` with and without the shadow step, and reports the largest corner
error [px] (median over seeds), the same for a light part on a dark table, and the median time
of the whole pipeline (luma already given: the part's side told → stretch → shadow step →
Canny → Hough → joining → corners).

    python bench/outline.py [--seeds 5]
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from app.cells.core.imaging import OutlineParams, outline  # noqa: E402
from tests.cells.scenes import PRISM_OUTLINE, light_prism_scene, prism_scene  # noqa: E402


def corner_error(found: np.ndarray) -> float:
    if found.shape != PRISM_OUTLINE.shape:
        return float("inf")
    return min(
        float(np.linalg.norm(np.roll(found, -k, axis=0) - PRISM_OUTLINE, axis=1).max())
        for k in range(len(found))
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=5)
    args = parser.parse_args()

    image = prism_scene()
    times = []
    for _ in range(60):
        t = time.perf_counter()
        outline(image)
        times.append(time.perf_counter() - t)
    print(
        f"time per 640×480 image: median {statistics.median(times) * 1000:.1f} ms, "
        f"p90 {np.percentile(times, 90) * 1000:.1f} ms"
    )

    print("\nlargest corner error [px], median over seeds (inf: no 6-corner polygon found)")
    print("| range | shadow | with shadow step | without |")
    print("|---|---|---|---|")
    for lo, hi in ((103, 170), (120, 150), (60, 200), (0, 255)):
        for shadow in (0.0, 0.3, 0.45, 0.6):
            errors = {True: [], False: []}
            for seed in range(args.seeds):
                scene = prism_scene(shadow=shadow, lo=lo, hi=hi, seed=seed)
                for step in (True, False):
                    o = outline(scene, OutlineParams(shadow=step))
                    errors[step].append(corner_error(o.corners))
            w, wo = statistics.median(errors[True]), statistics.median(errors[False])
            print(f"| {lo}–{hi} | {shadow:.2f} | {w:.2f} | {wo:.2f} |")

    print("\nnoise and blur (range 103–170, shadow 0.45, with the shadow step)")
    print("| noise σ [levels] | blur σ [px] | median error | worst of seeds |")
    print("|---|---|---|---|")
    for noise, blur in ((0.5, 1.0), (1.0, 1.0), (2.0, 1.0), (1.0, 1.5), (3.0, 1.0)):
        errs = [
            corner_error(outline(prism_scene(noise=noise, blur=blur, seed=s)).corners)
            for s in range(args.seeds)
        ]
        print(f"| {noise} | {blur} | {statistics.median(errs):.2f} | {max(errs):.2f} |")

    print("\na light part on a dark table (light_prism_scene), the part told automatically")
    print("| its shadow | part found | median error | worst of seeds |")
    print("|---|---|---|---|")
    for shadow in (True, False):
        found = [outline(light_prism_scene(shadow=shadow, seed=s)) for s in range(args.seeds)]
        errs = [corner_error(o.corners) for o in found]
        parts = "/".join(sorted({o.part for o in found}))
        print(f"| {shadow} | {parts} | {statistics.median(errs):.2f} | {max(errs):.2f} |")


if __name__ == "__main__":
    main()
