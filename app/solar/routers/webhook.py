"""The farm operator's webhook: where task and baseline events go, and what became of them."""

from __future__ import annotations

from datetime import datetime
from typing import Annotated, Literal

from fastapi import APIRouter, Query
from fastapi.responses import Response
from pydantic import Field
from sqlalchemy import select

from app.platform import outbox
from app.platform.db.models import OutboxMessage, WebhookSubscription
from app.platform.http.deps import Admin, Limit, SessionDep, TimingDep
from app.platform.http.errors import NotFound, Unprocessable
from app.platform.http.responses import AUTH_ERRORS, NOT_FOUND, UNPROCESSABLE
from app.platform.schemas import Out, Schema
from app.solar.services.events import TOPIC, TYPES

router = APIRouter(prefix="/solar", tags=["panels"])


class WebhookIn(Schema):
    url: str = Field(max_length=2000, description="http(s) URL that receives the events.")
    secret: str | None = Field(
        default=None,
        max_length=200,
        description="Standard Webhooks signing secret, whsec_ and the base64 of 24–64 random "
        "bytes; without one the events go unsigned.",
    )


class WebhookOut(Out):
    url: str
    signed: bool
    updated_at: datetime
    types: list[str] = Field(description="The events sent.")


class EventOut(Out):
    id: str = Field(description="The webhook-id of every attempt.")
    type: str
    created_at: datetime
    data: dict[str, object]
    delivered: bool
    attempts: int
    last_error: str | None


def _out(row: WebhookSubscription) -> WebhookOut:
    return WebhookOut(
        url=row.url, signed=row.secret is not None, updated_at=row.updated_at, types=list(TYPES)
    )


@router.put("/webhook", response_model=WebhookOut, responses={**AUTH_ERRORS, **UNPROCESSABLE})
def set_webhook(body: WebhookIn, session: SessionDep, timing: TimingDep, _: Admin) -> WebhookOut:
    """Send the farm's events (tasks opened, claimed, completed, failed; cleanings effective
    or ineffective; baselines too broad) to ``url`` as Standard Webhooks, retried with backoff
    for 24 h. Events kept while no receiver was set are sent too, if not older than that."""
    try:
        row = outbox.subscribe(session, TOPIC, body.url, body.secret, timing.now())
    except ValueError as exc:
        raise Unprocessable(str(exc), code="bad_webhook") from None
    return _out(row)


@router.get("/webhook", response_model=WebhookOut, responses={**AUTH_ERRORS, **NOT_FOUND})
def get_webhook(session: SessionDep, _: Admin) -> WebhookOut:
    row = session.get(WebhookSubscription, TOPIC)
    if row is None:
        raise NotFound("no solar webhook is set")
    return _out(row)


@router.delete("/webhook", status_code=204, responses={**AUTH_ERRORS, **NOT_FOUND})
def delete_webhook(session: SessionDep, _: Admin) -> Response:
    """Stop sending; events go on being kept (for a receiver set within 24 h)."""
    row = session.get(WebhookSubscription, TOPIC)
    if row is None:
        raise NotFound("no solar webhook is set")
    session.delete(row)
    return Response(status_code=204)


@router.get("/events", response_model=list[EventOut], responses={**AUTH_ERRORS})
def list_events(
    session: SessionDep,
    _: Admin,
    limit: Limit = 100,
    delivered: Annotated[bool | None, Query(description="Only those delivered, or not.")] = None,
    type: Annotated[Literal[TYPES] | None, Query(description="Only of this type.")] = None,  # type: ignore[valid-type]
) -> list[EventOut]:
    """The farm's events, newest first, with their delivery."""
    query = select(OutboxMessage).where(OutboxMessage.topic == TOPIC)
    if delivered is not None:
        query = query.where(OutboxMessage.delivered.is_(delivered))
    if type is not None:
        query = query.where(OutboxMessage.type == type)
    rows = session.scalars(
        query.order_by(OutboxMessage.created_at.desc(), OutboxMessage.id.desc()).limit(limit)
    ).all()
    return [
        EventOut(
            id=r.id,
            type=r.type,
            created_at=r.created_at,
            data=r.payload.get("data", {}),
            delivered=r.delivered,
            attempts=r.attempts,
            last_error=r.last_error,
        )
        for r in rows
    ]
