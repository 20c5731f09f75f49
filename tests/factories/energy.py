"""Simulated plants: a panel's daily output with seasons, clouds, dust and cleanings."""

from __future__ import annotations

from dataclasses import dataclass
from datetime import date

import numpy as np
from numpy.typing import NDArray

START = date(2026, 1, 1)


@dataclass(frozen=True)
class Plant:
    days: NDArray[np.int64]
    """Proleptic ordinals."""
    kwh: NDArray[np.float64]
    expected: NDArray[np.float64]
    truth: NDArray[np.float64]
    """The true soiling ratio of each day."""
    cleanings: list[int]
    """The first clean day after each cleaning [ordinal]."""


def plant(
    seed: int,
    *,
    days: int = 150,
    cleanings: tuple[int, ...] = (60,),
    rate: float = 0.003,
    noise: float = 0.01,
    start: date = START,
    kwp: float = 0.4,
) -> Plant:
    """``days`` of a ``kwp`` panel's output from ``start``: clean energy with a seasonal swing
    of ±30 % and clouds letting through 20–100 %, dust taking ``rate`` of it a day, perfect
    cleanings on the given day numbers, and multiplicative Gaussian noise of ``noise``."""
    rng = np.random.default_rng(seed)
    n = np.arange(days)
    ordinals = start.toordinal() + n
    season = 1.0 + 0.3 * np.sin(2 * np.pi * (ordinals - date(2026, 3, 21).toordinal()) / 365.25)
    clouds = rng.uniform(0.2, 1.0, days)
    expected = kwp * 5.0 * season * clouds
    since = n.copy()
    for c in cleanings:
        since = np.where(n >= c, n - c, since)
    truth = 1.0 - rate * since
    kwh = expected * truth * (1.0 + noise * rng.standard_normal(days))
    return Plant(
        ordinals.astype(np.int64), kwh, expected, truth, [int(ordinals[c]) for c in cleanings]
    )
