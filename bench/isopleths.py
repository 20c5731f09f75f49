"""Isopleths at scale: time and peak memory of each method for 50, 1,000 and 10,000 cameras on a
256×256 grid, bands included. With ``--stations``: how well the map predicts a reference
station it was not given (leave one station out), from the other stations alone and with the
cameras too.

Each case runs in a fresh process; peak memory is tracemalloc's peak (NumPy, SciPy and Python
allocations) plus the process's RSS growth, as reported.

    python bench/isopleths.py
    python bench/isopleths.py --stations
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


def field_level(lon: np.ndarray, lat: np.ndarray) -> np.ndarray:
    """The synthetic city's true level at (lon, lat): a smooth field over ~30 km."""
    return np.asarray(np.clip(5.5 + 3 * np.sin(lon * 20) * np.cos(lat * 25), 1, 10))


def leave_one_station_out(seed: int, stations: int = 12, cameras: int = 200) -> dict[str, float]:
    """Mean absolute error [level] of the kriged map at each station left out, the map made
    of the other stations (error 0.29, a level's rounding) alone, with the cameras (each
    reading off by N(0, σᵢ), σᵢ uniform in 0.5–2 levels, and saying so), and with the same
    cameras taken as exact."""
    sys.path.insert(0, str(ROOT))
    from app.air.core.isopleths import interpolate

    rng = np.random.default_rng(seed)
    s_lon, s_lat = 9.0 + 0.4 * rng.random(stations), 45.3 + 0.27 * rng.random(stations)
    c_lon, c_lat = 9.0 + 0.4 * rng.random(cameras), 45.3 + 0.27 * rng.random(cameras)
    s_true = field_level(s_lon, s_lat)
    sigma = rng.uniform(0.5, 2.0, cameras)
    c_read = field_level(c_lon, c_lat) + rng.normal(0, sigma)
    errors: dict[str, list[float]] = {"stations": [], "with cameras": [], "cameras as exact": []}
    for i in range(stations):
        rest = np.arange(stations) != i
        box = (s_lon[i] - 1e-4, s_lat[i] - 1e-4, s_lon[i] + 1e-4, s_lat[i] + 1e-4)
        for name, lon, lat, value, err in (
            ("stations", s_lon[rest], s_lat[rest], s_true[rest], np.full(rest.sum(), 0.29)),
            (
                "with cameras",
                np.r_[s_lon[rest], c_lon],
                np.r_[s_lat[rest], c_lat],
                np.r_[s_true[rest], c_read],
                np.r_[np.full(rest.sum(), 0.29), sigma],
            ),
            (
                "cameras as exact",
                np.r_[s_lon[rest], c_lon],
                np.r_[s_lat[rest], c_lat],
                np.r_[s_true[rest], c_read],
                np.r_[np.full(rest.sum(), 0.29), np.zeros(cameras)],
            ),
        ):
            f = interpolate(lon, lat, value, bbox=box, method="kriging", resolution=3,
                            max_distance=50_000, errors=err)  # fmt: skip
            errors[name].append(abs(float(f.value[1, 1]) - float(s_true[i])))
    return {k: float(np.mean(v)) for k, v in errors.items()}


def stations_table() -> None:
    print("| city (seed) | stations alone | stations and cameras | cameras taken as exact |")
    print("|---|---|---|---|")
    means = []
    for seed in range(5):
        r = leave_one_station_out(seed)
        means.append(list(r.values()))
        print(f"| {seed} | {r['stations']:.2f} | {r['with cameras']:.2f} | "
              f"{r['cameras as exact']:.2f} |")  # fmt: skip
    m = np.mean(means, axis=0)
    print(f"| mean | {m[0]:.2f} | {m[1]:.2f} | {m[2]:.2f} |")


def main() -> None:
    if sys.argv[1:] == ["--stations"]:
        stations_table()
        return
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
