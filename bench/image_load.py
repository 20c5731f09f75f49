"""Many large photos at once at an image endpoint: peak memory and time.

Posts ``--requests`` outlines of one ``--side`` × ``--side`` JPEG (a dark rectangle on grey,
with grain) at once to ``POST /vision/outline`` of an in-process service (SQLite in a temporary
directory), and reports the process's peak resident memory growth and the wall time. Run it
once with the default ``VANTAGE_IMAGE_THREADS`` (the CPUs) and once with ``--image-threads
40`` (as many as FastAPI's thread pool: every request at once) to compare.

    python bench/image_load.py [--requests 8] [--side 6000] [--image-threads 0]
"""

from __future__ import annotations

import argparse
import os
import resource
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import cv2
import numpy as np
from fastapi.testclient import TestClient

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from app.main import create_app  # noqa: E402
from app.platform.settings import Settings  # noqa: E402

TOKEN = "bench-admin-token-0123456789abcdef"


def photo(side: int) -> bytes:
    rng = np.random.default_rng(0)
    image = np.full((side, side, 3), 120, np.uint8)
    cv2.rectangle(image, (side // 6, side // 6), (side * 5 // 6, side * 2 // 3), (30, 30, 200), -1)
    image = cv2.add(image, rng.integers(0, 20, image.shape, dtype=np.uint8))
    ok, buf = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, 80])
    assert ok
    return buf.tobytes()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--requests", type=int, default=8)
    parser.add_argument("--side", type=int, default=6000)
    parser.add_argument("--image-threads", type=int, default=0)
    args = parser.parse_args()
    data = photo(args.side)
    with tempfile.TemporaryDirectory() as tmp:
        env = {**os.environ, "VANTAGE_DATA_DIR": tmp}
        subprocess.run(
            [sys.executable, "-m", "alembic", "upgrade", "head"],
            cwd=ROOT,
            env=env,
            check=True,
            capture_output=True,
        )
        settings = Settings(
            data_dir=Path(tmp),
            admin_token=TOKEN,  # type: ignore[arg-type]
            image_threads=args.image_threads,
            log_level="WARNING",
        )
        app = create_app(settings)
        headers = {"Authorization": f"Bearer {TOKEN}"}
        with TestClient(app) as client, ThreadPoolExecutor(args.requests) as pool:
            base = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
            start = time.perf_counter()
            statuses = list(
                pool.map(
                    lambda _: (
                        client.post(
                            "/vision/outline",
                            files={"file": ("p.jpg", data, "image/jpeg")},
                            headers=headers,
                        ).status_code
                    ),
                    range(args.requests),
                )
            )
            wall = time.perf_counter() - start
            peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024 - base
    print(
        f"{args.requests} × {args.side}×{args.side} outlines, image_threads "
        f"{settings.effective_image_threads}: statuses {sorted(set(statuses))}, "
        f"peak RSS growth {peak:.0f} MiB, wall {wall:.1f} s"
    )


if __name__ == "__main__":
    main()
