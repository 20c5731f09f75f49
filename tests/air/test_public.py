"""The public reading's arithmetic (``app.air.core.public``) against answers worked by hand."""

from __future__ import annotations

from datetime import UTC, datetime, timedelta

import numpy as np
import pytest
from scipy.stats import norm

from app.air.core import public

T = datetime(2026, 5, 1, 12, tzinfo=UTC)
BIG = 1e9
"""Degrees of freedom for which Student's t is the normal (to 1e-9)."""


@pytest.mark.parametrize(
    ("unit", "table", "edges"),
    [
        ("pm25", "eu_eaqi", (10.0, 20.0, 25.0, 50.0)),  # EEA 2017, upper edges inclusive
        ("pm25", "us_epa", (9.1, 35.5, 55.5, 125.5)),  # EPA 2024, truncated to 0.1
        ("aqi", "us_epa", (50.5, 100.5, 150.5, 200.5)),  # AQI rounded to a whole number
        ("level", "us_epa", (2.5, 4.5, 6.5, 8.5)),  # levels rounded to even (numpy's rint)
    ],
)
def test_the_category_edges_are_the_tables(unit: str, table: str, edges: tuple[float, ...]) -> None:
    assert public.category_edges(unit, table) == pytest.approx(edges, abs=1e-6)


def test_probabilities_are_the_t_masses_between_the_edges() -> None:
    """At the Good/Fair edge (20 µg/m³, European bands), half the mass either side; the
    masses are the normal's between the edges in ln(1 + PM2.5)."""
    loc, scale = float(np.log1p(20.0)), 0.3
    p = public.probabilities(public.Predictive(loc, scale, BIG, "pm25", "eu_eaqi"))
    assert sum(p.values()) == pytest.approx(1.0, abs=1e-12)
    assert p["Very Good"] + p["Good"] == pytest.approx(0.5, abs=1e-6)
    fair = norm.cdf((np.log1p(25.0) - loc) / scale) - 0.5
    assert p["Fair"] == pytest.approx(fair, abs=1e-6)
    sure = public.public(public.Predictive(float(np.log1p(17.0)), 0.01, BIG, "pm25", "eu_eaqi"))
    assert (sure.category, sure.level, sure.uncertain) == ("Good", 7, False)
    assert sure.probability == pytest.approx(1.0, abs=1e-9)


def test_a_narrow_category_can_hold_the_estimate_yet_not_be_named() -> None:
    """An estimate of 24 µg/m³ lies in Moderate (20–25, the service's Fair), but with a
    spread of 0.4 in ln(1 + PM2.5) Poor (25–50) holds more of the mass (0.42 against Fair's
    0.21 and Good's 0.31, by the normal's table): Poor is named, at its level nearest the
    estimate (4), and the reading is likely, not sure."""
    r = public.public(public.Predictive(float(np.log1p(24.0)), 0.4, BIG, "pm25", "eu_eaqi"))
    assert r.category == "Poor"
    assert r.probabilities["Poor"] == pytest.approx(0.42, abs=0.01)
    assert r.probabilities["Fair"] == pytest.approx(0.21, abs=0.01)
    assert r.level == 4
    assert r.uncertain
    assert r.value == pytest.approx(24.0)
    assert r.low < r.value < r.high
    assert r.poor == pytest.approx(r.probabilities["Poor"] + r.probabilities["Very Poor"])


def test_smoothing_weighs_hours_and_shares_errors() -> None:
    """Two frames in the last hour and one three hours before, equal estimates: the mean is
    theirs; with their errors all shared the scale is the weighted mean of scales, with
    none shared √Σωᵢ²sᵢ² (ω: each hour's NowCast weight, w = 1 for steady air, split among
    its frames)."""
    shape = public.Shape(BIG, "pm25", "eu_eaqi", shared=1.0)
    loc = float(np.log1p(12.0))
    reads = [
        public.Read(T - timedelta(minutes=10), loc, 0.2),
        public.Read(T - timedelta(minutes=40), loc, 0.4),
        public.Read(T - timedelta(hours=3, minutes=30), loc, 0.6),
    ]
    all_shared = public.smooth(reads, T, shape)
    assert all_shared is not None
    omega = np.array([0.25, 0.25, 0.5])  # hour 0 weighs 1/2, split by two; hour 3 the rest
    scales = np.array([0.2, 0.4, 0.6])
    assert all_shared.loc == pytest.approx(loc)
    assert all_shared.scale == pytest.approx(omega @ scales)
    own = public.smooth(reads, T, public.Shape(BIG, "pm25", "eu_eaqi", shared=0.0))
    assert own is not None
    assert own.scale == pytest.approx(np.sqrt(omega**2 @ scales**2))
    assert public.smooth(reads[2:], T, shape) is None  # nothing in the last 3 hours
    one = public.smooth(reads[:1], T, shape)
    assert one is not None
    assert (one.loc, one.scale) == pytest.approx((loc, 0.2))


def test_alerts_raise_and_clear_with_hysteresis() -> None:
    raise_at, clear_at = public.ALERT_RAISE, public.ALERT_CLEAR
    assert public.alert_kind(raise_at, [], False) == "raised"  # a camera's first
    assert public.alert_kind(raise_at, [clear_at], False) == "raised"  # from clear air
    # back from the dead band after an alert was cleared: the same episode's hovering
    assert public.alert_kind(raise_at, [(raise_at + clear_at) / 2, raise_at], False) is None
    assert public.alert_kind(0.9, [], True) is None  # an open episode: no second alert
    assert public.alert_kind(clear_at, [0.9], True) == "cleared"
    assert public.alert_kind((raise_at + clear_at) / 2, [0.9], True) is None
