"""The sky cameras as the air services look them up, and which of their readings count."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from sqlalchemy import (
    ColumnElement,
    Select,
    select,
)
from sqlalchemy.orm import Session

from app.air.models import SkyVerdict
from app.platform.db.models import Camera, CameraKind, Frame
from app.platform.http.errors import (
    NotFound,
)


def sky_camera(session: Session, camera_id: str) -> Camera:
    camera = session.get(Camera, camera_id)
    if camera is None or camera.kind != CameraKind.sky:
        raise NotFound(f"no sky camera {camera_id!r}")
    return camera


def sky_cameras(session: Session, camera_ids: Sequence[str] | None) -> None:
    """Refuse (404) ids that name no sky camera, all of them in one answer: a misspelt id is
    an error, not a camera with no readings."""
    if not camera_ids:
        return
    known = set(
        session.scalars(
            select(Camera.id).where(Camera.id.in_(camera_ids), Camera.kind == CameraKind.sky)
        )
    )
    unknown = sorted(set(camera_ids) - known)
    if unknown:
        raise NotFound(f"no sky camera {', '.join(map(repr, unknown))}", unknown=unknown)


def graded_cameras(applies_to: Sequence[str]) -> Select[Camera]:
    """The sky cameras in service a calibration grades: ``applies_to``, or, for a city-wide
    one, every one."""
    query = select(Camera).where(Camera.kind == CameraKind.sky, Camera.retired_at.is_(None))
    return query.where(Camera.id.in_(sorted(set(applies_to)))) if applies_to else query


@dataclass(frozen=True, slots=True)
class Place:
    """A sky camera as the public sees it: its id, name and position."""

    camera_id: str
    name: str | None
    lat: float | None
    lon: float | None


Reading = tuple[Frame, SkyVerdict]


TRUSTED = SkyVerdict.level.is_not(None)
"""A reading whose level counts: graded (a frame outside its calibration has no level). A
reading the regression is unsure of counts with its probability: doubt is said, not
silenced."""


def trusted(level: int | None) -> bool:
    """``TRUSTED`` for a row already read."""
    return level is not None


def with_verdicts(which: ColumnElement[bool]) -> Select[Frame, SkyVerdict]:
    return select(Frame, SkyVerdict).join(SkyVerdict, SkyVerdict.frame_id == Frame.id).where(which)
