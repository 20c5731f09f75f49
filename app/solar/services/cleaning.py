"""Cleaning tasks: each goes to exactly one robot, under a lease.

Claims and reports touch only the task row; the panel's state is derived from it. On
PostgreSQL the next task is taken with ``SELECT … FOR UPDATE SKIP LOCKED``, so robots claiming at
once through several server processes each lock a different row; on SQLite every write
transaction takes the database's write lock first (``BEGIN IMMEDIATE``).
"""

from __future__ import annotations

from collections.abc import Sequence
from datetime import datetime

from sqlalchemy import ColumnElement, and_, or_, select
from sqlalchemy.orm import Session

from app.platform.http.errors import Conflict
from app.platform.lookup import get_or_404
from app.platform.timing import Timing
from app.solar.core.panel_state import TaskPhase, task_phase
from app.solar.models import OPEN_TASK_STATUSES, CleaningTask, TaskStatus
from app.solar.services import events
from app.solar.services.lookup import get_panel, get_robot


def _claimable(now: datetime) -> ColumnElement[bool]:
    return or_(
        CleaningTask.status == TaskStatus.pending,
        and_(CleaningTask.status == TaskStatus.claimed, CleaningTask.lease_expires_at <= now),
    )


def _grant(session: Session, task: CleaningTask, robot_id: str, timing: Timing) -> CleaningTask:
    now = timing.now()
    task.status = TaskStatus.claimed
    task.robot_id = robot_id
    task.claimed_at = now
    task.lease_expires_at = now + timing.lease
    task.attempts += 1
    events.task_event(session, task, "task.claimed", now)
    return task


def claim_next(session: Session, robot_id: str, timing: Timing) -> CleaningTask | None:
    """Give the oldest claimable task (pending, or its lease expired) to ``robot_id``."""
    now = timing.now()
    task = session.scalars(
        select(CleaningTask)
        .where(_claimable(now))
        .order_by(CleaningTask.created_at, CleaningTask.id)
        .limit(1)
        .with_for_update(skip_locked=True)
    ).first()
    return _grant(session, task, robot_id, timing) if task is not None else None


def _locked(session: Session, task_id: str) -> CleaningTask:
    return get_or_404(session, CleaningTask, task_id, "cleaning task", lock=True)


def claim(session: Session, task_id: str, robot_id: str, timing: Timing) -> CleaningTask:
    """Claim a given task. Claiming one's own claimed task again renews the lease."""
    task = _locked(session, task_id)
    phase = task_phase(task.status, task.lease_expires_at, timing.now())
    if phase is TaskPhase.pending or (phase is TaskPhase.claimed and task.robot_id == robot_id):
        return _grant(session, task, robot_id, timing)
    if phase is TaskPhase.claimed:
        raise Conflict(f"task {task_id} is claimed by another robot", code="claimed_by_other")
    raise Conflict(f"task {task_id} is {task.status.value}; it cannot be claimed", code="closed")


def complete(session: Session, task_id: str, robot_id: str, timing: Timing) -> CleaningTask:
    """The robot has cleaned the panel. Idempotent for the robot that did it.

    A robot whose lease ran out may still complete the task unless another robot has claimed it
    since. The panel's next usable verdict then confirms the cleaning (``panel_state``).
    """
    task = _locked(session, task_id)
    if task.robot_id != robot_id:
        raise Conflict(f"task {task_id} is not this robot's", code="not_yours")
    if task.status is TaskStatus.completed or task.outcome in ("effective", "ineffective"):
        return task  # already completed by this robot (and perhaps confirmed since)
    if task.status is not TaskStatus.claimed:
        raise Conflict(f"task {task_id} is {task.status.value}; it cannot be completed")
    task.status = TaskStatus.completed
    task.completed_at = timing.now()
    task.lease_expires_at = None
    events.task_event(session, task, "task.completed", task.completed_at)
    return task


def fail(
    session: Session, task_id: str, robot_id: str, timing: Timing, reason: str | None
) -> CleaningTask:
    """The robot could not clean the panel: the task closes as failed. Idempotent.

    The panel stays ``needs_cleaning``; its next dirty verdict opens a new task.
    """
    task = _locked(session, task_id)
    if task.robot_id != robot_id:
        raise Conflict(f"task {task_id} is not this robot's", code="not_yours")
    if task.status is TaskStatus.failed:
        return task
    if task.status is not TaskStatus.claimed:
        raise Conflict(f"task {task_id} is {task.status.value}; it cannot fail now")
    task.status = TaskStatus.failed
    task.outcome = "failed"
    task.fail_reason = reason
    task.closed_at = timing.now()
    task.open_panel_id = None
    task.lease_expires_at = None
    events.task_event(session, task, "task.failed", task.closed_at)
    return task


def release_all(session: Session, robot_id: str, timing: Timing) -> int:
    """End the leases of the tasks the robot holds: they can be claimed by another robot at
    once (as when a lease runs out). Returns how many."""
    now = timing.now()
    held = session.scalars(
        select(CleaningTask)
        .where(
            CleaningTask.robot_id == robot_id,
            CleaningTask.status == TaskStatus.claimed,
            CleaningTask.lease_expires_at > now,
        )
        .with_for_update()
    ).all()
    for task in held:
        task.lease_expires_at = now
    return len(held)


def holds_task_on(session: Session, robot_id: str, panel_id: str, now: datetime) -> bool:
    """Whether the robot holds a task on the panel now (claimed, its lease running)."""
    held = session.scalar(
        select(CleaningTask.id)
        .where(
            CleaningTask.robot_id == robot_id,
            CleaningTask.panel_id == panel_id,
            CleaningTask.status == TaskStatus.claimed,
            CleaningTask.lease_expires_at > now,
        )
        .limit(1)
    )
    return held is not None


def get_task(session: Session, task_id: str) -> CleaningTask:
    return get_or_404(session, CleaningTask, task_id, "cleaning task")


def shown_as(status: str, now: datetime) -> ColumnElement[bool]:
    """Tasks whose status reads ``status`` at ``now`` (a claim whose lease ran out reads
    pending); ``open``: pending, claimed or completed awaiting confirmation."""
    if status == "pending":
        return _claimable(now)
    if status == "claimed":
        return and_(CleaningTask.status == TaskStatus.claimed, CleaningTask.lease_expires_at > now)
    if status == "open":
        return CleaningTask.status.in_(OPEN_TASK_STATUSES)
    return CleaningTask.status == TaskStatus(status)


def list_tasks(
    session: Session,
    *,
    panel_id: str | None,
    robot_id: str | None = None,
    statuses: Sequence[str] = (),
    now: datetime,
    limit: int,
    offset: int,
) -> Sequence[CleaningTask]:
    """Tasks newest first: a panel's, a robot's, of the statuses given (as they read at
    ``now``). An unknown panel or robot is 404: a mistyped id is not one without tasks."""
    if panel_id is not None:
        get_panel(session, panel_id)
    if robot_id is not None:
        get_robot(session, robot_id)
    q = select(CleaningTask)
    if panel_id is not None:
        q = q.where(CleaningTask.panel_id == panel_id)
    if robot_id is not None:
        q = q.where(CleaningTask.robot_id == robot_id)
    if statuses:
        q = q.where(or_(*(shown_as(s, now) for s in statuses)))
    return session.scalars(
        q.order_by(CleaningTask.created_at.desc(), CleaningTask.id).limit(limit).offset(offset)
    ).all()
