"""Delivering air-quality alerts to a webhook, with retries and exponential backoff.

A sweep takes undelivered alerts (``FOR UPDATE SKIP LOCKED``: several processes never send one
twice at once), POSTs each as JSON, and records the outcome; a failure is retried after
2, 4, 8 … seconds, up to ``MAX_ATTEMPTS``. Alerts live in the database, so a restart loses none.
"""

from __future__ import annotations

import asyncio
import json
import logging
import threading
import urllib.error
import urllib.request
from datetime import timedelta
from functools import partial

from sqlalchemy import or_, select
from sqlalchemy.orm import Session, sessionmaker

from app.db.models import AirAlert
from app.services.background import in_thread
from app.services.policy import Policy

log = logging.getLogger("vantage.webhooks")

MAX_ATTEMPTS = 6
TIMEOUT_S = 5.0


def _post(url: str, body: dict[str, object]) -> None:
    request = urllib.request.Request(
        url,
        data=json.dumps(body).encode(),
        headers={"Content-Type": "application/json", "User-Agent": "vantage-alerts"},
        method="POST",
    )
    with urllib.request.urlopen(request, timeout=TIMEOUT_S) as response:  # noqa: S310
        if not 200 <= response.status < 300:
            raise urllib.error.HTTPError(url, response.status, "not 2xx", response.headers, None)


def sweep(
    sessions: sessionmaker[Session],
    url: str,
    policy: Policy,
    *,
    batch: int = 20,
    stopping: threading.Event | None = None,
) -> int:
    """Try every due alert once; returns how many were delivered. Once ``stopping`` is set (a
    shutdown waiting for this sweep), the alerts not yet tried are left for the next one."""
    now = policy.now()
    delivered = 0
    with sessions() as session:
        alerts = session.scalars(
            select(AirAlert)
            .where(
                AirAlert.delivered.is_(False),
                AirAlert.attempts < MAX_ATTEMPTS,
                or_(AirAlert.next_attempt_at.is_(None), AirAlert.next_attempt_at <= now),
            )
            .order_by(AirAlert.created_at)
            .limit(batch)
            .with_for_update(skip_locked=True)
        ).all()
        for alert in alerts:
            if stopping is not None and stopping.is_set():
                break
            body = {
                "alert_id": alert.id,
                "camera_id": alert.camera_id,
                "frame_id": alert.frame_id,
                "created_at": alert.created_at.isoformat(),
                "smoothed_level": alert.smoothed_level,
                "category": alert.category,
                "message": f"Today's Air Quality is {alert.category}",
            }
            alert.attempts += 1
            try:
                _post(url, body)
            except (OSError, urllib.error.URLError) as exc:
                alert.last_error = str(exc)[:500]
                alert.next_attempt_at = now + timedelta(seconds=2**alert.attempts)
                log.warning(
                    "alert %s not delivered (attempt %d): %s", alert.id, alert.attempts, exc
                )
            else:
                alert.delivered = True
                alert.last_error = None
                delivered += 1
        session.commit()
    return delivered


async def run(sessions: sessionmaker[Session], url: str, policy: Policy, every: float) -> None:
    """Sweep forever (until cancelled), in a worker thread so the event loop stays free."""
    stopping = threading.Event()  # a shutdown waits for the post under way, not for all
    while True:
        try:
            await in_thread(
                partial(sweep, sessions, url, policy, stopping=stopping), on_cancel=stopping.set
            )
        except Exception:
            log.exception("webhook sweep failed")
        await asyncio.sleep(every)
