"""Structured JSON logs with a request id, and Prometheus metrics."""

from __future__ import annotations

import contextvars
import json
import logging
import sys
import time
import uuid
from datetime import UTC, datetime
from typing import Any

from prometheus_client import Counter, Histogram
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from app.platform.routes import route_of

request_id_var: contextvars.ContextVar[str | None] = contextvars.ContextVar(
    "request_id", default=None
)

FRAMES_RECEIVED = Counter(
    "vantage_frames_received_total", "Frames stored, per camera.", ["camera_id"]
)
FRAMES_REJECTED = Counter(
    "vantage_frames_rejected_total",
    "Frames refused, per camera and reason.",
    ["camera_id", "reason"],
)
INGEST_SECONDS = Histogram(
    "vantage_ingest_seconds",
    "Frame ingest latency, body read to response [s].",
    buckets=(0.002, 0.005, 0.01, 0.02, 0.05, 0.1, 0.2, 0.5, 1.0, 2.0, 5.0),
)

ALERT_DELIVERIES = Counter(
    "vantage_alert_deliveries_total",
    "Air-quality alerts POSTed to the webhook, per outcome (delivered, failed: each failed "
    "attempt, retried with backoff until VANTAGE_ALERT_RETRY_HOURS).",
    ["outcome"],
)

HTTP_REQUESTS = Counter(
    "vantage_http_requests_total",
    "Requests answered, per method, route (its template) and status.",
    ["method", "route", "status"],
)
HTTP_SECONDS = Histogram(
    "vantage_http_request_seconds",
    "Request latency, first byte in to the last out, per method and route [s].",
    ["method", "route"],
    buckets=(0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1.0, 2.5, 5.0, 10.0, 30.0),
)
WRITER_BATCH_FRAMES = Histogram(
    "vantage_writer_batch_frames",
    "Uploads committed per write transaction of the group-commit writer.",
    buckets=(1, 2, 4, 8, 16, 32, 64),
)
UNMATCHED = "unmatched"
"""The route label of requests no route took (404s of any path): one series, not one each."""


class JsonFormatter(logging.Formatter):
    """One JSON object per line: time, level, logger, message, request id, extras."""

    _skip = frozenset(logging.LogRecord("", 0, "", 0, "", (), None).__dict__) | {
        "message",
        "color_message",  # uvicorn's message again, with terminal colours
    }

    def format(self, record: logging.LogRecord) -> str:
        out: dict[str, Any] = {
            "time": datetime.fromtimestamp(record.created, UTC).isoformat(timespec="milliseconds"),
            "level": record.levelname,
            "logger": record.name,
            "message": record.getMessage(),
        }
        rid = request_id_var.get()
        if rid is not None:
            out["request_id"] = rid
        for key, value in record.__dict__.items():
            if key not in self._skip and not key.startswith("_"):
                out[key] = value
        if record.exc_info:
            out["exc_info"] = self.formatException(record.exc_info)
        return json.dumps(out, default=str)


class _StderrHandler(logging.StreamHandler[Any]):
    """Writes to whatever ``sys.stderr`` is at the time of each record."""

    @property
    def stream(self) -> Any:
        return sys.stderr

    @stream.setter
    def stream(self, _: Any) -> None:
        pass


def configure_logging(level: str, as_json: bool) -> None:
    handler = _StderrHandler()
    if as_json:
        handler.setFormatter(JsonFormatter())
    else:
        handler.setFormatter(logging.Formatter("%(asctime)s %(levelname)s %(name)s %(message)s"))
    root = logging.getLogger("vantage")
    root.handlers[:] = [handler]
    root.setLevel(level.upper())
    root.propagate = False
    # uvicorn's own lines (its start, a request that is not HTTP, an error it caught) in the
    # same format: they came as plain text between the JSON ones, which a log pipeline
    # parsing JSON lines takes for garbage. Its access line is ``vantage.access``'s twice
    # over, without the request id: it is left out (a line a request, not two).
    server = logging.getLogger("uvicorn")
    server.handlers[:] = [handler]
    server.setLevel(level.upper())
    server.propagate = False
    logging.getLogger("uvicorn.access").handlers[:] = []
    logging.getLogger("uvicorn.access").setLevel(logging.WARNING)


access_log = logging.getLogger("vantage.access")


class RequestIdMiddleware:
    """Give every request an id (the client's ``X-Request-ID`` when sane), echo it, log access."""

    def __init__(self, app: ASGIApp) -> None:
        self.app = app

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        incoming = dict(scope["headers"]).get(b"x-request-id", b"").decode("latin-1")
        rid = incoming if 0 < len(incoming) <= 64 and incoming.isprintable() else uuid.uuid4().hex
        token = request_id_var.set(rid)
        start = time.perf_counter()
        status = 500

        async def send_with_id(message: Message) -> None:
            nonlocal status
            if message["type"] == "http.response.start":
                status = message["status"]
                message.setdefault("headers", [])
                message["headers"] = [*message["headers"], (b"x-request-id", rid.encode())]
            await send(message)

        try:
            await self.app(scope, receive, send_with_id)
        finally:
            seconds = time.perf_counter() - start
            method = scope["method"]
            route = getattr(scope.get("route"), "path", None)
            if route is None and "app" in scope:
                route = route_of(scope["app"], scope["path"])
            HTTP_REQUESTS.labels(method, route or UNMATCHED, str(status)).inc()
            HTTP_SECONDS.labels(method, route or UNMATCHED).observe(seconds)
            access_log.info(
                "request",
                extra={
                    "method": method,
                    "path": scope["path"],
                    "status": status,
                    "duration_ms": round(seconds * 1000, 2),
                },
            )
            request_id_var.reset(token)
