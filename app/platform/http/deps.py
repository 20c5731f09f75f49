"""Request dependencies, declared once: the session, the caller, and the role checks."""

from __future__ import annotations

import asyncio
import base64
import binascii
import hmac
import math
from collections.abc import AsyncIterator, Callable, Sequence
from dataclasses import dataclass, replace
from datetime import UTC, datetime
from functools import partial
from typing import Annotated, Any, Literal, TypeVar

import anyio
from fastapi import Depends, Path, Query, Request, Response
from fastapi.concurrency import run_in_threadpool
from pydantic import AfterValidator, StringConstraints
from sqlalchemy import select
from sqlalchemy.orm import Session, sessionmaker

from app.platform.auth import hash_token
from app.platform.db.models import Camera
from app.solar.models import Panel, Robot
from app.platform.frames import cameras as registry
from app.platform.frames import rate_limit
from app.platform.frames.camera_info import CameraInfo, TokenCache
from app.platform.frames.cameras import FrameKey
from app.platform.frames.writer import GroupCommitWriter
from app.platform.http.errors import (
    Forbidden,
    NotFound,
    ServiceUnavailable,
    TooManyRequests,
    Unauthorized,
    Unprocessable,
)
from app.platform.policy import Policy
from app.platform.settings import Settings
from app.solar import panels

ID_PATTERN = r"^[A-Za-z0-9._-]{1,64}$"


def get_sessionmaker(request: Request) -> sessionmaker[Session]:
    sm: sessionmaker[Session] = request.app.state.sessionmaker
    return sm


async def get_settings(request: Request) -> Settings:
    settings: Settings = request.app.state.settings
    return settings


async def get_session(request: Request) -> AsyncIterator[Session]:
    """The request's unit of work: commits once on success, rolls back on any error.

    Services only ``flush()``; nothing else commits. Database work, the commit included, runs
    in worker threads: the session is created here (no I/O) and closed in a thread only when a
    transaction is still open.
    """
    session = get_sessionmaker(request)()
    try:
        yield session
        if session.in_transaction():
            await run_in_threadpool(session.commit)
    except BaseException:
        if session.in_transaction():
            await run_in_threadpool(session.rollback)
        raise
    finally:
        if session.in_transaction():
            await run_in_threadpool(session.close)
        else:
            session.close()


async def get_policy(request: Request) -> Policy:
    policy: Policy = request.app.state.policy
    return policy


# scope="function": the commit ends the route's work, before the response is sent. (With the
# default request scope it would run after: a client could see 201 and another process not yet
# find the row, or a failed commit would follow a success already sent.)
SessionDep = Annotated[Session, Depends(get_session, scope="function")]
PolicyDep = Annotated[Policy, Depends(get_policy)]
SettingsDep = Annotated[Settings, Depends(get_settings)]


@dataclass(frozen=True, slots=True)
class Principal:
    """Who is calling."""

    role: Literal["admin", "camera", "robot"]
    id: str | None = None
    """The camera or robot id; None for the admin."""


def _credentials(header: str) -> tuple[str, str | None]:
    """(token, Basic user name or None) from an Authorization header."""
    scheme, _, value = header.strip().partition(" ")
    value = value.strip()
    if scheme.lower() == "bearer" and value:
        return value, None
    if scheme.lower() == "basic" and value:
        try:
            user, sep, password = base64.b64decode(value, validate=True).decode().partition(":")
        except (binascii.Error, UnicodeDecodeError):
            raise Unauthorized("malformed Basic credentials") from None
        if sep and password:
            return password, user
        raise Unauthorized("malformed Basic credentials")
    raise Unauthorized("expected 'Authorization: Bearer <token>' or Basic credentials")


def _identify(request: Request, session: Session) -> Principal:
    header = request.headers.get("authorization")
    if not header:
        raise Unauthorized("missing Authorization header")
    token, basic_user = _credentials(header)
    digest = hash_token(token)
    if hmac.compare_digest(digest, request.app.state.admin_token_hash):
        return Principal("admin")
    camera_id = session.scalar(select(Camera.id).where(Camera.token_hash == digest))
    if camera_id is not None:
        if basic_user is not None and basic_user != camera_id:
            raise Unauthorized("the Basic user name is not the camera this token belongs to")
        return Principal("camera", camera_id)
    robot_id = session.scalar(select(Robot.id).where(Robot.token_hash == digest))
    if robot_id is not None:
        return Principal("robot", robot_id)
    raise Unauthorized("unknown token")


def get_principal(request: Request) -> Principal:
    """Authenticate the caller: admin, camera or robot. Missing or unknown token → 401.

    The lookup uses its own short read-only session, so the request's unit of work does not hold
    a transaction open while the request body is read and decoded.
    """
    with get_sessionmaker(request)() as session:
        return _identify(request, session)


PrincipalDep = Annotated[Principal, Depends(get_principal)]


def require_metrics_reader(request: Request) -> None:
    """``/metrics``: the metrics token (``VANTAGE_METRICS_TOKEN``, a scraper's, good for
    nothing else) or the admin token. It names every camera, so it is not public."""
    expected: str | None = request.app.state.metrics_token_hash
    header = request.headers.get("authorization")
    if header and expected is not None:
        token, _ = _credentials(header)
        if hmac.compare_digest(hash_token(token), expected):
            return
    require_admin(get_principal(request))


MetricsReader = Annotated[None, Depends(require_metrics_reader)]


def optional_principal(request: Request) -> Principal | None:
    """The caller of a public endpoint: None without an Authorization header; a token that is
    given must be valid (401), so an operator's misspelt token is not silently public."""
    if not request.headers.get("authorization"):
        return None
    return get_principal(request)


OptionalPrincipal = Annotated[Principal | None, Depends(optional_principal)]


def require_admin(principal: PrincipalDep) -> Principal:
    if principal.role != "admin":
        raise Forbidden(f"this needs the admin token; a {principal.role} token was given")
    return principal


def require_robot(principal: PrincipalDep) -> Principal:
    if principal.role != "robot":
        raise Forbidden(f"this needs a robot token; a {principal.role} token was given")
    return principal


def require_robot_or_admin(principal: PrincipalDep) -> Principal:
    if principal.role not in ("robot", "admin"):
        raise Forbidden(f"this needs a robot or admin token; a {principal.role} token was given")
    return principal


Admin = Annotated[Principal, Depends(require_admin)]
RobotAuth = Annotated[Principal, Depends(require_robot)]
RobotOrAdmin = Annotated[Principal, Depends(require_robot_or_admin)]

CameraId = Annotated[str, Path(pattern=ID_PATTERN, description="Camera id.")]
PanelId = Annotated[str, Path(pattern=ID_PATTERN, description="Panel id.")]
RigId = Annotated[str, Path(pattern=ID_PATTERN, description="Rig id.")]
RobotId = Annotated[str, Path(pattern=ID_PATTERN, description="Robot id.")]
RecordId = Annotated[str, Path(pattern=ID_PATTERN, description="Id given by the service.")]
IdFilter = Annotated[str | None, Query(pattern=ID_PATTERN, description="Only this id.")]
MAX_IDS = 100
IdsFilter = Annotated[
    list[Annotated[str, StringConstraints(pattern=ID_PATTERN)]] | None,
    Query(
        max_length=MAX_IDS,
        description=f"Only these ids (up to {MAX_IDS}): repeat the parameter, `?camera_id=a"
        "&camera_id=b`.",
    ),
]


def _utc(value: datetime) -> datetime:
    """A time from a client in UTC: one without an offset is taken as UTC; one whose
    conversion leaves the calendar (year 1 at +14:00) is refused."""
    if value.tzinfo is None:
        return value.replace(tzinfo=UTC)
    try:
        return value.astimezone(UTC)
    except OverflowError:
        raise ValueError("the time lies outside years 1–9999 once converted to UTC") from None


UtcTime = Annotated[datetime, AfterValidator(_utc)]
"""A time given by a client: RFC 3339, UTC when it carries no offset."""


@dataclass(frozen=True, slots=True)
class TimeRange:
    """[since, until): either end may be open."""

    since: datetime | None
    until: datetime | None


def _time_range(
    since: Annotated[UtcTime | None, Query(description="At or after (RFC 3339).")] = None,
    until: Annotated[UtcTime | None, Query(description="Before (RFC 3339).")] = None,
) -> TimeRange:
    if since and until and since >= until:
        raise Unprocessable("since must be before until")
    return TimeRange(since, until)


def _cursor(
    cursor: Annotated[
        str | None,
        Query(
            max_length=200,
            description="Where the previous page ended: the `cursor` of its `Link: rel=next` "
            "header. Unlike `offset`, a page costs the same however deep, and rows arriving "
            "meanwhile shift nothing.",
        ),
    ] = None,
) -> FrameKey | None:
    if cursor is None:
        return None
    try:
        when, _, frame_id = base64.urlsafe_b64decode(cursor.encode()).decode().partition("|")
        key = FrameKey(datetime.fromisoformat(when), frame_id)
    except (ValueError, binascii.Error):
        raise Unprocessable("cursor is not one this service gave", code="bad_cursor") from None
    if key.captured_at.tzinfo is None or not frame_id:
        raise Unprocessable("cursor is not one this service gave", code="bad_cursor")
    return key


FrameCursor = Annotated[FrameKey | None, Depends(_cursor)]
"""The ``cursor`` query parameter of a listing of frames newest first."""


def cursor_of(key: FrameKey) -> str:
    """The ``cursor`` for the page after ``key`` (read back by ``FrameCursor``)."""
    return base64.urlsafe_b64encode(
        f"{key.captured_at.isoformat()}|{key.frame_id}".encode()
    ).decode()


def link_next(request: Request, response: Response, rows: Sequence[Any], limit: int) -> None:
    """``Link: <…>; rel="next"`` on a full page of frames (rows with ``captured_at`` and the
    frame id as ``id``), as RFC 8288: the same query, from after its last row."""
    if len(rows) < limit:
        return
    last = rows[-1]
    url = request.url.remove_query_params("offset").include_query_params(
        cursor=cursor_of(FrameKey(last.captured_at, last.id))
    )
    response.headers["Link"] = f'<{url}>; rel="next"'


TimeRangeQuery = Annotated[TimeRange, Depends(_time_range)]
"""The ``since`` and ``until`` query parameters of a listing by time."""
Limit = Annotated[int, Query(ge=1, le=1000)]
Offset = Annotated[int, Query(ge=0, le=10_000_000)]


T = TypeVar("T")


async def _limited(
    request: Request, name: str, capacity: int, fn: Callable[..., T], *args: Any, **kwargs: Any
) -> T:
    """``fn`` in a worker thread, at most ``capacity`` at once in this process under the
    limiter ``name``; the others wait their turn (holding no thread)."""
    state = request.app.state
    limiter: anyio.CapacityLimiter | None = getattr(state, name, None)
    if limiter is None:  # made on first use, inside the event loop
        limiter = anyio.CapacityLimiter(capacity)
        setattr(state, name, limiter)
    return await anyio.to_thread.run_sync(partial(fn, *args, **kwargs), limiter=limiter)


async def image_work(request: Request, fn: Callable[..., T], *args: Any, **kwargs: Any) -> T:
    """``fn`` in a worker thread, at most ``image_threads`` at once in this process; the others
    wait their turn. The work is CPU-bound, so more at once only shares the cores, and each
    holds its images' pixels (an outline of a 36 MP photo peaked at ~460 MB): without a bound,
    FastAPI's 40 threads could hold 40 of them."""
    capacity = request.app.state.settings.effective_image_threads
    return await _limited(request, "image_limiter", capacity, fn, *args, **kwargs)


async def public_work(request: Request, fn: Callable[..., T], *args: Any, **kwargs: Any) -> T:
    """``fn(session, *args, **kwargs)`` in a worker thread with a read-only session of its
    own, at most ``public_work_threads`` (1) at once in this process: the public maps and
    aggregates, which anyone may ask for with any parameters (a cache does not help there),
    each costing up to seconds of CPU and database. The session is not the request's: on
    SQLite that one takes the write lock (see ``make_read_engine``). With 8 dashboards asking
    for a week's daily means, uploads kept 0.79–0.84 of their rate one at a time, 0.47 with
    40 at once (bench/public_load.py)."""
    state = request.app.state
    capacity = state.settings.public_work_threads
    return await _limited(request, "public_limiter", capacity, _read, state, fn, args, kwargs)


def _read(state: Any, fn: Callable[..., T], args: Any, kwargs: Any) -> T:
    sessions: sessionmaker[Session] = state.read_sessionmaker
    with sessions() as session:
        return fn(session, *args, **kwargs)


def _info(session: Session, camera: Camera) -> CameraInfo:
    """The camera as the ingest path reads it; ``panel_has_baseline``: its view (region) has a
    baseline, so the fleet model's features need not be computed."""
    panel = session.get(Panel, camera.panel_id) if camera.panel_id is not None else None
    info = CameraInfo.of(camera)
    if panel is None or panels.baseline_for(session, panel, info.region) is None:
        return info
    return replace(info, panel_has_baseline=True)


def _token_owner(session: Session, digest: str) -> CameraInfo | Principal | None:
    """The camera (or robot) a token belongs to (run in the frame writer's batch)."""
    camera = session.scalar(select(Camera).where(Camera.token_hash == digest))
    if camera is not None:
        return replace(_info(session, camera), token_hash=digest)
    robot_id = session.scalar(select(Robot.id).where(Robot.token_hash == digest))
    return Principal("robot", robot_id) if robot_id is not None else None


async def _in_next_batch(request: Request, job: Callable[[Session], T], what: str) -> T:
    """``job(session)`` run in the frame writer's next batch (``GroupCommitWriter.submit``),
    or 503 after ``upload_timeout_seconds``. The upload's own reads and writes before its body
    is read (its camera looked up, a block of its budget reserved) go there rather than to a
    thread of the shared pool with a session of their own: that cost ~0.6 ms of CPU for a
    lookup and ~0.8 ms for a reservation on PostgreSQL (a session, a pooled connection's ping,
    BEGIN, the statements, the end of the transaction), a quarter to a third of a frame's, and
    a camera posting once a minute pays both on every frame."""
    writer: GroupCommitWriter = request.app.state.writer
    seconds: float = request.app.state.settings.upload_timeout_seconds
    try:
        return await asyncio.wait_for(writer.submit(job), seconds)
    except TimeoutError:
        raise ServiceUnavailable(
            f"{what} within {seconds:g} s (the database is not answering, or the service is "
            "overloaded): send the frame again",
            code="upload_timeout",
        ) from None


def _camera_by_id(request: Request, camera_id: str) -> CameraInfo | None:
    with get_sessionmaker(request)() as session:
        camera = session.get(Camera, camera_id)
        if camera is None:
            return None
        registry.check_in_service(camera)  # a retired camera's own token no longer exists
        return _info(session, camera)


async def fresh_upload_target(request: Request, target: CameraInfo) -> CameraInfo:
    """The upload's camera as it is now, looked up again (and cached again under its token):
    the writer found it changed through another process since ``target`` was cached."""
    info = await run_in_threadpool(_camera_by_id, request, target.id)
    if info is None:
        raise NotFound(f"no camera {target.id!r}")
    info = replace(info, token_hash=target.token_hash)
    if target.token_hash is not None:
        cache: TokenCache = request.app.state.camera_tokens
        cache.put(target.token_hash, info)
    return info


async def get_upload_target(camera_id: CameraId, request: Request) -> CameraInfo:
    """Authenticate and authorise a frame upload and find its camera, before the body is read.

    The camera's own token (Bearer, or Basic with the camera id as user name) or the admin
    token; another camera's or a robot's → 403. Camera tokens are cached briefly
    (``TokenCache``), so a steady stream of frames costs no lookup here.
    """
    header = request.headers.get("authorization")
    if not header:
        raise Unauthorized("missing Authorization header")
    token, basic_user = _credentials(header)
    digest = hash_token(token)
    if hmac.compare_digest(digest, request.app.state.admin_token_hash):
        info = await run_in_threadpool(_camera_by_id, request, camera_id)
        if info is None:
            raise NotFound(f"no camera {camera_id!r}")
        return info
    cache: TokenCache = request.app.state.camera_tokens
    found: CameraInfo | Principal | None = cache.get(digest)
    if found is None:
        found = await _in_next_batch(
            request, partial(_token_owner, digest=digest), "the camera could not be looked up"
        )
        if isinstance(found, CameraInfo):
            cache.put(digest, found)
    if found is None:
        raise Unauthorized("unknown token")
    if isinstance(found, Principal):
        raise Forbidden(f"a {found.role} token may not post frames")
    if basic_user is not None and basic_user != found.id:
        raise Unauthorized("the Basic user name is not the camera this token belongs to")
    if found.id != camera_id:
        raise Forbidden("this camera's token may only post frames for its own camera")
    await _check_rate(request, found.id)
    return found


async def _check_rate(request: Request, camera_id: str) -> None:
    """At most ``rate_limit_per_minute`` frames per camera in each clock minute, over all
    processes: budget reserved in the database in blocks (``app.platform.frames.rate_limit``), spent
    here without a round trip. A camera flooding is refused before its body is read and cannot
    crowd out the others. A block is reserved in the frame writer's next batch, and committed
    with its frames (``_in_next_batch``)."""
    limit: int = request.app.state.settings.rate_limit_per_minute
    if limit <= 0:
        return
    policy: Policy = request.app.state.policy
    now = policy.now()
    minute = rate_limit.minute_of(now)
    budgets: rate_limit.LocalBudgets = request.app.state.rate_budgets
    if budgets.take(camera_id, minute):
        return
    reservation = partial(rate_limit.reserve, camera_id=camera_id, minute=minute, limit=limit)
    granted = await _in_next_batch(
        request, reservation, f"camera {camera_id}'s frame budget could not be reserved"
    )
    if granted <= 0:
        wait = 60 - (now - minute).total_seconds()
        raise TooManyRequests(
            f"camera {camera_id} has posted its {limit} frames for this minute",
            retry_after=max(1, math.ceil(wait)),
            code="rate_limited",
        )
    budgets.keep(camera_id, minute, granted - 1)


UploadTargetDep = Annotated[CameraInfo, Depends(get_upload_target)]
