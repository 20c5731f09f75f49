"""Delivering air-quality alerts to a webhook, with retries and exponential backoff.

A sweep claims each due alert (``FOR UPDATE SKIP LOCKED``, then committed with its next attempt
put ahead: several processes never send one at once, and no transaction waits on the
receiver), POSTs it as JSON, and records the outcome; a failure is retried after
2, 4, 8 … seconds, at most ``RETRY_CAP`` apart, until the alert is ``retry_for`` old (24 h by
default: a receiver down for a deploy or a night still gets every alert). Alerts live in the
database, so a restart loses none.

Each POST carries the Standard Webhooks headers (https://www.standardwebhooks.com):
``webhook-id`` (the alert's id, the same on every attempt: a receiver drops a repeat by it),
``webhook-timestamp`` (the attempt's Unix time) and, with a signing secret,
``webhook-signature`` (``v1,`` and the base64 HMAC-SHA256 of ``id.timestamp.body``), so a
receiver can tell the service's alerts from anyone's who learnt its address, with any Standard
Webhooks library.

Only a 2xx answer to the POST itself is a delivery. A redirect is not followed: urllib would
follow a 301 or 302 with a GET without the alert, and a page answering that GET 200 would pass
for the receiver. Whatever else goes wrong with one alert (no answer, an answer that is not
HTTP, a truncated one) is that alert's failed attempt, never the sweep's: the outcomes of the
alerts already tried are kept.
"""

from __future__ import annotations

import json
import threading
from datetime import datetime, timedelta
from functools import partial
from typing import Literal

from sqlalchemy import or_, select
from sqlalchemy.orm import Session, sessionmaker

from app.air.core import airquality
from app.air.models import AirAlert
from app.platform import webhooks
from app.platform.db.models import Camera, Frame
from app.platform.observability import ALERT_DELIVERIES
from app.platform.timing import Timing

DEFAULT_RETRY_FOR = timedelta(hours=24)


Delivery = Literal["delivered", "pending", "gave_up", "no_webhook"]


def retried_since(now: datetime, retry_for: timedelta) -> datetime:
    """The one rule of how long an alert is tried: those created at or after this time still
    are (the sweep's query and the listing's ``delivery`` both read it here)."""
    return now - retry_for


def delivery(alert: AirAlert, now: datetime, *, retry_for: timedelta | None) -> Delivery:
    """Where an alert's delivery stands; ``retry_for`` None: no webhook is configured."""
    if alert.delivered:
        return "delivered"
    if retry_for is None:
        return "no_webhook"
    return "pending" if alert.created_at >= retried_since(now, retry_for) else "gave_up"


def sweep(
    sessions: sessionmaker[Session],
    url: str,
    timing: Timing,
    *,
    retry_for: timedelta = DEFAULT_RETRY_FOR,
    batch: int = 20,
    stopping: threading.Event | None = None,
    key: bytes | None = None,
) -> int:
    """Try every due alert once (at most ``batch``); returns how many were delivered
    (``webhooks.deliver_due``: claimed, posted with no transaction open, recorded, one at a
    time). ``key`` (``signing_key``) signs each POST."""
    return webhooks.deliver_due(
        sessions,
        AirAlert,
        partial(_claim, sessions, retry_for=retry_for),
        url,
        timing.now,
        key=key,
        batch=batch,
        stopping=stopping,
        outcome=lambda ok: ALERT_DELIVERIES.labels("delivered" if ok else "failed").inc(),
    )


CLAIM = timedelta(minutes=2)
"""How long a claimed alert is left to the process posting it (well beyond ``TIMEOUT_S``); a
process that died posting it leaves it to be sent again after this."""


def _claim(
    sessions: sessionmaker[Session], now: datetime, *, retry_for: timedelta
) -> tuple[str, int, bytes] | None:
    """The next due alert, claimed (committed): its id, its attempts with this one, and the
    JSON to POST; None when none is due."""
    with sessions() as session:
        alert = session.scalars(
            select(AirAlert)
            .where(
                AirAlert.delivered.is_(False),
                AirAlert.created_at >= retried_since(now, retry_for),
                or_(AirAlert.next_attempt_at.is_(None), AirAlert.next_attempt_at <= now),
            )
            .order_by(AirAlert.created_at)
            .limit(1)
            .with_for_update(skip_locked=True)
        ).first()
        if alert is None:
            return None
        camera = session.get(Camera, alert.camera_id)
        frame = session.get(Frame, alert.frame_id)
        body = json.dumps(
            {
                "alert_id": alert.id,
                "camera_id": alert.camera_id,
                "camera_name": camera.name if camera else None,
                "lat": camera.lat if camera else None,
                "lon": camera.lon if camera else None,
                "frame_id": alert.frame_id,
                "captured_at": frame.captured_at.isoformat() if frame else None,
                "created_at": alert.created_at.isoformat(),
                "kind": alert.kind,
                "smoothed_level": alert.smoothed_level,
                "category": alert.category,
                "probability": alert.probability,
                "message": airquality.message(alert.category),
            }
        ).encode()
        alert.attempts += 1
        alert.next_attempt_at = now + CLAIM
        claimed = (alert.id, alert.attempts, body)
        session.commit()
    return claimed


async def run(
    sessions: sessionmaker[Session],
    url: str,
    timing: Timing,
    every: float,
    retry_for: timedelta = DEFAULT_RETRY_FOR,
    key: bytes | None = None,
) -> None:
    """Sweep forever (until cancelled), in a worker thread so the event loop stays free."""
    await webhooks.keep_sweeping(
        lambda stopping: sweep(
            sessions, url, timing, retry_for=retry_for, stopping=stopping, key=key
        ),
        every,
        "air alerts",
    )
