"""Air-quality alerts (public listing; the admin's webhook test)."""

from __future__ import annotations

from datetime import timedelta
from typing import Annotated, Literal

from fastapi import APIRouter, Query, Request

from app.air.schemas import (
    AirAlertOut,
    WebhookTestOut,
)
from app.air.services import alerts as air_alerts
from app.air.services import webhook as alert_webhook
from app.platform import webhooks
from app.platform.http.deps import (
    Admin,
    IdsFilter,
    Limit,
    Offset,
    OptionalPrincipal,
    SessionDep,
    SettingsDep,
    TimeRangeQuery,
    TimingDep,
)
from app.platform.http.errors import (
    Conflict,
)
from app.platform.http.responses import (
    AUTH_ERRORS,
    NOT_FOUND,
    UNPROCESSABLE,
)
from app.platform.state import app_state

router = APIRouter(prefix="/air", tags=["air quality"])


@router.post(
    "/alerts/test",
    response_model=WebhookTestOut,
    responses={**AUTH_ERRORS, 409: {"description": "No webhook is configured."}},
)
def try_alert_webhook(
    request: Request, settings: SettingsDep, timing: TimingDep, _: Admin
) -> WebhookTestOut:
    """POST a test alert (``kind: "test"``, recorded nowhere) to ``VANTAGE_ALERT_WEBHOOK_URL``
    now, signed as every alert is, and say whether the receiver took it (a 2xx) or why not: a
    receiver and its signing secret can be checked before the air turns Poor."""
    if settings.alert_webhook_url is None:
        raise Conflict("no webhook is configured: set VANTAGE_ALERT_WEBHOOK_URL", code="no_webhook")
    key = app_state(request).webhook_key
    msg_id, error = webhooks.send_test(settings.alert_webhook_url, timing.now(), key=key)
    return WebhookTestOut(
        webhook_id=msg_id, delivered=error is None, error=error, signed=key is not None
    )


@router.get(
    "/alerts",
    response_model=list[AirAlertOut],
    responses={**NOT_FOUND, **UNPROCESSABLE, 401: AUTH_ERRORS[401]},
)
def alerts(
    session: SessionDep,
    settings: SettingsDep,
    timing: TimingDep,
    span: TimeRangeQuery,
    caller: OptionalPrincipal,
    camera_id: IdsFilter = None,
    kind: Annotated[
        Literal["raised", "cleared"] | None, Query(description="Only alerts of this kind.")
    ] = None,
    limit: Limit = 100,
    offset: Offset = 0,
) -> list[AirAlertOut]:
    """Alerts, newest first, made in [``since``, ``until``): ``raised`` when a camera's smoothed
    level entered Poor or Very Poor, ``cleared`` when, after that, it came back to 5.0 or
    better; with where each one's webhook delivery stands. Why the last delivery failed
    (``last_error``: the receiver's answer, a redirect's address) is the operator's to read:
    null without the admin token."""
    operator = caller is not None and caller.role == "admin"
    rows = air_alerts.listing(
        session,
        camera_ids=camera_id,
        limit=limit,
        offset=offset,
        since=span.since,
        until=span.until,
        kind=kind,
    )
    now = timing.now()
    retry_for = timedelta(hours=settings.alert_retry_hours) if settings.alert_webhook_url else None
    return [
        AirAlertOut(
            id=a.id,
            camera_id=a.camera_id,
            frame_id=a.frame_id,
            created_at=a.created_at,
            kind=a.kind,
            smoothed_level=a.smoothed_level,
            category=a.category,
            probability=a.probability,
            delivered=a.delivered,
            attempts=a.attempts,
            delivery=alert_webhook.delivery(a, now, retry_for=retry_for),
            last_error=a.last_error if operator else None,
            next_attempt_at=a.next_attempt_at,
        )
        for a in rows
    ]
