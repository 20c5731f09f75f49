"""Isopleths at scale: time and peak memory of each method for 50, 1,000 and 10,000 cameras on a
256×256 grid, bands included.

Each case runs in a fresh process; peak memory is tracemalloc's peak (NumPy, SciPy and Python
allocations) plus the process's RSS growth, as reported.

    python bench/isopleths.py
"""

from __future__ import annotations

import json
import resource
import subprocess
import sys
import time
import tracemalloc
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def case(n: int, method: str) -> dict[str, object]:
    sys.path.insert(0, str(ROOT))
    from app.air.core.isopleths import bands, default_bbox, interpolate

    rng = np.random.default_rng(n)
    # a city of ~30 km: cameras clustered along streets, a smooth pollution field
    lon = 9.0 + 0.4 * rng.random(n)
    lat = 45.3 + 0.27 * rng.random(n)
    level = np.clip(5.5 + 3 * np.sin(lon * 20) * np.cos(lat * 25) + rng.normal(0, 0.5, n), 1, 10)
    rss0 = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    tracemalloc.start()
    t = time.perf_counter()
    f = interpolate(
        lon,
        lat,
        level,
        bbox=default_bbox(lon, lat),
        method=method,  # type: ignore[arg-type]
        resolution=256,
        max_distance=3000,
    )
    t_field = time.perf_counter() - t
    features = bands(f)
    total = time.perf_counter() - t
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return {
        "cameras": n,
        "method": method,
        "field_s": round(t_field, 3),
        "total_s": round(total, 3),
        "peak_traced_mb": round(peak / 2**20, 1),
        "rss_growth_mb": round((rss - rss0) / 1024, 1),
        "bands": len(features),
    }


def main() -> None:
    if len(sys.argv) == 3:
        print(json.dumps(case(int(sys.argv[1]), sys.argv[2])))
        return
    print("| cameras | method | field [s] | with bands [s] | peak traced [MB] | RSS growth [MB] |")
    print("|---|---|---|---|---|---|")
    for n in (50, 1000, 10_000):
        for method in ("idw", "kriging", "rbf"):
            out = subprocess.run(
                [sys.executable, __file__, str(n), method],
                capture_output=True,
                text=True,
                check=True,
            )
            r = json.loads(out.stdout)
            print(
                f"| {n} | {method} | {r['field_s']} | {r['total_s']} | {r['peak_traced_mb']} | "
                f"{r['rss_growth_mb']} |",
                flush=True,
            )


if __name__ == "__main__":
    main()
