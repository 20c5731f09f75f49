"""What the farm's operator is told through the solar webhook (``platform.outbox``, topic
``solar``): cleaning tasks opened, claimed, completed, failed; cleanings that proved effective
or ineffective; baselines too broad to judge."""

from __future__ import annotations

from datetime import datetime

from sqlalchemy.orm import Session

from app.platform import outbox
from app.solar.models import CleaningTask

TOPIC = "solar"

TYPES = (
    "task.opened",
    "task.claimed",
    "task.completed",
    "task.failed",
    "cleaning.effective",
    "cleaning.ineffective",
    "baseline.too_broad",
)


def task_event(session: Session, task: CleaningTask, type_: str, now: datetime) -> None:
    """One of the task's moments, with the task as it stands after it."""
    outbox.enqueue(
        session,
        TOPIC,
        type_,
        {
            "task_id": task.id,
            "panel_id": task.panel_id,
            "status": task.status.value,
            "outcome": task.outcome,
            "robot_id": task.robot_id,
            "attempts": task.attempts,
            "fail_reason": task.fail_reason,
        },
        now,
    )


def baseline_too_broad(
    session: Session, panel_id: str, baseline_id: str, detail: str, now: datetime
) -> None:
    outbox.enqueue(
        session,
        TOPIC,
        "baseline.too_broad",
        {"panel_id": panel_id, "baseline_id": baseline_id, "detail": detail},
        now,
    )
