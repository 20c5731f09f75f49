"""Cleaning robots."""

from __future__ import annotations

from fastapi import APIRouter

from app.deps import Admin, Limit, Offset, SessionDep
from app.routers.responses import AUTH_ERRORS, CONFLICT, UNPROCESSABLE
from app.schemas import RobotCreate, RobotCreated, RobotOut
from app.services import registry

router = APIRouter(tags=["robots"])


@router.post(
    "/robots",
    status_code=201,
    response_model=RobotCreated,
    responses={**AUTH_ERRORS, **CONFLICT, **UNPROCESSABLE},
)
def create_robot(body: RobotCreate, session: SessionDep, _: Admin) -> RobotCreated:
    """Register a cleaning robot; the response carries its token, shown only this once."""
    robot, token = registry.create_robot(session, body)
    return RobotCreated(**RobotOut.model_validate(robot).model_dump(), token=token)


@router.get("/robots", response_model=list[RobotOut], responses=AUTH_ERRORS)
def list_robots(
    session: SessionDep,
    _: Admin,
    limit: Limit = 100,
    offset: Offset = 0,
) -> list[RobotOut]:
    """List robots, ordered by id."""
    return [
        RobotOut.model_validate(r)
        for r in registry.list_robots(session, limit=limit, offset=offset)
    ]
