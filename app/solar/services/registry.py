"""Registering panels and robots."""

from __future__ import annotations

from sqlalchemy import select
from sqlalchemy.orm import Session

from app.platform.auth import hash_token, new_token
from app.platform.db.models import Camera
from app.platform.frames.cameras import check_in_service, check_located, insert_new, retire_row
from app.platform.http.errors import Conflict
from app.platform.timing import Timing
from app.solar.models import Panel, Robot, TaskStatus
from app.solar.schemas import PanelCreate, PanelUpdate, RobotCreate
from app.solar.services import cleaning, panels
from app.solar.services.lookup import get_panel, get_robot


def create_panel(session: Session, data: PanelCreate) -> Panel:
    panel = Panel(**data.model_dump())
    check_located(panel)
    insert_new(session, panel, "panel")
    return panel


def panel_in_service(session: Session, panel_id: str) -> Panel:
    """The panel (404 when there is none), refused (409) when retired."""
    panel = get_panel(session, panel_id)
    check_in_service(panel)
    return panel


def update_panel(session: Session, panel_id: str, data: PanelUpdate) -> Panel:
    """Change the fields ``data`` carries (``null`` clears one)."""
    panel = panel_in_service(session, panel_id)
    for field, value in data.model_dump(include=data.model_fields_set).items():
        setattr(panel, field, value)
    check_located(panel)
    session.flush()
    return panel


def retire_panel(session: Session, panel_id: str, timing: Timing) -> None:
    """Take a panel out of service (removed from the farm): its open cleaning task is cancelled
    (a robot holding it can neither complete nor fail it), and it leaves the default panel
    list. Its history stays and its id stays taken. Refused (409 ``panel_in_use``) while
    cameras in service watch it: move them (PATCH ``panel_id``) or retire them first, or their
    frames would go on judging a panel nobody cleans. Retiring it again changes nothing."""
    panel = panels.lock_panel(session, panel_id)
    if panel.retired_at is not None:
        return
    watching = session.scalars(
        select(Camera.id)
        .where(Camera.panel_id == panel_id, Camera.retired_at.is_(None))
        .order_by(Camera.id)
    ).all()
    if watching:
        raise Conflict(
            f"cameras in service watch panel {panel_id!r}: {', '.join(watching[:20])}"
            f"{' …' if len(watching) > 20 else ''}; move them to another panel (PATCH "
            "/cameras/{id} with panel_id) or retire them first",
            code="panel_in_use",
        )
    now = timing.now()
    task = panels.open_task(session, panel_id, lock=True)
    if task is not None:
        panels.close_task(task, TaskStatus.cancelled, "panel_retired", now)
    panel.retired_at = now
    session.flush()


def create_robot(session: Session, data: RobotCreate) -> tuple[Robot, str]:
    token = new_token("vr")
    robot = Robot(**data.model_dump(), token_hash=hash_token(token))
    insert_new(session, robot, "robot")
    return robot, token


def rotate_robot_token(session: Session, robot_id: str) -> tuple[Robot, str]:
    """A new token for the robot; the old one stops working at once (robot tokens are looked up
    on every request, in every process). Returns the robot and the new token (shown once)."""
    robot = get_robot(session, robot_id)
    check_in_service(robot)
    token = new_token("vr")
    robot.token_hash = hash_token(token)
    session.flush()
    return robot, token


def retire_robot(session: Session, robot_id: str, timing: Timing) -> None:
    """Take the robot out of service: its token stops working, and the tasks it holds go back
    to the queue for the other robots. Its history stays. Retiring it again changes nothing."""
    if retire_row(get_robot(session, robot_id), "vr", timing):
        cleaning.release_all(session, robot_id, timing)
        session.flush()
