"""A panel's soiling trend: the line fitted to its verdicts' F over time, and when it will
cross the threshold that calls for cleaning (the farm board's forecast)."""

from __future__ import annotations

from dataclasses import dataclass
from datetime import datetime, timedelta

import numpy as np
from scipy import stats as sstats
from sqlalchemy import select
from sqlalchemy.orm import Session

from app.platform.db.models import Frame
from app.solar.models import (
    Baseline,
    CleaningTask,
    Panel,
    PanelVerdict,
)


@dataclass(frozen=True, slots=True)
class Trend:
    points: int
    slope_per_day: float | None
    """Theil–Sen slope of F against time [1/day]."""
    f_now: float | None
    """The fitted F at the time of the status [–]."""
    threshold: float | None
    crossing_at: datetime | None
    """When the fitted F reaches the threshold (None: flat or falling, or too few points, or
    too short a time)."""


MIN_TREND_POINTS = 3


MIN_TREND_SPAN = timedelta(hours=1)
"""Soiling builds up over days: a line through frames less than this far apart (a burst, a
camera's retries) is noise, and extrapolated it forecast crossings seconds away (a slope of
4·10⁷ a day from four frames posted back to back, within 0.3 s)."""


def soiling_trend(
    session: Session, panel: Panel, now: datetime, baseline: Baseline | None = None
) -> Trend:
    """F over time since the panel was last clean by decree (baseline or cleaning), and when
    its fitted line (Theil–Sen, robust to a few glare-struck frames) will cross the threshold.

    Of the verdicts of ``baseline`` (one view's), by default the panel's newest."""
    if baseline is None:
        if panel.baseline_id is None:
            return Trend(0, None, None, None, None)
        baseline = session.get(Baseline, panel.baseline_id)
        assert baseline is not None
    since = baseline.created_at
    last_clean = session.scalar(
        select(CleaningTask.closed_at)
        .where(CleaningTask.panel_id == panel.id, CleaningTask.outcome == "effective")
        .order_by(CleaningTask.closed_at.desc())
        .limit(1)
    )
    if last_clean is not None and last_clean > since:
        since = last_clean
    rows = session.execute(
        select(Frame.captured_at, PanelVerdict.f_stat)
        .join(PanelVerdict, PanelVerdict.frame_id == Frame.id)
        .where(
            PanelVerdict.panel_id == panel.id,
            PanelVerdict.baseline_id == baseline.id,
            PanelVerdict.f_stat.is_not(None),
            Frame.received_at >= since,
        )
        .order_by(Frame.captured_at)
    ).all()
    threshold = baseline.f_critical
    if len(rows) < MIN_TREND_POINTS:
        return Trend(len(rows), None, None, threshold, None)
    t0 = rows[0][0]
    if rows[-1][0] - t0 < MIN_TREND_SPAN:
        return Trend(len(rows), None, None, threshold, None)
    days = np.array([(r[0] - t0) / timedelta(days=1) for r in rows])
    f = np.array([r[1] for r in rows], dtype=np.float64)
    res = sstats.theilslopes(f, days)
    slope, intercept = float(res.slope), float(res.intercept)
    now_days = (now - t0) / timedelta(days=1)
    f_now = intercept + slope * now_days
    return Trend(
        len(rows), slope, f_now, threshold, crossing_at(t0, slope, intercept, threshold, now)
    )


FORECAST_HORIZON = timedelta(days=3650)
"""A crossing further ahead than this is no forecast (and a nearly flat line's would leave the
calendar)."""


def crossing_at(
    t0: datetime, slope: float, intercept: float, threshold: float, now: datetime
) -> datetime | None:
    """When the line ``intercept + slope · days since t0`` reaches ``threshold``: now if it
    already has, None if it falls, stays flat or gets there only after ``FORECAST_HORIZON``."""
    if not slope > 0:
        return None
    ahead = (threshold - intercept) / slope - (now - t0) / timedelta(days=1)
    if not ahead < FORECAST_HORIZON / timedelta(days=1):  # also NaN and inf
        return None
    return now + timedelta(days=max(ahead, 0.0))
