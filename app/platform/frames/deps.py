"""Request dependencies of the frame endpoints: the upload's camera and its rate budget,
and the cursor of a listing of frames."""

from __future__ import annotations

import base64
import binascii
import hmac
import math
from collections.abc import Sequence
from dataclasses import replace
from datetime import datetime
from typing import Annotated, Any

from fastapi import Depends, Query, Request, Response
from fastapi.concurrency import run_in_threadpool
from sqlalchemy import select
from sqlalchemy.orm import Session, sessionmaker

from app.platform.auth import hash_token
from app.platform.db.models import Camera
from app.platform.frames import cameras, rate_limit
from app.platform.frames.camera_info import CameraInfo, TokenCache
from app.platform.frames.cameras import FrameKey
from app.platform.frames.kinds import KINDS
from app.platform.http.credentials import credentials_of
from app.platform.http.crowds import Crowds
from app.platform.http.deps import (
    CameraId,
    Principal,
    challenge_cameras,
    get_sessionmaker,
    other_owner,
)
from app.platform.http.errors import (
    Forbidden,
    NotFound,
    TooManyRequests,
    Unauthorized,
    Unprocessable,
)
from app.platform.state import app_state
from app.platform.timing import Timing


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


def _info(session: Session, camera: Camera) -> CameraInfo:
    """The camera as the ingest path reads it, with what its kind knows of it
    (``KindHandler.describe``)."""
    return KINDS[camera.kind].describe(session, camera, CameraInfo.of(camera))


def _camera_by_token(request: Request, digest: str) -> CameraInfo | Principal | None:
    """The camera a token belongs to, or the principal of another role's token."""
    with get_sessionmaker(request)() as session:
        camera = session.scalar(select(Camera).where(Camera.token_hash == digest))
        if camera is not None:
            return replace(_info(session, camera), token_hash=digest)
        return other_owner(request, session, digest)


def _camera_by_id(request: Request, camera_id: str) -> CameraInfo | None:
    with get_sessionmaker(request)() as session:
        camera = session.get(Camera, camera_id)
        if camera is None:
            return None
        cameras.check_in_service(camera)  # a retired camera's own token no longer exists
        return _info(session, camera)


async def fresh_upload_target(request: Request, target: CameraInfo) -> CameraInfo:
    """The upload's camera as it is now, looked up again (and cached again under its token):
    the writer found it changed through another process since ``target`` was cached."""
    info = await run_in_threadpool(_camera_by_id, request, target.id)
    if info is None:
        raise NotFound(f"no camera {target.id!r}")
    info = replace(info, token_hash=target.token_hash)
    if target.token_hash is not None:
        cache: TokenCache = app_state(request).camera_tokens
        cache.put(target.token_hash, info)
    return info


async def get_upload_target(camera_id: CameraId, request: Request) -> CameraInfo:
    """The upload's camera (``_upload_target``); a 401 challenges a camera for Basic too."""
    try:
        target = await _upload_target(camera_id, request)
    except Unauthorized as exc:
        challenge_cameras(request, exc)
        raise
    if target.token_hash is not None:  # its uploads skip the anonymous limits (``crowds``)
        crowds: Crowds = app_state(request).crowds
        crowds.trust(target.token_hash)
    return target


async def _upload_target(camera_id: CameraId, request: Request) -> CameraInfo:
    """Authenticate and authorise a frame upload and find its camera, before the body is read.

    The camera's own token (Bearer, or Basic with the camera id as user name) or the admin
    token; another camera's or a robot's → 403. Camera tokens are cached briefly
    (``TokenCache``), so a steady stream of frames costs no lookup here.
    """
    header = request.headers.get("authorization")
    if not header:
        raise Unauthorized("missing Authorization header")
    token, basic_user = credentials_of(header)
    digest = hash_token(token)
    if basic_user is None and hmac.compare_digest(digest, app_state(request).admin_token_hash):
        info = await run_in_threadpool(_camera_by_id, request, camera_id)
        if info is None:
            raise NotFound(f"no camera {camera_id!r}")
        return info
    cache: TokenCache = app_state(request).camera_tokens
    found: CameraInfo | Principal | None = cache.get(digest)
    if found is None:
        found = await run_in_threadpool(_camera_by_token, request, digest)
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


def _reserve(request: Request, camera_id: str, minute: datetime, limit: int) -> int:
    with get_sessionmaker(request).begin() as session:
        return rate_limit.reserve(session, camera_id, minute, limit)


async def _check_rate(request: Request, camera_id: str) -> None:
    """At most ``rate_limit_per_minute`` frames per camera in each clock minute, over all
    processes: budget reserved in the database in blocks (``app.platform.frames.rate_limit``), spent
    here without a round trip. A camera flooding is refused before its body is read and cannot
    crowd out the others."""
    limit: int = app_state(request).settings.rate_limit_per_minute
    if limit <= 0:
        return
    timing: Timing = app_state(request).timing
    now = timing.now()
    minute = rate_limit.minute_of(now)
    budgets: rate_limit.LocalBudgets = app_state(request).rate_budgets
    if budgets.take(camera_id, minute):
        return
    granted = await run_in_threadpool(_reserve, request, camera_id, minute, limit)
    if granted <= 0:
        wait = 60 - (now - minute).total_seconds()
        raise TooManyRequests(
            f"camera {camera_id} has posted its {limit} frames for this minute",
            retry_after=max(1, math.ceil(wait)),
            code="rate_limited",
        )
    budgets.keep(camera_id, minute, granted - 1)


def within_rate(
    sessions: sessionmaker[Session],
    budgets: rate_limit.LocalBudgets,
    timing: Timing,
    limit: int,
    camera_id: str,
) -> bool:
    """Whether the camera may store one more frame this minute (``_check_rate``'s budget),
    spending it: for the frames the service pulls, in a worker thread."""
    if limit <= 0:
        return True
    minute = rate_limit.minute_of(timing.now())
    if budgets.take(camera_id, minute):
        return True
    with sessions.begin() as session:
        granted = rate_limit.reserve(session, camera_id, minute, limit)
    if granted <= 0:
        return False
    budgets.keep(camera_id, minute, granted - 1)
    return True


UploadTargetDep = Annotated[CameraInfo, Depends(get_upload_target)]
