"""When a panel's fitted F line crosses its threshold (``trends.crossing_at``)."""

from __future__ import annotations

from datetime import UTC, datetime, timedelta

import pytest

from app.solar.services.trends import FORECAST_HORIZON, crossing_at

T0 = datetime(2026, 6, 1, tzinfo=UTC)
NOW = T0 + timedelta(days=2)


def test_a_rising_line_crosses_where_it_reaches_the_threshold() -> None:
    # 0 + 0.5 · d = 10 at d = 20
    assert crossing_at(T0, 0.5, 0.0, 10.0, NOW) == T0 + timedelta(days=20)


def test_a_line_already_above_the_threshold_crosses_now() -> None:
    assert crossing_at(T0, 0.5, 20.0, 10.0, NOW) == NOW


@pytest.mark.parametrize("slope", [0.0, -0.5, float("nan")])
def test_a_flat_or_falling_line_never_crosses(slope: float) -> None:
    assert crossing_at(T0, slope, 0.0, 10.0, NOW) is None


@pytest.mark.parametrize("slope", [1e-12, 5e-324])
def test_a_nearly_flat_line_is_no_forecast(slope: float) -> None:
    # its crossing lies millions of years ahead: past the horizon, and past datetime's range
    # (computing it raised OverflowError: a 500 on the panel's status)
    assert crossing_at(T0, slope, 0.0, 10.0, NOW) is None


def test_the_horizon() -> None:
    days = FORECAST_HORIZON / timedelta(days=1)
    slope = 10.0 / (2 + days - 1)  # crosses a day inside the horizon
    assert crossing_at(T0, slope, 0.0, 10.0, NOW) is not None
    slope = 10.0 / (2 + days + 1)  # a day past it
    assert crossing_at(T0, slope, 0.0, 10.0, NOW) is None
