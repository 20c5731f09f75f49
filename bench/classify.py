"""What classifying a panel frame costs next to decoding it, side by side in one run.

For 640×480 and 1920×1080 frames, the median time of
- decode: ``cv2.imdecode`` of the full frame, nothing else (the reference);
- the service's panel path: header check, full-size decode (the T² statistic is of the
  picture's own pixels, chapter 5 §III), channel statistics in the ROI, quality gate, then the
  T² verdict against the panel's baseline (baseline path) or the fleet features and the fleet
  model (fleet path).
Each round runs every variant once, in an order shuffled per round (seeded), so that machine
noise and the cache each variant leaves behind hit them alike. The histograms run on both cores
(OpenCV's calcHist): on a machine busy with other work the T² path's ratio rises, so the load
average is printed first. Last, the channel histograms alone, timed right after a decode and
right after the fleet path: what ran before moves them (likely OpenCV's worker threads, asleep
after a long call).

    python bench/classify.py [--rounds 200]
"""

from __future__ import annotations

import argparse
import os
import random
import statistics
import time
from collections.abc import Callable

import cv2
import numpy as np

from app.main import register_kinds
from app.platform.db.models import CameraKind
from app.platform.frames.camera_info import CameraInfo
from app.platform.frames.ingest import analyse
from app.platform.frames.stats import channel_histograms
from app.solar.core import fleet
from app.stats import hotelling

CAMERA = CameraInfo(id="bench", kind=CameraKind.panel, panel_id=None, roi=None)
WITH_BASELINE = CameraInfo(
    id="bench", kind=CameraKind.panel, panel_id="p", roi=None, has_reference=True
)


def panel_frame(width: int, height: int, seed: int = 0) -> bytes:
    """A panel under daylight: blue cells, frame lines, a sky strip, gradients, noise."""
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:height, 0:width]
    image = np.empty((height, width, 3), np.float64)
    image[:] = (56, 60, 84)
    image += (x / width * 20)[..., None]
    image[(y % (height // 12)) < 3] = (170, 172, 178)
    image[(x % (width // 16)) < 3] = (170, 172, 178)
    image[: height // 8] = (150, 180, 230)
    image += rng.normal(0, 6, image.shape)
    bgr = np.clip(image, 0, 255).astype(np.uint8)[:, :, ::-1]
    ok, buf = cv2.imencode(".jpg", np.ascontiguousarray(bgr), [cv2.IMWRITE_JPEG_QUALITY, 90])
    assert ok
    return buf.tobytes()


def make_variants(
    data: bytes, baseline: hotelling.Baseline, model: fleet.LogisticModel
) -> dict[str, Callable[[], None]]:
    arr = np.frombuffer(data, np.uint8)

    def decode() -> None:
        cv2.imdecode(arr, cv2.IMREAD_COLOR)

    def service_baseline() -> None:
        d = analyse(data, camera=WITH_BASELINE, max_pixels=10**9)
        hotelling.classify(baseline, d.stats.modes)

    def service_fleet() -> None:
        d = analyse(data, camera=CAMERA, max_pixels=10**9)
        model.probability(d.features)

    return {
        "decode only": decode,
        "service, baseline path": service_baseline,
        "service, fleet path": service_fleet,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=200)
    args = parser.parse_args()
    register_kinds()  # what the app does at start: the panel kind's ingest path
    rng = np.random.default_rng(1)
    baseline = hotelling.fit_baseline(rng.multivariate_normal([56, 60, 84], np.eye(3) * 4, 20))
    model = fleet.LogisticModel(
        feature_names=fleet.FEATURES,
        mean=np.zeros(len(fleet.FEATURES)),
        scale=np.ones(len(fleet.FEATURES)),
        coef=rng.normal(0, 0.1, len(fleet.FEATURES)),
        intercept=0.0,
    )

    order = random.Random(0)
    print("load average (1, 5, 15 min): {:.2f} {:.2f} {:.2f}".format(*os.getloadavg()))
    for width, height in ((640, 480), (1920, 1080)):
        data = panel_frame(width, height)
        variants = make_variants(data, baseline, model)
        times: dict[str, list[float]] = {k: [] for k in variants}
        for _ in range(args.rounds):
            names = list(variants)
            order.shuffle(names)
            for name in names:
                fn = variants[name]
                t = time.perf_counter()
                fn()
                times[name].append(time.perf_counter() - t)
        ref = statistics.median(times["decode only"])
        print(f"{width}×{height}:")
        for name, ts in times.items():
            m = statistics.median(ts)
            print(f"  {name:30s} {m * 1000:7.2f} ms   {m / ref:5.2f} × decode")
        image = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR_RGB)
        for before in ("decode only", "service, fleet path"):
            spent = []
            for _ in range(args.rounds):
                variants[before]()
                t = time.perf_counter()
                channel_histograms(image)
                spent.append(time.perf_counter() - t)
            m = statistics.median(spent)
            print(f"  histograms alone, after {before:19s} {m * 1000:7.3f} ms")


if __name__ == "__main__":
    main()
