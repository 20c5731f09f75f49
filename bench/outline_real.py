"""Outlines of the real part photos in ``../shared/data/parts`` against their hand-checked
corners (``corners.json``): how many corners the service finds within 2 px, and what it says
when it finds no outline.

    .venv/bin/python bench/outline_real.py
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from app.cells.core import imaging  # noqa: E402
from app.cells.services import vision  # noqa: E402
from app.platform.http.errors import Unprocessable  # noqa: E402

PARTS = ROOT.parent / "shared" / "data" / "parts"


def main() -> None:
    truth = json.loads((PARTS / "corners.json").read_text())
    print("| photo | size | corners | found within 2 px | worst [px] | s | answer |")
    print("|---|---|---|---|---|---|---|")
    within = total = 0
    for name, info in truth.items():
        corners = np.array(info["corners"])
        total += len(corners)
        start = time.perf_counter()
        try:
            got = vision.find_outline(
                (PARTS / name).read_bytes(),
                imaging.OutlineParams(),
                roi=None,
                max_pixels=60_000_000,
            )
            found = np.asarray(got.outline.corners) + np.array(got.offset)
            nearest = np.linalg.norm(found[None] - corners[:, None], axis=2).min(axis=1)
            hits = int((nearest <= 2.0).sum())
            answer, worst = f"{len(found)} corners", f"{nearest.max():.1f}"
        except Unprocessable as exc:
            hits, answer, worst = 0, f"422: {str(exc.detail)[:90]}…", "—"
        took = time.perf_counter() - start
        within += hits
        size = f"{info['width']}×{info['height']}"
        print(f"| {name} | {size} | {len(corners)} | {hits} | {worst} | {took:.1f} | {answer} |")
    print(f"\n{within} of {total} corners within 2 px ({100 * within / total:.0f} %)")


if __name__ == "__main__":
    main()
