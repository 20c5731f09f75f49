"""Request dependencies, declared once: the session, the caller, and the role checks."""

from __future__ import annotations

import base64
import binascii
import hmac
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Annotated, Literal

from fastapi import Depends, Path, Request
from sqlalchemy import select
from sqlalchemy.orm import Session, sessionmaker

from app.db.models import Camera, Robot
from app.errors import Forbidden, NotFound, Unauthorized
from app.security import hash_token
from app.settings import Settings

ID_PATTERN = r"^[A-Za-z0-9._-]{1,64}$"


def get_sessionmaker(request: Request) -> sessionmaker[Session]:
    sm: sessionmaker[Session] = request.app.state.sessionmaker
    return sm


def get_settings(request: Request) -> Settings:
    settings: Settings = request.app.state.settings
    return settings


def get_session(request: Request) -> Iterator[Session]:
    """The request's unit of work: commits once on success, rolls back on any error.

    Services only ``flush()``; nothing else commits.
    """
    with get_sessionmaker(request)() as session:
        try:
            yield session
            session.commit()
        except BaseException:
            session.rollback()
            raise


SessionDep = Annotated[Session, Depends(get_session)]
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


def get_principal(request: Request) -> Principal:
    """Authenticate the caller: admin, camera or robot. Missing or unknown token → 401.

    The lookup uses its own short read-only session, so the request's unit of work does not hold
    a transaction open while the request body is read and decoded.
    """
    header = request.headers.get("authorization")
    if not header:
        raise Unauthorized("missing Authorization header")
    token, basic_user = _credentials(header)
    digest = hash_token(token)
    if hmac.compare_digest(digest, request.app.state.admin_token_hash):
        return Principal("admin")
    with get_sessionmaker(request)() as session:
        camera_id = session.scalar(select(Camera.id).where(Camera.token_hash == digest))
        if camera_id is not None:
            if basic_user is not None and basic_user != camera_id:
                raise Unauthorized("the Basic user name is not the camera this token belongs to")
            return Principal("camera", camera_id)
        robot_id = session.scalar(select(Robot.id).where(Robot.token_hash == digest))
        if robot_id is not None:
            return Principal("robot", robot_id)
    raise Unauthorized("unknown token")


PrincipalDep = Annotated[Principal, Depends(get_principal)]


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


def camera_auth(camera_id: CameraId, principal: PrincipalDep) -> Principal:
    """The camera's own token (Bearer or Basic) or the admin token; another camera's → 403."""
    if principal.role == "admin":
        return principal
    if principal.role == "camera" and principal.id == camera_id:
        return principal
    if principal.role == "camera":
        raise Forbidden("this camera's token may only post frames for its own camera")
    raise Forbidden(f"a {principal.role} token may not post frames")


CameraAuth = Annotated[Principal, Depends(camera_auth)]


@dataclass(frozen=True, slots=True)
class UploadTarget:
    """The camera a frame is posted for, checked before its body is read."""

    id: str
    roi: tuple[int, int, int, int] | None


def get_upload_target(camera_id: CameraId, principal: CameraAuth, request: Request) -> UploadTarget:
    with get_sessionmaker(request)() as session:
        row = session.execute(select(Camera.id, Camera.roi).where(Camera.id == camera_id)).first()
    if row is None:
        raise NotFound(f"no camera {camera_id!r}")
    roi = (row.roi[0], row.roi[1], row.roi[2], row.roi[3]) if row.roi else None
    return UploadTarget(row.id, roi)


UploadTargetDep = Annotated[UploadTarget, Depends(get_upload_target)]
