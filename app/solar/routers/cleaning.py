"""Cleaning robots: claim a task, then complete it or report failure."""

from __future__ import annotations

from typing import Annotated, Literal

from fastapi import APIRouter, Body, Query, Response
from sqlalchemy.orm import Session

from app.platform.http.deps import (
    AnyReader,
    IdFilter,
    Limit,
    Offset,
    RecordId,
    RobotAuth,
    SessionDep,
    TimingDep,
)
from app.platform.http.responses import AUTH_ERRORS, CONFLICT, NOT_FOUND
from app.solar.models import CleaningTask
from app.solar.schemas import ClaimOut, FailIn, PanelPlace, TaskOut
from app.solar.services import cleaning, lookup
from app.solar.services.panels import task_view

router = APIRouter(prefix="/cleaning", tags=["cleaning"])

TaskId = RecordId


@router.post(
    "/claim",
    response_model=ClaimOut,
    responses={204: {"description": "Nothing to clean"}, **AUTH_ERRORS},
)
def claim_next(session: SessionDep, timing: TimingDep, robot: RobotAuth) -> ClaimOut | Response:
    """Take the oldest waiting task, under a lease; 204 when there is none."""
    assert robot.id is not None
    task = cleaning.claim_next(session, robot.id, timing)
    if task is None:
        return Response(status_code=204)
    return _claimed(session, task)


@router.post(
    "/tasks/{task_id}/claim",
    response_model=ClaimOut,
    responses={**AUTH_ERRORS, **NOT_FOUND, **CONFLICT},
)
def claim(task_id: TaskId, session: SessionDep, timing: TimingDep, robot: RobotAuth) -> ClaimOut:
    """Claim this task (or renew one's own lease on it); 409 when another robot holds it."""
    assert robot.id is not None
    task = cleaning.claim(session, task_id, robot.id, timing)
    return _claimed(session, task)


def _claimed(session: Session, task: CleaningTask) -> ClaimOut:
    """A claimed task with where its panel is: the robot learns it with the claim."""
    assert task.lease_expires_at is not None
    panel = lookup.get_panel(session, task.panel_id)
    return ClaimOut(
        task_id=task.id,
        panel_id=task.panel_id,
        lease_expires_at=task.lease_expires_at,
        panel=PanelPlace.model_validate(panel),
    )


@router.post(
    "/tasks/{task_id}/complete",
    response_model=TaskOut,
    responses={**AUTH_ERRORS, **NOT_FOUND, **CONFLICT},
)
def complete(task_id: TaskId, session: SessionDep, timing: TimingDep, robot: RobotAuth) -> TaskOut:
    """The panel is cleaned; its next frames confirm it. Idempotent."""
    assert robot.id is not None
    task = cleaning.complete(session, task_id, robot.id, timing)
    return TaskOut(**task_view(task, timing.now()))


@router.post(
    "/tasks/{task_id}/fail",
    response_model=TaskOut,
    responses={**AUTH_ERRORS, **NOT_FOUND, **CONFLICT},
)
def fail(
    task_id: TaskId,
    session: SessionDep,
    timing: TimingDep,
    robot: RobotAuth,
    body: Annotated[FailIn | None, Body()] = None,
) -> TaskOut:
    """The robot could not clean the panel. Idempotent."""
    assert robot.id is not None
    reason = body.reason if body else None
    task = cleaning.fail(session, task_id, robot.id, timing, reason)
    return TaskOut(**task_view(task, timing.now()))


@router.get("/tasks", response_model=list[TaskOut], responses={**AUTH_ERRORS, **NOT_FOUND})
def list_tasks(
    session: SessionDep,
    timing: TimingDep,
    _: AnyReader,
    panel_id: IdFilter = None,
    robot_id: IdFilter = None,
    status: Annotated[
        list[Literal["open", "pending", "claimed", "completed", "closed", "failed", "cancelled"]],
        Query(
            description="Only tasks of these statuses, as they read now (a claim whose lease "
            "ran out is pending); open: pending, claimed or completed awaiting confirmation."
        ),
    ] = [],  # noqa: B006
    limit: Limit = 100,
    offset: Offset = 0,
) -> list[TaskOut]:
    """Cleaning tasks, newest first: a panel's, a robot's, of the statuses given."""
    now = timing.now()
    rows = cleaning.list_tasks(
        session,
        panel_id=panel_id,
        robot_id=robot_id,
        statuses=status,
        now=now,
        limit=limit,
        offset=offset,
    )
    return [TaskOut(**task_view(t, now)) for t in rows]


@router.get("/tasks/{task_id}", response_model=TaskOut, responses={**AUTH_ERRORS, **NOT_FOUND})
def get_task(task_id: TaskId, session: SessionDep, timing: TimingDep, _: AnyReader) -> TaskOut:
    """One cleaning task."""
    return TaskOut(**task_view(cleaning.get_task(session, task_id), timing.now()))
