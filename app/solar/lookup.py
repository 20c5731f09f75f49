"""A panel or robot by id, or 404: shared by the registry and the cleaning queue."""

from __future__ import annotations

from sqlalchemy.orm import Session

from app.platform.http.errors import NotFound
from app.solar.models import Panel, Robot


def get_panel(session: Session, panel_id: str) -> Panel:
    panel = session.get(Panel, panel_id)
    if panel is None:
        raise NotFound(f"no panel {panel_id!r}")
    return panel


def get_robot(session: Session, robot_id: str) -> Robot:
    robot = session.get(Robot, robot_id)
    if robot is None:
        raise NotFound(f"no robot {robot_id!r}")
    return robot
