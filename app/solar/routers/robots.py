"""Cleaning robots."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Query
from fastapi.responses import Response

from app.platform.frames import cameras
from app.platform.http.deps import Admin, Limit, Offset, RobotId, SessionDep, TimingDep
from app.platform.http.responses import (
    AUTH_ERRORS,
    CONFLICT,
    NOT_FOUND,
    ROBOT_RETIRED,
    UNPROCESSABLE,
)
from app.solar.models import Robot
from app.solar.schemas import RobotCreate, RobotCreated, RobotOut
from app.solar.services import lookup, registry

router = APIRouter(tags=["robots"])


def _with_token(robot: Robot, token: str) -> RobotCreated:
    """The robot as the API shows it, with its token (shown only this once)."""
    return RobotCreated(**RobotOut.model_validate(robot).model_dump(), token=token)


@router.post(
    "/robots",
    status_code=201,
    response_model=RobotCreated,
    responses={**AUTH_ERRORS, **CONFLICT, **UNPROCESSABLE},
)
def create_robot(body: RobotCreate, session: SessionDep, _: Admin) -> RobotCreated:
    """Register a cleaning robot; the response carries its token, shown only this once."""
    return _with_token(*registry.create_robot(session, body))


@router.get("/robots", response_model=list[RobotOut], responses=AUTH_ERRORS)
def list_robots(
    session: SessionDep,
    _: Admin,
    limit: Limit = 100,
    offset: Offset = 0,
    retired: Annotated[
        bool, Query(description="Include retired robots (by default only those in service).")
    ] = False,
) -> list[RobotOut]:
    """List robots, ordered by id."""
    robots = cameras.listed(session, Robot, limit=limit, offset=offset, retired=retired)
    return [RobotOut.model_validate(r) for r in robots]


@router.get("/robots/{robot_id}", response_model=RobotOut, responses={**AUTH_ERRORS, **NOT_FOUND})
def get_robot(robot_id: RobotId, session: SessionDep, _: Admin) -> RobotOut:
    """One robot, retired or not (its tasks: ``GET /cleaning/tasks?robot_id=``)."""
    return RobotOut.model_validate(lookup.get_robot(session, robot_id))


@router.post(
    "/robots/{robot_id}/token",
    response_model=RobotCreated,
    responses={**AUTH_ERRORS, **NOT_FOUND, **ROBOT_RETIRED},
)
def rotate_robot_token(robot_id: RobotId, session: SessionDep, _: Admin) -> RobotCreated:
    """Issue the robot a new token, shown only this once; the old one stops working at once,
    on every server process."""
    return _with_token(*registry.rotate_robot_token(session, robot_id))


@router.delete(
    "/robots/{robot_id}",
    status_code=204,
    response_class=Response,
    responses={**AUTH_ERRORS, **NOT_FOUND},
)
def retire_robot(robot_id: RobotId, session: SessionDep, timing: TimingDep, _: Admin) -> Response:
    """Retire a robot taken out of service. Its token stops working at once, and the tasks it
    holds go back to the queue: another robot can claim them now rather than when their lease
    runs out. Its tasks' history stays; its id stays taken. Retiring it again changes nothing."""
    registry.retire_robot(session, robot_id, timing)
    return Response(status_code=204)
