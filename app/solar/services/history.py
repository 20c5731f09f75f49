"""A panel's soiling history: its verdicts summed by hour or day, for the farm board's trends."""

from __future__ import annotations

from datetime import UTC, datetime, timedelta
from typing import Any, Literal

from sqlalchemy import case, func, literal_column, select
from sqlalchemy.orm import Session

from app.platform.db.base import time_slot
from app.platform.db.models import Frame
from app.solar.models import PanelVerdict
from app.solar.services.lookup import get_panel

BUCKETS = {"hour": 3600, "day": 86400}


def history(
    session: Session,
    panel_id: str,
    *,
    since: datetime | None,
    until: datetime | None,
    bucket: Literal["hour", "day"],
) -> list[dict[str, Any]]:
    """The panel's verdicts of frames taken in [since, until) by UTC hour or day, oldest
    first: how many, judged clean, judged dirty, not judged (no verdict: night, glare, snow, no
    model), the mean and largest T² and the smallest p-value of those judged by the baseline
    (eqs. 5.19–5.21), the mean p_dirty of those judged by the fleet model. Summed by the
    database: one row per bucket reaches Python. 404 for an unknown panel."""
    get_panel(session, panel_id)
    length = BUCKETS[bucket]
    key = time_slot(Frame.captured_at, literal_column(str(length)), literal_column("0"))
    slot = key.label("slot")
    q = (
        select(
            slot,
            func.count(),
            func.sum(case((PanelVerdict.clean.is_(True), 1), else_=0)),
            func.sum(case((PanelVerdict.clean.is_(False), 1), else_=0)),
            func.avg(PanelVerdict.t2),
            func.max(PanelVerdict.t2),
            func.min(PanelVerdict.p_value),
            func.avg(PanelVerdict.p_dirty),
        )
        .join(Frame, Frame.id == PanelVerdict.frame_id)
        .where(PanelVerdict.panel_id == panel_id)
        .group_by(slot)
        .order_by(slot)
    )
    if since is not None:
        q = q.where(Frame.captured_at >= since)
    if until is not None:
        q = q.where(Frame.captured_at < until)
    out = []
    for index, n, clean, dirty, t2_mean, t2_max, p_min, p_dirty in session.execute(q):
        start = datetime.fromtimestamp(int(index) * length, UTC)
        out.append(
            {
                "start": start,
                "end": start + timedelta(seconds=length),
                "frames": int(n),
                "clean": int(clean or 0),
                "dirty": int(dirty or 0),
                "not_judged": int(n) - int(clean or 0) - int(dirty or 0),
                "t2_mean": None if t2_mean is None else float(t2_mean),
                "t2_max": None if t2_max is None else float(t2_max),
                "p_value_min": None if p_min is None else float(p_min),
                "p_dirty_mean": None if p_dirty is None else float(p_dirty),
            }
        )
    return out
