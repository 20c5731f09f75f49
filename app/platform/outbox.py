"""Events for a topic's webhook, kept in the database until delivered (the outbox pattern).

A domain writes an event (``enqueue``) in the transaction that caused it; ``run`` sweeps each
topic's due events to the receiver set for it (``WebhookSubscription``: one URL and its
Standard Webhooks secret, changed through the API without a restart), one at a time: claimed
(``FOR UPDATE SKIP LOCKED``, its next attempt put ``CLAIM`` ahead, committed), POSTed with no
transaction open, its outcome recorded. A failure is retried after 2, 4, 8 … s (at most 10 min
apart) until the event is ``retry_for`` old. The body is Standard Webhooks' shape:
``{"type": …, "timestamp": …, "data": {…}}``; ``webhook-id`` is the event's id.
"""

from __future__ import annotations

import json
import threading
import uuid
from datetime import datetime, timedelta
from functools import partial
from typing import Any

from sqlalchemy import delete, or_, select
from sqlalchemy.orm import Session, sessionmaker

from app.platform import webhooks
from app.platform.db.models import OutboxMessage, WebhookSubscription
from app.platform.timing import Timing

RETRY_FOR = timedelta(hours=24)
"""How long an event is tried: a receiver down for a deploy or a night still gets it."""

KEEP_FOR = timedelta(days=30)
"""How long an event is listed after it was made, delivered or not."""

CLAIM = timedelta(minutes=2)
"""How long a claimed event is left to the process posting it."""


def enqueue(
    session: Session, topic: str, type_: str, data: dict[str, Any], now: datetime
) -> OutboxMessage:
    """Keep an event for the topic's webhook, in the caller's transaction."""
    message = OutboxMessage(
        id=f"msg_{uuid.uuid4().hex}",
        topic=topic,
        type=type_,
        created_at=now,
        payload={"type": type_, "timestamp": now.isoformat(), "data": data},
        delivered=False,
        attempts=0,
    )
    session.add(message)
    return message


def subscribe(
    session: Session, topic: str, url: str, secret: str | None, now: datetime
) -> WebhookSubscription:
    """Set (or replace) the topic's receiver. Raises ValueError for a bad URL or secret."""
    webhooks.check_url(url)
    if secret is not None:
        webhooks.signing_key(secret)
    row = session.get(WebhookSubscription, topic)
    if row is None:
        row = WebhookSubscription(topic=topic, url=url, secret=secret, updated_at=now)
        session.add(row)
    else:
        row.url, row.secret, row.updated_at = url, secret, now
    return row


def forget_old(sessions: sessionmaker[Session], now: datetime) -> int:
    """Delete the events older than ``KEEP_FOR``, of every topic (the retention sweep's,
    hourly); returns how many."""
    with sessions() as session:
        gone = session.execute(
            delete(OutboxMessage).where(OutboxMessage.created_at < now - KEEP_FOR)
        )
        session.commit()
    return int(getattr(gone, "rowcount", 0) or 0)


def sweep(
    sessions: sessionmaker[Session],
    topic: str,
    timing: Timing,
    *,
    retry_for: timedelta = RETRY_FOR,
    batch: int = 50,
    stopping: threading.Event | None = None,
) -> int:
    """Try every due event of ``topic`` once (at most ``batch``); returns how many were
    delivered. Nothing is tried while the topic has no receiver."""
    with sessions() as session:
        receiver = session.get(WebhookSubscription, topic)
        if receiver is None:
            return 0
        url, secret = receiver.url, receiver.secret
    key = webhooks.signing_key(secret) if secret else None
    return webhooks.deliver_due(
        sessions,
        OutboxMessage,
        partial(_claim, sessions, topic, retry_for=retry_for),
        url,
        timing.now,
        key=key,
        batch=batch,
        stopping=stopping,
    )


def _claim(
    sessions: sessionmaker[Session], topic: str, now: datetime, *, retry_for: timedelta
) -> tuple[str, int, bytes] | None:
    with sessions() as session:
        message = session.scalars(
            select(OutboxMessage)
            .where(
                OutboxMessage.topic == topic,
                OutboxMessage.delivered.is_(False),
                OutboxMessage.created_at >= now - retry_for,
                or_(OutboxMessage.next_attempt_at.is_(None), OutboxMessage.next_attempt_at <= now),
            )
            .order_by(OutboxMessage.created_at, OutboxMessage.id)
            .limit(1)
            .with_for_update(skip_locked=True)
        ).first()
        if message is None:
            return None
        message.attempts += 1
        message.next_attempt_at = now + CLAIM
        claimed = (message.id, message.attempts, json.dumps(message.payload).encode())
        session.commit()
    return claimed


async def run(sessions: sessionmaker[Session], topic: str, timing: Timing, every: float) -> None:
    """Sweep ``topic`` forever (until cancelled), in a worker thread."""
    await webhooks.keep_sweeping(
        lambda stopping: sweep(sessions, topic, timing, stopping=stopping), every, topic
    )
