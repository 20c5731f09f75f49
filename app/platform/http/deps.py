"""Request dependencies, declared once: the session, the caller, and the role checks."""

from __future__ import annotations

import hmac
from collections.abc import AsyncIterator, Callable
from dataclasses import dataclass
from datetime import UTC, datetime
from functools import partial
from typing import Annotated, Any, Literal, TypeVar

import anyio
from fastapi import Depends, Path, Query, Request
from fastapi.concurrency import run_in_threadpool
from pydantic import AfterValidator, StringConstraints
from sqlalchemy import select
from sqlalchemy.orm import Session, sessionmaker

from app.platform.auth import hash_token
from app.platform.db.models import Camera, ViewerToken
from app.platform.http.credentials import credentials_of
from app.platform.http.crowds import Crowds
from app.platform.http.errors import (
    Forbidden,
    ServiceUnavailable,
    TooManyRequests,
    Unauthorized,
    Unprocessable,
)
from app.platform.settings import Settings
from app.platform.state import app_state
from app.platform.timing import Timing

ID_PATTERN = r"^[A-Za-z0-9._-]{1,64}$"


def get_sessionmaker(request: Request) -> sessionmaker[Session]:
    sm: sessionmaker[Session] = app_state(request).sessionmaker
    return sm


async def get_settings(request: Request) -> Settings:
    settings: Settings = app_state(request).settings
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


async def get_timing(request: Request) -> Timing:
    timing: Timing = app_state(request).timing
    return timing


# scope="function": the commit ends the route's work, before the response is sent. (With the
# default request scope it would run after: a client could see 201 and another process not yet
# find the row, or a failed commit would follow a success already sent.)
SessionDep = Annotated[Session, Depends(get_session, scope="function")]
TimingDep = Annotated[Timing, Depends(get_timing)]
SettingsDep = Annotated[Settings, Depends(get_settings)]


@dataclass(frozen=True, slots=True)
class Principal:
    """Who is calling."""

    role: Literal["admin", "camera", "robot", "viewer"]
    id: str | None = None
    """The camera, robot or viewer token id; None for the admin."""


def _identify(request: Request, session: Session) -> Principal:
    """The caller, its token then known to the anonymous limits (``crowds``)."""
    header = request.headers.get("authorization")
    if not header:
        raise Unauthorized("missing Authorization header")
    token, basic_user = credentials_of(header)
    digest = hash_token(token)
    principal = _owner(request, session, digest, basic_user)
    crowds: Crowds = app_state(request).crowds
    crowds.trust(digest)
    return principal


def _owner(request: Request, session: Session, digest: str, basic_user: str | None) -> Principal:
    camera_id = session.scalar(select(Camera.id).where(Camera.token_hash == digest))
    if camera_id is not None:
        if basic_user is not None and basic_user != camera_id:
            raise Unauthorized("the Basic user name is not the camera this token belongs to")
        return Principal("camera", camera_id)
    if basic_user is not None:  # a browser replays Basic cross-site: only cameras use it
        raise Unauthorized("HTTP Basic is for cameras (their id and token); use Bearer")
    if hmac.compare_digest(digest, app_state(request).admin_token_hash):
        return Principal("admin")
    principal = other_owner(request, session, digest)
    if principal is None:
        raise Unauthorized("unknown token")
    return principal


def other_owner(request: Request, session: Session, digest: str) -> Principal | None:
    """The caller a token (its hash) belongs to among viewers and the roles the domains add
    (``app.state.token_owners``: robots), or None."""
    viewer_id = session.scalar(select(ViewerToken.id).where(ViewerToken.token_hash == digest))
    if viewer_id is not None:
        return Principal("viewer", viewer_id)
    for role, owner_of in app_state(request).token_owners:
        owner = owner_of(session, digest)
        if owner is not None:
            return Principal(role, owner)
    return None


def get_principal(request: Request) -> Principal:
    """Authenticate the caller: admin, camera or robot. Missing or unknown token → 401.

    The lookup uses its own short read-only session, so the request's unit of work does not hold
    a transaction open while the request body is read and decoded.
    """
    try:
        with get_sessionmaker(request)() as session:
            return _identify(request, session)
    except Unauthorized as exc:
        challenge_cameras(request, exc)
        raise


def challenge_cameras(request: Request, exc: Unauthorized) -> None:
    """Add the Basic challenge to ``exc`` where a camera posts frames (some answer only a
    challenge); a browser (it sends ``Sec-Fetch-Mode``) is never challenged for Basic, which
    it would then replay to the service from any site."""
    parts = request.url.path.split("/")
    if (
        len(parts) == 4
        and parts[1] == "cameras"
        and parts[3] == "frames"
        and "sec-fetch-mode" not in request.headers
    ):
        exc.headers = {"WWW-Authenticate": 'Bearer, Basic realm="vantage cameras"'}


PrincipalDep = Annotated[Principal, Depends(get_principal)]


def require_metrics_reader(request: Request) -> None:
    """``/metrics``: the metrics token (``VANTAGE_METRICS_TOKEN``, a scraper's, good for
    nothing else) or the admin token. It names every camera, so it is not public."""
    expected: str | None = app_state(request).metrics_token_hash
    header = request.headers.get("authorization")
    if header and expected is not None:
        token, _ = credentials_of(header)
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


def require_reader(principal: PrincipalDep) -> Principal:
    """The boards' reads: the admin, or a viewer (read-only)."""
    if principal.role not in ("admin", "viewer"):
        raise Forbidden(f"this needs an admin or viewer token; a {principal.role} token was given")
    return principal


def require_any_reader(principal: PrincipalDep) -> Principal:
    """Reads a robot needs too: the admin, a robot or a viewer."""
    if principal.role not in ("admin", "robot", "viewer"):
        raise Forbidden(
            f"this needs an admin, robot or viewer token; a {principal.role} token was given"
        )
    return principal


Admin = Annotated[Principal, Depends(require_admin)]
RobotAuth = Annotated[Principal, Depends(require_robot)]
RobotOrAdmin = Annotated[Principal, Depends(require_robot_or_admin)]
Reader = Annotated[Principal, Depends(require_reader)]
AnyReader = Annotated[Principal, Depends(require_any_reader)]

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


TimeRangeQuery = Annotated[TimeRange, Depends(_time_range)]
"""The ``since`` and ``until`` query parameters of a listing by time."""
Limit = Annotated[int, Query(ge=1, le=1000)]
Offset = Annotated[int, Query(ge=0, le=10_000_000)]
Significance = Annotated[
    float,
    Query(
        ge=1e-6,
        le=0.05,
        description="ς, the level of significance of Hotelling's T² test (eq. 5.21; eq. 6.21 "
        "for the sky's levels).",
    ),
]
Shrinkage = Annotated[
    float,
    Query(
        ge=0,
        le=100,
        description="Variance added to the diagonal of each Σ̂ of modes [level²]. 0 refuses a "
        "singular covariance; 1/12 (the integer rounding of modes) admits a channel whose "
        "mode never changes.",
    ),
]


T = TypeVar("T")


async def _limited(
    request: Request, name: str, capacity: int, fn: Callable[..., T], *args: Any, **kwargs: Any
) -> T:
    """``fn`` in a worker thread, at most ``capacity`` at once in this process under the
    limiter ``name``; the others wait their turn (holding no thread)."""
    state = app_state(request)
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
    capacity = app_state(request).settings.effective_image_threads
    return await _limited(request, "image_limiter", capacity, fn, *args, **kwargs)


async def public_read(request: Request, fn: Callable[..., T], *args: Any, **kwargs: Any) -> T:
    """``fn(session, *args, **kwargs)`` as ``public_work`` runs it (a read-only session of its
    own, in a worker thread), in a lane of its own: cheap public reads that every dashboard
    polls (the latest reading of every camera) never wait behind the maps and aggregates,
    nor count as computations against a client's share."""
    state = app_state(request)
    capacity = state.settings.public_work_threads
    return await _limited(request, "public_read_limiter", capacity, _read, state, fn, args, kwargs)


async def public_work(request: Request, fn: Callable[..., T], *args: Any, **kwargs: Any) -> T:
    """``fn(session, *args, **kwargs)`` in a worker thread with a read-only session of its
    own, at most ``public_work_threads`` (1) at once in this process: the public maps and
    aggregates, which anyone may ask for with any parameters (a cache does not help there),
    each costing up to seconds of CPU and database. The session is not the request's: on
    SQLite that one takes the write lock (see ``make_read_engine``). With 8 dashboards asking
    for a week's daily means, uploads kept 0.79–0.84 of their rate one at a time, 0.47 with
    40 at once (bench/public_load.py)."""
    state = app_state(request)
    capacity = state.settings.public_work_threads
    crowds: Crowds = state.crowds
    try:
        crowds.enter_work(request)  # 429 past a client's share, 503 when the queue is full
    except (TooManyRequests, ServiceUnavailable):
        await anyio.sleep(crowds.refusal_delay(request.scope))
        raise
    try:
        return await _limited(request, "public_limiter", capacity, _read, state, fn, args, kwargs)
    finally:
        crowds.leave_work()


def _read(state: Any, fn: Callable[..., T], args: Any, kwargs: Any) -> T:
    sessions: sessionmaker[Session] = state.read_sessionmaker
    with sessions() as session:
        return fn(session, *args, **kwargs)
