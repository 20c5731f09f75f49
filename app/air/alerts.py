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

import asyncio
import json
import logging
import threading
from datetime import datetime, timedelta
from functools import partial
from typing import Literal

from sqlalchemy import or_, select
from sqlalchemy.orm import Session, sessionmaker

from app.air.core import airquality
from app.air.models import AirAlert
from app.platform import webhooks
from app.platform.background import in_thread
from app.platform.db.models import Camera, Frame
from app.platform.observability import ALERT_DELIVERIES
from app.platform.policy import Policy
from app.platform.webhooks import DeliveryFailed, backoff

log = logging.getLogger("vantage.webhooks")


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
    policy: Policy,
    *,
    retry_for: timedelta = DEFAULT_RETRY_FOR,
    batch: int = 20,
    stopping: threading.Event | None = None,
    key: bytes | None = None,
) -> int:
    """Try every due alert once (at most ``batch``); returns how many were delivered. Each
    alert is claimed, posted and recorded one at a time: a process that dies during a sweep
    sends again, once its claim has run out, at most the alert it was posting, not every one
    delivered before it in the sweep. Once ``stopping`` is set (a shutdown waiting for this
    sweep), the alerts not yet tried are left for the next one. ``key`` (``signing_key``) signs
    each POST.

    The POST holds no transaction: the alert is claimed first (taken ``FOR UPDATE SKIP
    LOCKED``, its attempt counted and its next attempt put ``CLAIM`` ahead, committed), so no
    other process sends it meanwhile, and its outcome is recorded after. Holding the
    transaction through the POST held a database connection for as long as the receiver took,
    up to ``TIMEOUT_S`` an alert: with SQLite, the one every request shares, a receiver that
    took connections and never answered held every request of the service 5 s per alert
    (GET /cameras waited 20 s behind 4 alerts)."""
    delivered = 0
    for _ in range(batch):
        if stopping is not None and stopping.is_set():
            break
        # the time of each attempt, not the sweep's start: a sweep of many alerts to a slow
        # receiver takes minutes, and a claim dated from its start would run out before it
        # was posted (another process would then send it too)
        now = policy.now()
        claimed = _claim(sessions, now, retry_for)
        if claimed is None:
            break
        alert_id, attempts, body = claimed
        try:
            webhooks.post(url, body, webhooks.signed_headers(alert_id, body, now, key))
        except DeliveryFailed as exc:
            error: str | None = str(exc)[:500]
            log.warning("alert %s not delivered (attempt %d): %s", alert_id, attempts, exc)
        else:
            error = None
            delivered += 1
        with sessions() as session:
            alert = session.get(AirAlert, alert_id)
            if alert is not None:  # not swept away by retention meanwhile
                alert.delivered = error is None
                alert.last_error = error
                alert.next_attempt_at = None if error is None else now + backoff(attempts)
                session.commit()
        ALERT_DELIVERIES.labels("failed" if error else "delivered").inc()  # once recorded
    return delivered


CLAIM = timedelta(minutes=2)
"""How long a claimed alert is left to the process posting it (well beyond ``TIMEOUT_S``); a
process that died posting it leaves it to be sent again after this."""


def _claim(
    sessions: sessionmaker[Session], now: datetime, retry_for: timedelta
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
    policy: Policy,
    every: float,
    retry_for: timedelta = DEFAULT_RETRY_FOR,
    key: bytes | None = None,
) -> None:
    """Sweep forever (until cancelled), in a worker thread so the event loop stays free."""
    stopping = threading.Event()  # a shutdown waits for the post under way, not for all
    while True:
        try:
            await in_thread(
                partial(
                    sweep, sessions, url, policy, retry_for=retry_for, stopping=stopping, key=key
                ),
                on_cancel=stopping.set,
            )
        except Exception:
            log.exception("webhook sweep failed")
        await asyncio.sleep(every)
