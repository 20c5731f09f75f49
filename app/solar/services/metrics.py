"""The farm in /metrics: panels by state and cleaning tasks by outcome, read from the database
when scraped (the same for every process: each worker would count only its own otherwise)."""

from __future__ import annotations

from collections.abc import Iterable

from prometheus_client.core import CounterMetricFamily, GaugeMetricFamily, Metric
from sqlalchemy import func, select
from sqlalchemy.orm import Session

from app.platform.timing import Timing
from app.solar.models import CleaningTask
from app.solar.services import panels


def collect(session: Session, timing: Timing) -> Iterable[Metric]:
    states = GaugeMetricFamily(
        "vantage_panels", "Panels in service, by state now.", labels=["state"]
    )
    for state, n in panels.state_counts(session, timing).items():
        states.add_metric([state.value], n)
    yield states
    tasks = CounterMetricFamily(
        "vantage_cleaning_tasks",
        "Cleaning tasks by outcome (open: not yet closed; effective, ineffective, "
        "not_needed, failed, panel_retired).",
        labels=["outcome"],
    )
    rows = session.execute(
        select(CleaningTask.outcome, func.count()).group_by(CleaningTask.outcome)
    ).all()
    for outcome, n in rows:
        tasks.add_metric([outcome or "open"], n)
    yield tasks
