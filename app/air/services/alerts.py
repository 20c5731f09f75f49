"""Air-quality alerts: when a camera's smoothed level raises or clears one, and the listing."""

from __future__ import annotations

import uuid
from collections.abc import Sequence
from datetime import datetime, timedelta

from sqlalchemy import (
    Row,
    and_,
    or_,
    select,
)
from sqlalchemy.orm import Session

from app.air.core import airquality, public
from app.air.models import AirAlert, SkyVerdict
from app.air.services.cameras import sky_cameras
from app.platform.db.models import Frame


def alert_row(
    camera_id: str,
    frame_id: str,
    at: datetime,
    kind: str,
    level: float,
    category: str,
    *,
    probability: float | None = None,
) -> AirAlert:
    return AirAlert(
        probability=probability,
        id=str(uuid.uuid4()),
        camera_id=camera_id,
        frame_id=frame_id,
        created_at=at,
        kind=kind,
        smoothed_level=level,
        category=category,
        delivered=False,
        attempts=0,
    )


def public_level_changed(
    session: Session,
    camera_id: str,
    reading_id: str,
    level: float,
    at: datetime,
    *,
    poor: float | None = None,
) -> list[AirAlert]:
    """The alert called for when a camera's public level (its newest reading's smoothed level)
    becomes ``level`` through a reading taken before it that arrived after it (a backlog sent
    newest first): raised when the level is in an alert category that no open episode has
    raised yet (as bad or worse), cleared when it is back to ``CLEAR_LEVEL`` in an open one;
    by the smoothed probability of Poor or worse, ``poor``, when a regression grades it
    (``public.ALERT_RAISE``, ``public.ALERT_CLEAR``).
    The late reading's own hours are history and raise nothing; without this, a backlog sent
    newest first whose newest frame alone read Fair, the hours before it Poor, left the camera
    public Poor with no alert ever raised."""
    name = airquality.category(level)
    last = _last_alert(session, camera_id)
    episode = last if last is not None and last.kind == "raised" else None  # still open
    severity = airquality.ALERT_CATEGORIES.index
    if poor is not None:
        if poor >= public.ALERT_RAISE and episode is None:
            worse = name if name in airquality.ALERT_CATEGORIES else "Poor"
            return [alert_row(camera_id, reading_id, at, "raised", level, worse, probability=poor)]
        if poor <= public.ALERT_CLEAR and episode is not None:
            return [alert_row(camera_id, reading_id, at, "cleared", level, name, probability=poor)]
        return []
    if name in airquality.ALERT_CATEGORIES:
        if episode is not None and severity(episode.category) >= severity(name):
            return []
        kind = "raised"
    elif episode is not None and level >= airquality.CLEAR_LEVEL:
        kind = "cleared"
    else:
        return []
    return [alert_row(camera_id, reading_id, at, kind, level, name)]


def _last_alert(session: Session, camera_id: str) -> Row[str, str, datetime] | None:
    """The camera's last alert: its kind, category and when its frame was taken."""
    return session.execute(
        select(AirAlert.kind, AirAlert.category, Frame.captured_at)
        .join(Frame, Frame.id == AirAlert.frame_id)
        .where(AirAlert.camera_id == camera_id)
        .order_by(AirAlert.created_at.desc(), AirAlert.id.desc())
        .limit(1)
    ).first()


def in_episode(session: Session, frame: Frame) -> bool:
    """Whether the camera's last alert was raised and its episode still runs at ``frame``: no
    clear reading (at ``CLEAR_LEVEL``, or, with a probability of Poor or worse, at
    ``public.ALERT_CLEAR``) taken since, and a reading with a smoothed level in the
    ``NOWCAST_HOURS`` before it (a camera dark all night, or gone quiet, ends the episode: the
    next day's bad air is news again). Without the first test, alerts raised before cleared
    ones existed would each be cleared by the next clean frame, months after their air had
    cleared."""
    last = _last_alert(session, frame.camera_id)
    if last is None or last.kind != "raised":
        return False
    since = (
        select(Frame.id)
        .join(SkyVerdict, SkyVerdict.frame_id == Frame.id)
        .where(
            Frame.camera_id == frame.camera_id,
            Frame.captured_at > last.captured_at,
            Frame.captured_at < frame.captured_at,
        )
    )
    clear = session.scalar(
        since.where(
            or_(
                SkyVerdict.poor_probability <= public.ALERT_CLEAR,
                and_(
                    SkyVerdict.poor_probability.is_(None),
                    SkyVerdict.smoothed_level >= airquality.CLEAR_LEVEL,
                ),
            )
        ).limit(1)
    )
    if clear is not None:
        return False
    window = frame.captured_at - timedelta(hours=airquality.NOWCAST_HOURS)
    recent = session.scalar(
        select(Frame.id)
        .join(SkyVerdict, SkyVerdict.frame_id == Frame.id)
        .where(
            Frame.camera_id == frame.camera_id,
            Frame.captured_at >= max(window, last.captured_at),
            Frame.captured_at < frame.captured_at,
            SkyVerdict.smoothed_level.is_not(None),
        )
        .limit(1)
    )
    return recent is not None or last.captured_at >= window


def listing(
    session: Session,
    *,
    camera_ids: Sequence[str] | None,
    limit: int,
    offset: int,
    since: datetime | None = None,
    until: datetime | None = None,
    kind: str | None = None,
) -> Sequence[AirAlert]:
    """Alerts newest first, made in [``since``, ``until``); only ``kind`` ones when given; 404
    for ids in ``camera_ids`` that name no sky camera."""
    sky_cameras(session, camera_ids)
    q = select(AirAlert)
    if kind is not None:
        q = q.where(AirAlert.kind == kind)
    if camera_ids is not None:
        q = q.where(AirAlert.camera_id.in_(camera_ids))
    if since is not None:
        q = q.where(AirAlert.created_at >= since)
    if until is not None:
        q = q.where(AirAlert.created_at < until)
    return session.scalars(
        q.order_by(AirAlert.created_at.desc(), AirAlert.id).limit(limit).offset(offset)
    ).all()
