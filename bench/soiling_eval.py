"""The soiling ratio from output (``app.solar.core.soiling``): its accuracy on simulated plants
against the truth and, where RdTools is installed, against RdTools' stochastic rate and
recovery method on the same series; and the time to analyse a farm's decade of output.

    .venv/bin/python bench/soiling_eval.py                        # ours: accuracy and speed
    pip install rdtools==3.2.1 && python bench/soiling_eval.py    # and RdTools beside it

RdTools is not a dependency of the service (it brings several hundred MB with it); a venv
with it and numpy/scipy can run this file with ``PYTHONPATH=.``.
"""

from __future__ import annotations

import argparse
import sys
import time
from datetime import date
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from app.solar.core import soiling  # noqa: E402
from tests.factories.energy import plant  # noqa: E402

try:  # optional: the reference implementation
    import warnings

    import pandas as pd

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        from rdtools.soiling import soiling_srr
except ImportError:
    soiling_srr = None


def ours(p: object, *, known: bool) -> tuple[float, float, float, float, float]:
    """Last-day ratio, its low and high, the last interval's rate [1/day], seconds taken."""
    start = time.perf_counter()
    found = soiling.analyse(
        p.days,
        p.kwh,
        p.expected,
        cleanings=p.cleanings if known else (),  # type: ignore[attr-defined]
    )
    took = time.perf_counter() - start
    now = found.current
    assert now is not None
    assert now.rate is not None
    return now.ratio, now.low, now.high, now.rate, took


def rdtools(p: object, seed: int) -> tuple[float, float, float, float, float]:
    """RdTools' last-day ratio (``soiling_ratio_perfect_clean``, the simulation's cleanings
    being perfect), the 2.5 and 97.5 percentiles of its 200 realisations' last day, its last
    interval's rate, and seconds taken."""
    index = pd.DatetimeIndex([pd.Timestamp(date.fromordinal(int(d))) for d in p.days])  # type: ignore[attr-defined]
    pi = pd.Series(p.kwh / p.expected, index=index).asfreq("D")  # type: ignore[attr-defined]
    insolation = pd.Series(p.expected, index=index).asfreq("D")  # type: ignore[attr-defined]
    np.random.seed(seed)  # noqa: NPY002 (RdTools draws from the global state)
    start = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        _, _, info = soiling_srr(pi, insolation, reps=200, method="perfect_clean")
    took = time.perf_counter() - start
    last = np.array([float(s.iloc[-1]) for s in info["stochastic_soiling_profiles"]])
    low, high = np.percentile(last, [2.5, 97.5])
    rate = float(info["soiling_interval_summary"]["soiling_rate"].iloc[-1])
    return float(info["soiling_ratio_perfect_clean"].iloc[-1]), low, high, rate, took


def family(seed: int) -> object:
    """A plant of the family: dust at 0.1–0.5 %/day, noise 0.5–3 %, the cleaning on day
    30–110 of 150, all drawn from ``seed``."""
    rng = np.random.default_rng(seed)
    return plant(
        seed,
        rate=float(rng.uniform(0.001, 0.005)),
        noise=float(rng.uniform(0.005, 0.03)),
        cleanings=(int(rng.integers(30, 111)),),
    )


def accuracy(n: int, *, base: int, vary: bool, with_rdtools: bool) -> None:
    rows: dict[str, list[tuple[float, float, float, float, float, float]]] = {}
    for seed in range(n):
        p = family(base + seed) if vary else plant(base + seed)
        truth = float(p.truth[-1])
        true_rate = float(p.truth[-1] - p.truth[-2])  # [1/day], negative
        runs = {
            "ours, cleaning known": ours(p, known=True),
            "ours, from output": ours(p, known=False),
        }
        if with_rdtools:
            runs["RdTools SRR (200 reps)"] = rdtools(p, seed)
        for name, (r, lo, hi, rate, took) in runs.items():
            rows.setdefault(name, []).append((r - truth, lo, hi, truth, rate - true_rate, took))
    what = "the family" if vary else "0.3 %/day, one cleaning on day 60, 1 % noise"
    print(f"\n{n} simulated plants from seed {base} (150 days, clouds 20-100 %, {what})")
    print(
        "| estimator | mean abs. error | largest | within 0.015 | interval holds | rate err. | ms |"
    )
    print("|---|---|---|---|---|---|---|")
    for name, got in rows.items():
        err = np.array([g[0] for g in got])
        held = np.mean([g[1] <= g[3] <= g[2] for g in got])
        rate = np.mean([abs(g[4]) for g in got])
        ms = 1000 * np.mean([g[5] for g in got])
        print(
            f"| {name} | {np.abs(err).mean():.4f} | {np.abs(err).max():.4f} | "
            f"{100 * np.mean(np.abs(err) <= 0.015):.0f} % | {100 * held:.1f} % | "
            f"{rate:.5f} | {ms:.1f} |"
        )


def speed(panels: int, years: int) -> None:
    """A farm's decade: each panel cleaned every 30–120 days, its output analysed once."""
    rng = np.random.default_rng(0)
    days = 365 * years
    plants = []
    for k in range(panels):
        gaps = rng.integers(30, 121, size=days // 30)
        cleanings = tuple(int(c) for c in np.cumsum(gaps) if c < days)
        plants.append(
            plant(k, days=days, cleanings=cleanings, rate=float(rng.uniform(0.001, 0.004)))
        )
    start = time.process_time()
    found = [soiling.analyse(p.days, p.kwh, p.expected, cleanings=p.cleanings) for p in plants]
    took = time.process_time() - start
    intervals = sum(len(f.intervals) for f in found)
    print(f"\n{panels} panels x {years} years of daily output ({intervals} soiling intervals)")
    print("| analysis | CPU seconds (one core) | ms a panel |")
    print("|---|---|---|")
    print(f"| all intervals, ratio, losses | {took:.1f} | {1000 * took / panels:.1f} |")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--plants", type=int, default=200)
    ap.add_argument("--panels", type=int, default=1000)
    ap.add_argument("--years", type=int, default=10)
    ap.add_argument(
        "--seed",
        type=int,
        default=5000,
        help="the first plant's seed (1000-1399 were looked at "
        "while the recovery detector was built: the figures are of seeds from 5000)",
    )
    ap.add_argument("--family", action="store_true", help="vary rate, noise and cleaning day")
    args = ap.parse_args()
    if soiling_srr is None:
        print("RdTools not installed: ours only")
    rd = soiling_srr is not None
    accuracy(args.plants, base=args.seed, vary=False, with_rdtools=rd)
    if args.family:
        print("\nthe family: dust 0.1-0.5 %/day, noise 0.5-3 %, cleaning on day 30-110")
        accuracy(args.plants, base=args.seed, vary=True, with_rdtools=False)
    speed(args.panels, args.years)


if __name__ == "__main__":
    main()
