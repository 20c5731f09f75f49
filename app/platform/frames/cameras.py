"""Registering cameras, and the reads of their frames that several domains share."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from datetime import datetime
from typing import Any, Protocol, TypeVar

from sqlalchemy import ColumnElement, ScalarSelect, Select, event, or_, select, tuple_
from sqlalchemy.exc import IntegrityError
from sqlalchemy.orm import QueryableAttribute, Session, selectinload

from app.platform.auth import hash_token, new_token
from app.platform.db.base import Base, utcnow
from app.platform.db.models import Camera, CameraKind, Frame
from app.platform.db.rows import select_rows
from app.platform.frames import sources
from app.platform.frames.camera_info import TokenCache, view_of
from app.platform.frames.ingest import check_fits
from app.platform.frames.kinds import KINDS
from app.platform.frames.writer import Credential, Refusal
from app.platform.http.errors import Conflict, NotFound, Unprocessable
from app.platform.lookup import get_or_404
from app.platform.schemas import CameraCreate, CameraUpdate
from app.platform.timing import Timing


class Identified(Protocol):
    id: str


class Located(Protocol):
    lat: float | None
    lon: float | None


class Retirable(Protocol):
    id: str
    retired_at: datetime | None


class Tokened(Retirable, Protocol):
    token_hash: str


def insert_new(session: Session, row: Identified, what: str) -> None:
    """Add a row whose id the caller chose: 409 when the id is taken, or was by a retired row."""
    existing = session.get(type(row), row.id)
    if existing is not None:
        retired = getattr(existing, "retired_at", None)
        if retired is not None:  # its history keeps the id: a new one would inherit it
            raise Conflict(
                f"a {what} with id {row.id!r} was retired at {retired.isoformat()}; ids are not "
                f"reused (its history is kept under it): choose another id",
                code=f"{what}_retired",
            )
        raise Conflict(f"a {what} with id {row.id!r} already exists")
    session.add(row)
    try:
        session.flush()
    except IntegrityError:  # a concurrent request inserted the same id first
        raise Conflict(f"a {what} with id {row.id!r} already exists") from None


def _check_panel(session: Session, kind: CameraKind, panel_id: str | None) -> None:
    if panel_id is None:
        return
    if kind != CameraKind.panel:
        raise Unprocessable(f"panel_id is only for panel cameras, not {kind.value}")
    KINDS[kind].check_camera(session, panel_id)


def check_located(row: Located) -> None:
    """A place is a latitude and a longitude: one alone (a camera that would silently stay
    off the air map) is refused, as a request or as the result of a change."""
    if (row.lat is None) != (row.lon is None):
        given = "lat" if row.lat is not None else "lon"
        raise Unprocessable(
            f"{given} without {'lon' if given == 'lat' else 'lat'}: a place needs both "
            "(or neither)",
            code="half_a_place",
        )


def create_camera(session: Session, data: CameraCreate) -> tuple[Camera, str]:
    """Register a camera; returns it with its token (the only time the token is seen)."""
    _check_panel(session, data.kind, data.panel_id)
    token = new_token("vc")
    camera = Camera(**data.model_dump(exclude={"source"}), token_hash=hash_token(token))
    check_located(camera)
    insert_new(session, camera, "camera")
    if data.source is not None:
        sources.set_source(session, camera.id, data.source, utcnow())
        session.flush()
    return camera, token


def get_camera(session: Session, camera_id: str) -> Camera:
    return get_or_404(session, Camera, camera_id, "camera")


def check_in_service(row: Retirable) -> None:
    """Refuse (409 ``camera_retired``, ``robot_retired``, ``panel_retired``) to act for a
    retired camera or robot, or to attach a camera to or train a baseline for a retired
    panel."""
    if row.retired_at is not None:
        what = type(row).__name__.lower()
        raise Conflict(
            f"{what} {row.id!r} was retired at {row.retired_at.isoformat()}",
            code=f"{what}_retired",
        )


def retire_row(row: Tokened, token_prefix: str, timing: Timing) -> bool:
    """Mark the row retired and replace its token hash by that of a token nobody holds; False
    (and nothing changed) when it already was."""
    if row.retired_at is not None:
        return False
    row.retired_at = timing.now()
    row.token_hash = hash_token(new_token(token_prefix))
    return True


def _in_service(session: Session, camera_id: str) -> Camera:
    camera = get_camera(session, camera_id)
    check_in_service(camera)
    return camera


def _check_region_fits(session: Session, camera: Camera) -> None:
    """Refuse a region that would not fit the camera's latest frame: its next frames, if of
    that size, would all be refused. (A camera about to send larger frames gets its new region
    after its first one.)"""
    latest = session.execute(_newest(camera.id, Frame.width, Frame.height)).first()
    if latest is None:
        return
    try:
        check_fits(camera.roi, *latest)
    except ValueError as exc:
        raise Unprocessable(
            f"{exc} the camera sent last; its frames of that size would all be refused"
        ) from None


def _forget_on_commit(session: Session, tokens: TokenCache, camera_id: str) -> None:
    """Drop this process's cached view of the camera once the change is committed (not before:
    a concurrent upload could cache the old row again). Other processes' caches expire within
    their ``TokenCache.ttl``."""
    event.listen(session, "after_commit", lambda _: tokens.forget(camera_id), once=True)


def refusals(session: Session, credentials: set[Credential]) -> dict[Credential, Refusal]:
    """Which (camera id, token hash, view) triples no longer hold, and how: ``revoked``, the
    token was replaced or its camera retired; ``changed``, the camera is now of another kind,
    watches another panel or measures another region (``view_of``), so a frame measured by
    the old view must be measured again. One query for all of them, made by the group-commit
    writer in every batch of frames, so sent through the driver (``select_rows``). A None
    token or view is not checked (an upload with the admin token has no token of the
    camera's)."""
    ids = sorted({camera_id for camera_id, _, _ in credentials})
    marks = ", ".join("?" * len(ids))
    sql = (
        "SELECT id, token_hash, kind, panel_id, roi FROM cameras"
        f" WHERE retired_at IS NULL AND id IN ({marks})"
    )
    if session.get_bind().dialect.name == "postgresql":
        # the lock the batch's frame rows take on their cameras anyway (their foreign key),
        # taken now: a change of kind (``_check_no_frames``, FOR UPDATE) either waits for
        # this batch and then sees its frames, or is seen by this check
        sql += " ORDER BY id FOR KEY SHARE"
    now = {
        camera_id: (token_hash, view_of(kind, panel_id, roi))
        for camera_id, token_hash, kind, panel_id, roi in select_rows(session, sql, ids)
    }
    out: dict[Credential, Refusal] = {}
    for credential in credentials:
        camera_id, token_hash, view = credential
        found = now.get(camera_id)
        if found is None:  # retired: its token went with it
            out[credential] = "revoked" if token_hash is not None else "changed"
        elif token_hash is not None and token_hash != found[0]:
            out[credential] = "revoked"
        elif view is not None and view != found[1]:
            out[credential] = "changed"
    return out


def _check_no_frames(session: Session, camera: Camera) -> None:
    """Refuse (409 ``camera_has_frames``) to change the kind of a camera that has stored a
    frame: its verdicts are of its kind. Takes the camera's row first (PostgreSQL): a batch
    storing the camera's first frame holds it from its check of the cameras (``refusals``)
    to its commit, so this either waits for that batch and finds its frame, or goes first and
    the batch's check finds the new kind (and the frame is measured again as that kind)."""
    session.execute(select(Camera.id).where(Camera.id == camera.id).with_for_update())
    if session.execute(select(Frame.id).where(Frame.camera_id == camera.id).limit(1)).first():
        raise Conflict(
            f"camera {camera.id!r} has stored frames as a {camera.kind.value} camera: its kind "
            "cannot change; register a camera of the other kind (and retire this one)",
            code="camera_has_frames",
        )


def update_camera(
    session: Session, camera_id: str, data: CameraUpdate, tokens: TokenCache
) -> Camera:
    """Change the fields ``data`` carries (``null`` clears one); frames uploaded after the
    commit are judged with the new region."""
    camera = _in_service(session, camera_id)
    changes = data.model_dump(include=data.model_fields_set - {"source"})
    if "source" in data.model_fields_set:
        sources.set_source(session, camera_id, data.source, utcnow())
    kind = changes.get("kind", camera.kind)
    if kind is None:
        raise Unprocessable("kind cannot be cleared: give panel, sky or rig")
    if kind != camera.kind:
        _check_no_frames(session, camera)
    if "panel_id" in changes or kind != camera.kind:
        _check_panel(session, kind, changes.get("panel_id", camera.panel_id))
    for field, value in changes.items():
        setattr(camera, field, value)
    check_located(camera)
    if changes.get("roi") is not None:  # on error the request's transaction is rolled back
        _check_region_fits(session, camera)
    session.flush()
    _forget_on_commit(session, tokens, camera_id)
    return camera


def rotate_camera_token(session: Session, camera_id: str, tokens: TokenCache) -> tuple[Camera, str]:
    """A new upload token for the camera; the old one stops working. Returns the camera and
    the new token (the only time it is seen)."""
    camera = _in_service(session, camera_id)
    token = new_token("vc")
    camera.token_hash = hash_token(token)
    session.flush()
    _forget_on_commit(session, tokens, camera_id)
    return camera, token


def retire_camera(session: Session, camera_id: str, tokens: TokenCache, timing: Timing) -> None:
    """Take the camera out of service: its token stops working (replaced by the hash of one
    nobody holds), its frames are refused, and it leaves the air map and the default camera
    list. Its history stays. Retiring a retired camera changes nothing."""
    if retire_row(get_camera(session, camera_id), "vc", timing):
        session.flush()
        _forget_on_commit(session, tokens, camera_id)


Listed = TypeVar("Listed", bound=Base)


def listed(
    session: Session, model: type[Listed], *, limit: int, offset: int, retired: bool = False
) -> Sequence[Listed]:
    """Rows in service of a model with ``id`` and ``retired_at`` columns (cameras, robots,
    panels), by id; with ``retired``, the retired ones too."""
    columns: Any = model
    q = select(model)
    if not retired:
        q = q.where(columns.retired_at.is_(None))
    return session.scalars(q.order_by(columns.id).limit(limit).offset(offset)).all()


def _newest(camera_id: str | QueryableAttribute[str], *columns: Any) -> Select[Any]:
    """``columns`` of the camera's newest frame kept (the (camera_id, captured_at) index)."""
    return (
        select(*columns)
        .where(Frame.camera_id == camera_id)
        .order_by(Frame.captured_at.desc())
        .limit(1)
    )


def _last_captured() -> ScalarSelect[datetime]:
    """The capture time of a camera's newest frame kept, correlated: one lookup per camera."""
    return _newest(Camera.id, Frame.captured_at).correlate(Camera).scalar_subquery()


def cameras_seen(
    session: Session,
    *,
    limit: int,
    offset: int,
    retired: bool = False,
    silent_since: datetime | None = None,
    kind: CameraKind | None = None,
    panel_id: str | None = None,
) -> list[tuple[Camera, datetime | None]]:
    """Cameras (as ``listed``) with their newest frame's capture time; with ``silent_since``,
    only those with no frame taken since then (or none kept); of one ``kind``, or watching
    ``panel_id`` (404 when there is no such panel: a mistyped id is not a panel without
    cameras)."""
    if panel_id is not None and not KINDS[CameraKind.panel].link_exists(session, panel_id):
        raise NotFound(f"no panel {panel_id!r}")
    last = _last_captured()
    q = select(Camera, last)
    if not retired:
        q = q.where(Camera.retired_at.is_(None))
    if kind is not None:
        q = q.where(Camera.kind == kind)
    if panel_id is not None:
        q = q.where(Camera.panel_id == panel_id)
    if silent_since is not None:
        q = q.where(or_(last.is_(None), last < silent_since))
    rows = session.execute(q.order_by(Camera.id).limit(limit).offset(offset)).all()
    return [(camera, when) for camera, when in rows]


def last_captured_at(session: Session, camera_id: str) -> datetime | None:
    """The capture time of the camera's newest frame kept."""
    found: datetime | None = session.scalars(_newest(camera_id, Frame.captured_at)).first()
    return found


@dataclass(frozen=True, slots=True)
class FrameKey:
    """Where a page of frames, newest first, ended: the next page starts after it."""

    captured_at: datetime
    frame_id: str


NEWEST_FIRST = (Frame.captured_at.desc(), Frame.id.desc())
"""Frames newest first, ties by id: the order of ``ix_frames_captured_at_id`` read backwards."""


def after(key: FrameKey | None) -> list[ColumnElement[bool]]:
    """Frames after ``key`` in ``NEWEST_FIRST`` order (keyset paging: a page costs the same
    however deep, and frames arriving meanwhile shift nothing)."""
    if key is None:
        return []
    return [tuple_(Frame.captured_at, Frame.id) < tuple_(key.captured_at, key.frame_id)]


def taken_in(
    camera_id: str | Sequence[str] | None, since: datetime | None, until: datetime | None
) -> list[ColumnElement[bool]]:
    """Conditions on frames: one camera's (or several, or all), taken in [since, until)."""
    conditions = []
    if isinstance(camera_id, str):
        conditions.append(Frame.camera_id == camera_id)
    elif camera_id is not None:
        conditions.append(Frame.camera_id.in_(camera_id))
    if since is not None:
        conditions.append(Frame.captured_at >= since)
    if until is not None:
        conditions.append(Frame.captured_at < until)
    return conditions


def frames_of(
    session: Session,
    camera_id: str,
    *,
    since: datetime | None,
    until: datetime | None,
    limit: int,
    offset: int,
    cursor: FrameKey | None = None,
) -> Sequence[Frame]:
    """A camera's frames taken in [since, until), newest first (after ``cursor``), with their
    verdicts."""
    get_camera(session, camera_id)
    return session.scalars(
        select(Frame)
        .where(*taken_in(camera_id, since, until), *after(cursor))
        .options(selectinload(Frame.verdict))
        .order_by(*NEWEST_FIRST)
        .limit(limit)
        .offset(offset)
    ).all()
