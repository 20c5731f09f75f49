"""Cameras and their frames."""

from __future__ import annotations

import asyncio
import json
import time
from datetime import datetime, timedelta
from functools import partial
from typing import Annotated, Any, TypeVar

import cv2
from fastapi import APIRouter, Header, Query, Request
from fastapi.concurrency import run_in_threadpool
from fastapi.responses import Response
from pydantic import TypeAdapter, ValidationError
from sqlalchemy import select
from sqlalchemy.orm import Session, selectinload
from sqlalchemy.orm.interfaces import ORMOption

from app.platform.db.models import Camera, CameraKind, CameraSource, Frame
from app.platform.db.session import release
from app.platform.frames import cameras, ingest, jpeg, regions, retention, sources
from app.platform.frames.camera_info import TokenCache
from app.platform.frames.deps import FrameCursor, UploadTargetDep, fresh_upload_target, link_next
from app.platform.frames.kinds import frame_out
from app.platform.frames.writer import CameraChanged, GroupCommitWriter
from app.platform.http.deps import (
    Admin,
    CameraId,
    IdFilter,
    Limit,
    Offset,
    Reader,
    RecordId,
    SessionDep,
    SettingsDep,
    TimeRangeQuery,
    TimingDep,
    UtcTime,
    get_principal,
    image_work,
)
from app.platform.http.errors import (
    Forbidden,
    NotFound,
    ServiceUnavailable,
    Unauthorized,
    Unprocessable,
)
from app.platform.http.responses import (
    AUTH_ERRORS,
    CAMERA_KEEPS_KIND,
    CAMERA_RETIRED,
    CONFLICT,
    NOT_FOUND,
    UNPROCESSABLE,
    UPLOAD_ERRORS,
    UPLOAD_UNAVAILABLE,
    not_modified,
)
from app.platform.http.uploads import FrameUpload, read_jpeg
from app.platform.observability import FRAMES_RECEIVED, INGEST_SECONDS
from app.platform.schemas import CameraCreate, CameraCreated, CameraOut, CameraUpdate, FrameOut
from app.platform.settings import Settings
from app.platform.state import app_state
from app.platform.timing import Timing

router = APIRouter(tags=["cameras"])

FRAMES_PATH = "/cameras/{camera_id}/frames"
# a camera's clock may run a little ahead; further ahead is a broken clock
MAX_CLOCK_SKEW = timedelta(minutes=10)
MEASURES = 3
"""Times a frame is measured when its camera keeps changing (through other processes) meanwhile."""

_JPEG_BODY = {
    "requestBody": {
        "required": True,
        "content": {
            "image/jpeg": {"schema": {"type": "string", "format": "binary"}},
            # what many cameras and scripts label any bytes: taken when they are a JPEG
            "application/octet-stream": {"schema": {"type": "string", "format": "binary"}},
            "multipart/form-data": {
                "schema": {
                    "type": "object",
                    "properties": {
                        "file": {"type": "string", "format": "binary"},
                        "captured_at": {
                            "type": "string",
                            "format": "date-time",
                            "description": "As the query parameter (either or both, equal).",
                        },
                    },
                    "required": ["file"],
                }
            },
        },
    }
}


def _captured_at(
    value: datetime | None, now: datetime, settings: Settings, backfill: bool = False
) -> datetime | None:
    """``captured_at`` when it is a time the service takes a frame of: not in the future, and
    within the upload window (``frame_retention_days``), or, for an archive imported by an
    admin (``backfill``), within the history it keeps (the longer of its two retentions). A
    camera whose clock was reset (1970, 2000) sent frames that were stored, graded and then
    never seen: a sky camera's latest reading and its place on the map stayed those of its
    last frame before the reset, and a panel's state ignored every new frame as a late
    upload."""
    if value is None:
        return None
    if value > now + MAX_CLOCK_SKEW:
        raise Unprocessable(f"captured_at {value.isoformat()} lies in the future", code="bad_time")
    keep = retention.kept_days(settings.frame_retention_days, settings.history_retention_days)
    window = keep if backfill else settings.frame_retention_days
    if value >= now - timedelta(days=window):
        return value
    if not backfill and keep > window and value >= now - timedelta(days=keep):
        raise Unprocessable(
            f"captured_at {value.isoformat()} is more than {window:g} days ago, older than a "
            f"camera's frames are taken: an archive's frames (within the {keep:g} days of "
            "history kept) are imported by an admin with backfill=true; else, is the camera's "
            "clock set (NTP)?",
            code="bad_time",
        )
    raise Unprocessable(
        f"captured_at {value.isoformat()} is more than {keep:g} days ago, before the "
        "history this service keeps: is the camera's clock set (NTP)?",
        code="bad_time",
    )


_TIME = TypeAdapter(UtcTime)


def _form_captured_at(
    text: str, query: datetime | None, now: datetime, settings: Settings, backfill: bool
) -> datetime | None:
    """A multipart upload's ``captured_at`` field: the same rules as the query parameter, and
    the same time when both are given (422 ``bad_time`` otherwise)."""
    try:
        value = _TIME.validate_python(text.strip())
    except ValidationError:
        raise Unprocessable(
            f"captured_at {text[:64]!r} is not an RFC 3339 time", code="bad_time"
        ) from None
    if query is not None and query != value:
        raise Unprocessable(
            f"captured_at differs between the query ({query.isoformat()}) and the form "
            f"({value.isoformat()})",
            code="bad_time",
        )
    return _captured_at(value, now, settings, backfill)


CapturedAt = Annotated[
    UtcTime | None,
    Query(description="When the frame was taken (RFC 3339; default: when received)."),
]
IdempotencyKey = Annotated[
    str | None,
    Header(
        max_length=128,
        description="Retries with the same key get the original response (as do retries "
        "of the same bytes with the same captured_at).",
    ),
]
Backfill = Annotated[
    bool,
    Query(
        description="An archive's frame (admin token): captured_at may be as old as the "
        "history kept (VANTAGE_HISTORY_RETENTION_DAYS), not only the upload window "
        "(VANTAGE_FRAME_RETENTION_DAYS); it is graded and smoothed in its own time and "
        "raises no alert."
    ),
]


async def _upload_and_time(
    request: Request,
    captured_at: datetime | None,
    timing: Timing,
    settings: Settings,
    backfill: bool,
) -> tuple[FrameUpload, datetime | None]:
    """The posted JPEG and its capture time (the query's, or the form's, checked alike)."""
    when = _captured_at(captured_at, timing.now(), settings, backfill)
    upload = await read_jpeg(request, settings.max_body_bytes)
    if upload.captured_at is not None:
        when = _form_captured_at(upload.captured_at, when, timing.now(), settings, backfill)
    return upload, when


@router.post(
    FRAMES_PATH,
    status_code=201,
    response_model=FrameOut,
    responses={
        **AUTH_ERRORS,
        **NOT_FOUND,
        **CAMERA_RETIRED,
        **UPLOAD_ERRORS,
        **UPLOAD_UNAVAILABLE,
    },
    openapi_extra=_JPEG_BODY,
)
async def post_frame(
    request: Request,
    target: UploadTargetDep,
    settings: SettingsDep,
    timing: TimingDep,
    captured_at: CapturedAt = None,
    idempotency_key: IdempotencyKey = None,
    backfill: Backfill = False,
) -> Response:
    """Post a frame (raw ``image/jpeg`` body or multipart field ``file``); returns its verdict.

    A retried upload gets the original frame and verdict, with ``Idempotent-Replay: true``.
    """
    start = time.perf_counter()
    if backfill and get_principal(request).role != "admin":
        raise Forbidden("backfill=true imports an archive: the admin token only")
    upload, when = await _upload_and_time(request, captured_at, timing, settings, backfill)
    data = upload.data
    store = app_state(request).frame_store if settings.store_frames else None
    writer: GroupCommitWriter = app_state(request).writer

    prepare = partial(
        ingest.recording,
        store,
        data=data,
        captured_at=when,
        max_pixels=settings.max_pixels,
        timing=timing,
        idempotency_key=idempotency_key,
        backfill=backfill,
    )

    # decoding and the file write take one of the writer's preparing threads, which then queues
    # the database part itself; the wait for the commit takes no thread, so a stalled database
    # (a failover) holds none
    tokens: TokenCache = app_state(request).camera_tokens
    for _ in range(MEASURES):
        try:
            done = await _within(
                settings.upload_timeout_seconds,
                writer.submit_after(partial(prepare, target), credential=target.credential),
            )
            break
        except Unauthorized:  # the token was replaced, or the camera retired, elsewhere
            tokens.forget(target.id)  # the next upload looks it up, refused before its body
            raise
        except CameraChanged:  # moved to another panel or region through another process
            tokens.forget(target.id)
            target = await fresh_upload_target(request, target)
    else:
        raise ServiceUnavailable(
            f"camera {target.id} was changed {MEASURES} times while this frame was measured; "
            "send it again",
            retry_after=1,
            code="camera_changing",
        )
    if not done.replay:
        FRAMES_RECEIVED.labels(target.id).inc()
    INGEST_SECONDS.observe(time.perf_counter() - start)
    # answered as a Response (FastAPI's "return a Response directly"): the body is already a
    # FrameOut, and the route's response_model documents it without validating it again
    body = frame_out(done.frame, done.verdict).model_dump_json()
    headers = {"Idempotent-Replay": "true"} if done.replay else None
    return Response(body, status_code=201, media_type="application/json", headers=headers)


def _out(
    camera: Camera, last_captured_at: datetime | None, source: CameraSource | None = None
) -> CameraOut:
    out = CameraOut.model_validate(camera)
    out.last_captured_at = last_captured_at
    out.source = sources.source_out(source)
    out.source_state = out.source.state if out.source is not None else None
    return out


def _shown(session: Session, camera: Camera) -> CameraOut:
    """The camera as the API shows it, with its newest frame's capture time."""
    source = session.get(CameraSource, camera.id)
    return _out(camera, cameras.last_captured_at(session, camera.id), source)


def _with_token(session: Session, camera: Camera, token: str) -> CameraCreated:
    """The camera as the API shows it, with its upload token (shown only this once)."""
    return CameraCreated(**_shown(session, camera).model_dump(), token=token)


@router.post(
    "/cameras",
    status_code=201,
    response_model=CameraCreated,
    responses={**AUTH_ERRORS, **CONFLICT, **UNPROCESSABLE},
)
def create_camera(
    body: CameraCreate, session: SessionDep, settings: SettingsDep, _: Admin
) -> CameraCreated:
    """Register a camera; the response carries its upload token, shown only this once. A
    ``source`` whose host resolves to an address sources may not reach is refused (422)."""
    sources.check_address(body.source, settings.source_allowed_networks)
    camera, token = cameras.create_camera(session, body)
    return _with_token(session, camera, token)


@router.get("/cameras", response_model=list[CameraOut], responses={**AUTH_ERRORS, **NOT_FOUND})
def list_cameras(
    session: SessionDep,
    timing: TimingDep,
    _: Admin,
    limit: Limit = 100,
    offset: Offset = 0,
    retired: Annotated[
        bool, Query(description="Include retired cameras (by default only those in service).")
    ] = False,
    silent_for: Annotated[
        int | None,
        Query(
            ge=1,
            le=10 * 366 * 86400,
            description="Only cameras with no frame taken in the last … seconds (or none kept).",
        ),
    ] = None,
    kind: Annotated[CameraKind | None, Query(description="Only cameras of this kind.")] = None,
    panel_id: IdFilter = None,
) -> list[CameraOut]:
    """List cameras, ordered by id, each with when its newest frame was taken; ``silent_for``
    finds the cameras gone quiet, ``kind`` and ``panel_id`` those of a kind or watching a panel
    (404 when there is no such panel)."""
    since = None if silent_for is None else timing.now() - timedelta(seconds=silent_for)
    rows = cameras.cameras_seen(
        session,
        limit=limit,
        offset=offset,
        retired=retired,
        silent_since=since,
        kind=kind,
        panel_id=panel_id,
    )
    pulled = sources.sources_of(session, [camera.id for camera, _ in rows])
    return [_out(camera, last, pulled.get(camera.id)) for camera, last in rows]


@router.get(
    "/cameras/{camera_id}", response_model=CameraOut, responses={**AUTH_ERRORS, **NOT_FOUND}
)
def get_camera(camera_id: CameraId, session: SessionDep, _: Admin) -> CameraOut:
    """One camera."""
    return _shown(session, cameras.get_camera(session, camera_id))


@router.patch(
    "/cameras/{camera_id}",
    response_model=CameraOut,
    responses={
        **AUTH_ERRORS,
        **NOT_FOUND,
        **CAMERA_KEEPS_KIND,
        **UNPROCESSABLE,
    },
)
def update_camera(
    camera_id: CameraId,
    body: CameraUpdate,
    session: SessionDep,
    settings: SettingsDep,
    _: Admin,
    request: Request,
) -> CameraOut:
    """Change a camera's name, location, panel or region of interest (JSON merge: fields left
    out keep their value, ``null`` clears one), and its kind while it has stored no frame
    (409 ``camera_has_frames`` after). A region that would not fit the camera's latest frame
    is refused (422). Frames uploaded afterwards are judged with the new values, on every
    server process (each batch of frames checks its cameras again)."""
    sources.check_address(body.source, settings.source_allowed_networks)
    tokens: TokenCache = app_state(request).camera_tokens
    return _shown(session, cameras.update_camera(session, camera_id, body, tokens))


@router.post(
    "/cameras/{camera_id}/token",
    response_model=CameraCreated,
    responses={**AUTH_ERRORS, **NOT_FOUND, **CAMERA_RETIRED},
)
def rotate_camera_token(
    camera_id: CameraId, session: SessionDep, _: Admin, request: Request
) -> CameraCreated:
    """Issue the camera a new upload token, shown only this once; the old token stops working
    (at once on this server process, within ``VANTAGE_CAMERA_CACHE_SECONDS`` (10 s) on the
    others)."""
    tokens: TokenCache = app_state(request).camera_tokens
    camera, token = cameras.rotate_camera_token(session, camera_id, tokens)
    return _with_token(session, camera, token)


@router.delete(
    "/cameras/{camera_id}",
    status_code=204,
    response_class=Response,
    responses={**AUTH_ERRORS, **NOT_FOUND},
)
def retire_camera(
    camera_id: CameraId, session: SessionDep, timing: TimingDep, _: Admin, request: Request
) -> Response:
    """Retire a camera taken out of service. Its token stops working (at once on this server
    process, within ``VANTAGE_CAMERA_CACHE_SECONDS`` (10 s) on the others), frames for it are
    refused (409), and it leaves the air-quality map and the camera list (``?retired=true``
    shows it). Its frames, verdicts, readings and alerts stay readable until the retention
    removes them; its id stays taken. Retiring it again changes nothing."""
    tokens: TokenCache = app_state(request).camera_tokens
    cameras.retire_camera(session, camera_id, tokens, timing)
    return Response(status_code=204)


@router.get(
    "/cameras/{camera_id}/frames",
    response_model=list[FrameOut],
    responses={**AUTH_ERRORS, **NOT_FOUND, **UNPROCESSABLE},
)
def list_frames(
    camera_id: CameraId,
    session: SessionDep,
    _: Admin,
    span: TimeRangeQuery,
    request: Request,
    response: Response,
    limit: Limit = 50,
    offset: Offset = 0,
    cursor: FrameCursor = None,
) -> list[FrameOut]:
    """A camera's frames with their verdicts, newest first; those taken in [since, until).
    A full page names the next in its ``Link: <…>; rel="next"`` header (a ``cursor``)."""
    frames = cameras.frames_of(
        session,
        camera_id,
        since=span.since,
        until=span.until,
        limit=limit,
        offset=offset,
        cursor=cursor,
    )
    link_next(request, response, frames, limit)
    return [frame_out(f, f.verdict) for f in frames]


@router.get("/frames/{frame_id}", response_model=FrameOut, responses={**AUTH_ERRORS, **NOT_FOUND})
def get_frame(frame_id: RecordId, session: SessionDep, _: Admin) -> FrameOut:
    """One frame with its verdict."""
    frame = session.scalars(
        select(Frame).where(Frame.id == frame_id).options(selectinload(Frame.verdict))
    ).first()
    if frame is None:
        raise NotFound(f"no frame {frame_id!r}")
    return frame_out(frame, frame.verdict)


@router.get(
    "/frames/{frame_id}/image",
    response_class=Response,
    responses={
        200: {"content": {"image/jpeg": {}}},
        304: {"description": "The client already holds these bytes (If-None-Match)."},
        **AUTH_ERRORS,
        **NOT_FOUND,
    },
)
async def get_frame_image(
    frame_id: RecordId, session: SessionDep, _: Admin, request: Request
) -> Response:
    """The stored JPEG of a frame (304 when the client's ``If-None-Match`` already names it)."""
    frame = await run_in_threadpool(_frame_row, session, frame_id)
    if frame is None or frame.stored_path is None:
        raise NotFound(f"no stored image for frame {frame_id!r}")
    # content-addressed: the bytes behind this URL never change
    etag = f'"{frame.sha256}"'
    headers = {"ETag": etag, "Cache-Control": "private, max-age=31536000, immutable"}
    if not_modified(request.headers.get("if-none-match"), etag):
        return Response(status_code=304, headers=headers)
    data = await app_state(request).bounded_store.read(frame.stored_path)
    if data is None:
        raise NotFound(f"the image of frame {frame_id!r} is no longer kept")
    return Response(data, media_type="image/jpeg", headers=headers)


def _frame_row(session: Session, frame_id: str, *options: ORMOption) -> Frame | None:
    """The frame's row, the session then released: what follows waits on the frame store and
    on image work (an image read from a store that hung had held every request of the
    service on SQLite for as long)."""
    try:
        return session.get(Frame, frame_id, options=options)
    finally:
        release(session)


RegionQuery = Annotated[
    str | None,
    Query(
        max_length=2000,
        description="Preview another region before giving it to the camera: JSON, a rectangle "
        "[x, y, w, h] or a polygon [[x, y], ...] in the frame's pixels. Default: the region "
        "the frame's verdict was measured in.",
    ),
]


@router.get(
    "/frames/{frame_id}/region.jpg",
    response_class=Response,
    responses={
        200: {"content": {"image/jpeg": {}}},
        **AUTH_ERRORS,
        **NOT_FOUND,
        **UNPROCESSABLE,
    },
)
async def get_frame_region(
    frame_id: RecordId, session: SessionDep, _: Reader, request: Request, roi: RegionQuery = None
) -> Response:
    """The stored frame with the region its statistics were measured in outlined and the rest
    darkened: where a sky camera's region (clear of overlays, buildings and the sun) or a panel
    camera's panel lies, checked on a real frame; ``roi`` previews another region."""
    frame = await run_in_threadpool(_frame_row, session, frame_id, selectinload(Frame.verdict))
    if frame is None or frame.stored_path is None:
        raise NotFound(f"no stored image for frame {frame_id!r}")
    region = frame.verdict.roi if frame.verdict is not None else None
    if roi is not None:
        try:
            region = CameraUpdate.model_validate({"roi": json.loads(roi)}).roi
        except (ValueError, ValidationError) as exc:
            raise Unprocessable(f"roi is not a region: {exc}"[:300], code="bad_roi") from None
    try:
        ingest.check_fits(region, frame.width, frame.height)
    except ValueError as exc:
        raise Unprocessable(str(exc), code="roi_outside_frame") from None
    data = await app_state(request).bounded_store.read(frame.stored_path)
    if data is None:
        raise NotFound(f"the image of frame {frame_id!r} is no longer kept")
    body = await image_work(request, _outlined, data, region)
    return Response(body, media_type="image/jpeg", headers={"Cache-Control": "private"})


MAX_STORED_PIXELS = 1_000_000_000
"""A stored frame passed the pixel limit of its day; a lower one since does not hide it."""


def _outlined(data: bytes, region: list[Any] | None) -> bytes:
    image = jpeg.decode_rgb(data, max_pixels=MAX_STORED_PIXELS)[1]
    outlined = cv2.cvtColor(regions.outline_region(image, region), cv2.COLOR_RGB2BGR)
    ok, buf = cv2.imencode(".jpg", outlined, [cv2.IMWRITE_JPEG_QUALITY, 85])
    assert ok
    return bytes(buf.tobytes())


T = TypeVar("T")


async def _within(seconds: float, stored: asyncio.Future[T]) -> T:
    """The upload's result, or 503 after ``seconds``: a database that hangs (its disk stalled)
    held every upload and its body for as long, and cameras, timing out and sending again,
    queued more. On the deadline the job is cancelled: the writer drops it unless its batch
    is already being written (then the frame is stored, and the camera's retry of it is
    answered as a replay when it carries ``captured_at`` or an ``Idempotency-Key``)."""
    try:
        return await asyncio.wait_for(stored, seconds)
    except TimeoutError:
        raise ServiceUnavailable(
            f"the frame was not measured and stored within {seconds:g} s (the database or the "
            "disk is not answering, or the service is overloaded): send it again",
            code="upload_timeout",
        ) from None
