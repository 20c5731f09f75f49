"""A panel or robot by id, or 404: shared by the registry and the cleaning queue."""

from __future__ import annotations

from sqlalchemy.orm import Session

from app.platform.lookup import get_or_404
from app.solar.models import Panel, Robot


def get_panel(session: Session, panel_id: str) -> Panel:
    return get_or_404(session, Panel, panel_id, "panel")


def get_robot(session: Session, robot_id: str) -> Robot:
    return get_or_404(session, Robot, robot_id, "robot")
