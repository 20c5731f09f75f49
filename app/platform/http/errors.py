"""Domain errors and their single mapping to RFC 9457 problem+json."""

from __future__ import annotations

import logging
from http import HTTPStatus
from typing import Any

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse, Response
from sqlalchemy.exc import DataError, DBAPIError, OperationalError
from sqlalchemy.exc import TimeoutError as PoolTimeout
from starlette.exceptions import HTTPException as StarletteHTTPException
from starlette.requests import ClientDisconnect

from app.platform.db.rows import READ_ONLY_SQL_TRANSACTION
from app.platform.observability import FRAMES_REJECTED
from app.platform.routes import operations_of

log = logging.getLogger("vantage.errors")

PROBLEM_JSON = "application/problem+json"


class VantageError(Exception):
    """Base of every error the service reports to clients; carries its HTTP status."""

    status = 400
    title = "Bad request"

    def __init__(self, detail: str, *, headers: dict[str, str] | None = None, **extra: Any):
        super().__init__(detail)
        self.detail = detail
        self.headers = headers
        self.extra = extra


class Unauthorized(VantageError):
    status = 401
    title = "Unauthorized"

    def __init__(self, detail: str = "missing or unknown token", **extra: Any):
        headers = {"WWW-Authenticate": 'Bearer realm="vantage"'}
        super().__init__(detail, headers=headers, **extra)


class Forbidden(VantageError):
    status = 403
    title = "Forbidden"


class NotFound(VantageError):
    status = 404
    title = "Not found"


class Conflict(VantageError):
    status = 409
    title = "Conflict"


class PayloadTooLarge(VantageError):
    status = 413
    title = "Payload too large"


class UnsupportedMediaType(VantageError):
    status = 415
    title = "Unsupported media type"


class Unprocessable(VantageError):
    status = 422
    title = "Unprocessable content"


class TooManyRequests(VantageError):
    status = 429
    title = "Too many requests"

    def __init__(self, detail: str, *, retry_after: int, **extra: Any):
        super().__init__(detail, headers={"Retry-After": str(retry_after)}, **extra)


RETRY_AFTER_SECONDS = 5
"""What a 503 asks its client to wait: the database or the frame store unavailable, an upload
not stored in time."""


class ServiceUnavailable(VantageError):
    status = 503
    title = "Service unavailable"

    def __init__(self, detail: str, *, retry_after: int = RETRY_AFTER_SECONDS, **extra: Any):
        super().__init__(detail, headers={"Retry-After": str(retry_after)}, **extra)


def problem(
    status: int,
    title: str,
    detail: str,
    *,
    headers: dict[str, str] | None = None,
    **extra: Any,
) -> JSONResponse:
    body = {"type": "about:blank", "title": title, "status": status, "detail": detail, **extra}
    return JSONResponse(body, status_code=status, headers=headers, media_type=PROBLEM_JSON)


def _jsonable(errors: Any) -> Any:
    # validation errors may carry exceptions or bytes in ctx/input; keep what JSON can hold
    out = []
    for e in errors:
        item = {k: e[k] for k in ("loc", "msg", "type") if k in e}
        item["loc"] = [str(p) for p in item.get("loc", [])]
        out.append(item)
    return out


FRAMES_ROUTE = "/cameras/{camera_id}/frames"


def _count_rejected_frame(request: Request, status: int, code: str | None) -> None:
    route = request.scope.get("route")
    if getattr(route, "path", None) != FRAMES_ROUTE or request.method != "POST":
        return
    # label only cameras that passed authentication and exist: bounded label cardinality
    camera = request.path_params.get("camera_id") if status not in (401, 403, 404) else None
    FRAMES_REJECTED.labels(camera or "unknown", code or str(status)).inc()


def _title(status: int) -> str:
    """The status's reason phrase as the problem's title, as the service's own errors have
    (``Bad request`` for a body that is not JSON at all)."""
    try:
        return HTTPStatus(status).phrase.capitalize()
    except ValueError:
        return "Error"


def _is_json(media_type: str) -> bool:
    return media_type == "application/json" or media_type.endswith("+json")


def allowed_methods(request: Request, first: str | None) -> str:
    """Every method the request's path answers, for a 405's ``Allow`` (RFC 9110 §15.5.6: the
    resource's supported methods). Starlette names only those of the first route matching the
    path (``first``), so ``DELETE /cameras`` was told ``Allow: POST`` where GET is served too;
    the others come from the OpenAPI document. HEAD is answered wherever GET is
    (``app.platform.http.head``)."""
    path = request.url.path
    methods = {m for pattern, _, m in operations_of(request.app) if pattern.match(path)}
    methods |= {m.strip() for m in (first or "").split(",") if m.strip()}
    if "GET" in methods:
        methods.add("HEAD")
    return ", ".join(sorted(methods))


CLIENT_CLOSED_REQUEST = 499
"""The status a request whose client went away is counted under (nginx's), never sent."""


def install_error_handlers(app: FastAPI) -> None:
    @app.exception_handler(VantageError)
    async def _vantage(request: Request, exc: VantageError) -> JSONResponse:
        _count_rejected_frame(request, exc.status, exc.extra.get("code"))
        return problem(exc.status, exc.title, exc.detail, headers=exc.headers, **exc.extra)

    @app.exception_handler(RequestValidationError)
    async def _validation(request: Request, exc: RequestValidationError) -> JSONResponse:
        errors = _jsonable(exc.errors())
        media_type = request.headers.get("content-type", "").split(";")[0].strip().lower()
        if not _is_json(media_type) and any(e["loc"][:1] == ["body"] for e in errors):
            # FastAPI reads a JSON body only when labelled so; otherwise it reported the body
            # as "not a valid dictionary", though `curl -d` had sent valid JSON labelled as a
            # form (its default) or nothing labelled at all
            return problem(
                415,
                "Unsupported media type",
                f"the body must be JSON, sent with Content-Type: application/json; it came as "
                f"{media_type or 'no Content-Type'}",
                code="not_json",
            )
        _count_rejected_frame(request, 422, "invalid_parameters")
        first = errors[0] if errors else {"loc": [], "msg": "invalid request"}
        detail = f"{'.'.join(first['loc'])}: {first['msg']}"
        return problem(422, "Unprocessable content", detail, errors=errors)

    @app.exception_handler(StarletteHTTPException)
    async def _http(request: Request, exc: StarletteHTTPException) -> JSONResponse:
        title = _title(exc.status_code)
        headers = dict(exc.headers) if exc.headers else None
        if exc.status_code == 405:
            allow = allowed_methods(request, (headers or {}).get("Allow"))
            headers = {**(headers or {}), "Allow": allow}
        return problem(exc.status_code, title, str(exc.detail), headers=headers)

    @app.exception_handler(DataError)
    async def _data(_: Request, exc: DataError) -> JSONResponse:
        # a value the database refuses (NUL in text, a number out of its range): bad input
        log.warning("database refused a value: %s", exc.orig)
        return problem(
            422,
            "Unprocessable content",
            "a value is not storable (out of range or containing NUL characters)",
        )

    @app.exception_handler(DBAPIError)
    async def _database(request: Request, exc: DBAPIError) -> JSONResponse:
        if not database_unavailable(exc):
            return await _unexpected(request, exc)
        return _database_unavailable(request, exc)

    @app.exception_handler(PoolTimeout)
    async def _pool_timeout(request: Request, exc: PoolTimeout) -> JSONResponse:
        return _database_unavailable(request, exc)

    @app.exception_handler(ClientDisconnect)
    async def _client_gone(request: Request, _: ClientDisconnect) -> Response:
        # The client went away before its body was all sent (a camera losing its link
        # mid-upload, or cut off by the proxy for sending too slowly): nothing is stored, and
        # there is no one to answer; not a failure of the service (no 500, no ERROR).
        log.info("the client went away before sending its whole request")
        _count_rejected_frame(request, CLIENT_CLOSED_REQUEST, "client_disconnected")
        return Response(status_code=CLIENT_CLOSED_REQUEST)

    @app.exception_handler(Exception)
    async def _unexpected(_: Request, exc: Exception) -> JSONResponse:
        log.exception("unhandled error", exc_info=exc)
        return problem(500, "Internal server error", "the service failed; see its logs")


SQLITE_OUTAGES = frozenset(
    {
        "SQLITE_BUSY",  # locked past the busy timeout
        "SQLITE_LOCKED",
        "SQLITE_NOMEM",
        "SQLITE_IOERR",  # the disk failing
        "SQLITE_FULL",
        "SQLITE_CANTOPEN",  # the file or its directory gone
        "SQLITE_READONLY",  # the disk remounted read-only after errors
        "SQLITE_PROTOCOL",
    }
)
"""SQLite's primary result codes of a database that cannot serve now. Its OperationalError
also stands for "no such table" or "no such column" (SQLITE_ERROR): a schema this code does
not match, which a retry does not mend."""


def database_unavailable(exc: BaseException) -> bool:
    """Whether the database could not serve at all (down, restarting, its connection lost,
    out of connections or disk, locked past the busy timeout, a serialization conflict, the
    pool's connections all taken) rather than failed on this request: PostgreSQL's
    OperationalError, except its class 54 (a statement over a program limit, which a retry
    repeats), and SQLite's of ``SQLITE_OUTAGES``."""
    if isinstance(exc, PoolTimeout):
        return True
    if not isinstance(exc, DBAPIError):
        return False
    if exc.connection_invalidated:
        return True
    if not isinstance(exc, OperationalError):
        return False
    name = getattr(exc.orig, "sqlite_errorname", None)
    if name is not None:  # extended codes (SQLITE_IOERR_WRITE) by their primary code
        return any(name == c or name.startswith(c + "_") for c in SQLITE_OUTAGES)
    sqlstate = getattr(exc.orig, "sqlstate", None) or ""
    return not sqlstate.startswith("54")


DISK_FULL = "53100"
"""PostgreSQL's sqlstate of a statement refused for want of disk space."""


def _why_unavailable(exc: BaseException) -> str:
    """The 503's detail: what the driver's error says of the database."""
    orig = getattr(exc, "orig", None)
    code = getattr(orig, "sqlite_errorname", None) or getattr(orig, "sqlstate", None)
    if code in ("SQLITE_FULL", DISK_FULL):
        return "the database's disk is full: try again when space has been freed"
    if code == READ_ONLY_SQL_TRANSACTION:
        return (
            "the database is read-only (a standby after a failover, or maintenance): "
            "try again shortly"
        )
    return "the database cannot be reached or is busy: try again shortly"


def _database_unavailable(request: Request, exc: Exception) -> JSONResponse:
    # An outage: a 503 the client retries (cameras, robots, dashboards), not a 500 "the
    # service failed", and one line in the log per request, not a traceback.
    log.warning("database unavailable: %s", str(exc).splitlines()[0])
    _count_rejected_frame(request, 503, "database_unavailable")
    detail = _why_unavailable(exc)
    return problem(
        503,
        "Service unavailable",
        detail,
        headers={"Retry-After": str(RETRY_AFTER_SECONDS)},
        code="database_unavailable",
    )
