"""Tables. The schema is built only by the Alembic migrations in ``migrations/``."""

from __future__ import annotations

import enum
from datetime import datetime
from typing import Any

from sqlalchemy import (
    JSON,
    BigInteger,
    Boolean,
    Enum,
    Float,
    ForeignKey,
    Index,
    Integer,
    SmallInteger,
    String,
    UniqueConstraint,
    true,
)
from sqlalchemy.orm import Mapped, mapped_column, relationship

from app.platform.db.base import Base, UTCDateTime, utcnow

ID_LENGTH = 64


class CameraKind(enum.StrEnum):
    panel = "panel"
    sky = "sky"
    rig = "rig"


class TimestampMixin:
    created_at: Mapped[datetime] = mapped_column(UTCDateTime(), default=utcnow)
    """When the row was written [UTC]."""


class Camera(TimestampMixin, Base):
    __tablename__ = "cameras"

    id: Mapped[str] = mapped_column(String(ID_LENGTH), primary_key=True)
    kind: Mapped[CameraKind] = mapped_column(
        Enum(CameraKind, native_enum=False, length=16, validate_strings=True)
    )
    name: Mapped[str | None] = mapped_column(String(200))
    lat: Mapped[float | None] = mapped_column(Float)
    lon: Mapped[float | None] = mapped_column(Float)
    panel_id: Mapped[str | None] = mapped_column(ForeignKey("panels.id"), index=True)
    roi: Mapped[list[int] | list[list[int]] | None] = mapped_column(JSON)
    """Region of interest [x, y, w, h] in pixels of the full frame, or none for the whole frame."""
    token_hash: Mapped[str] = mapped_column(String(64), unique=True)
    """SHA-256 of the camera's token (the token itself is shown once and never stored)."""
    retired_at: Mapped[datetime | None] = mapped_column(UTCDateTime(), default=None)
    """When the camera was taken out of service: it posts no more frames, leaves the air map,
    and keeps its history (its frames go with the retention like any others)."""
    attention: Mapped[list[str] | None] = mapped_column(JSON, default=None)
    """What a domain asks of the camera's operator ("recalibrate: …"); None: nothing."""


class CameraSource(Base):
    """Where the service pulls a camera's frames from (a stream or a snapshot URL), and how
    pulling it goes. Its lease names the one process pulling it."""

    __tablename__ = "camera_sources"
    __table_args__ = (Index("ix_camera_sources_next_due_at", "next_due_at"),)

    camera_id: Mapped[str] = mapped_column(ForeignKey("cameras.id"), primary_key=True)
    url: Mapped[str] = mapped_column(String(2048))
    """rtsp://, http:// or https://, without credentials."""
    every_seconds: Mapped[int] = mapped_column(Integer)
    username: Mapped[str | None] = mapped_column(String(200))
    password: Mapped[str | None] = mapped_column(String(200))
    """Write-only: never returned by the API, never logged."""
    state: Mapped[str] = mapped_column(String(16), default="connecting")
    """connecting (none taken yet), ok, unreachable or bad_stream."""
    failures: Mapped[int] = mapped_column(Integer, default=0)
    """Failed pulls in a row (the back-off's exponent)."""
    last_error: Mapped[str | None] = mapped_column(String(500))
    last_error_at: Mapped[datetime | None] = mapped_column(UTCDateTime())
    last_frame_at: Mapped[datetime | None] = mapped_column(UTCDateTime())
    last_frame_id: Mapped[str | None] = mapped_column(String(36))
    next_due_at: Mapped[datetime] = mapped_column(UTCDateTime())
    lease_owner: Mapped[str | None] = mapped_column(String(64))
    lease_expires_at: Mapped[datetime | None] = mapped_column(UTCDateTime())


class Frame(Base):
    __tablename__ = "frames"
    __table_args__ = (
        Index("ix_frames_camera_id_captured_at", "camera_id", "captured_at"),
        # every camera's frames newest first, paged by (captured_at, id): the public readings
        Index("ix_frames_captured_at_id", "captured_at", "id"),
        # a camera retrying an upload: the same bytes taken at the same instant are one frame
        UniqueConstraint("camera_id", "sha256", "captured_at", name="uq_frames_camera_sha_time"),
        UniqueConstraint("camera_id", "idempotency_key", name="uq_frames_camera_idempotency"),
    )

    id: Mapped[str] = mapped_column(String(36), primary_key=True)
    camera_id: Mapped[str] = mapped_column(ForeignKey("cameras.id"))
    captured_at: Mapped[datetime] = mapped_column(UTCDateTime())
    received_at: Mapped[datetime] = mapped_column(UTCDateTime(), index=True)
    width: Mapped[int] = mapped_column(Integer)
    """[px]"""
    height: Mapped[int] = mapped_column(Integer)
    """[px]"""
    size_bytes: Mapped[int] = mapped_column(BigInteger)
    sha256: Mapped[str] = mapped_column(String(64))
    """Looked up only with the camera (``uq_frames_camera_sha_time``)."""
    stored_path: Mapped[str | None] = mapped_column(String(200), index=True)
    """Where the frame store keeps the JPEG (the locator its ``put`` returned), or none.
    Indexed: the sweeps ask which of a store's files and packs some row still refers to."""
    idempotency_key: Mapped[str | None] = mapped_column(String(128))
    """The client's ``Idempotency-Key``: a retry with the same key gets the original frame."""

    verdict: Mapped[Verdict] = relationship(back_populates="frame", lazy="raise")


class Verdict(Base):
    """What the service concluded from one frame, typed by the camera's kind.

    Every kind keeps the per-channel statistics the conclusion rests on.
    """

    __tablename__ = "verdicts"

    frame_id: Mapped[str] = mapped_column(ForeignKey("frames.id"), primary_key=True)
    kind: Mapped[CameraKind] = mapped_column(
        Enum(CameraKind, native_enum=False, length=16, validate_strings=True)
    )
    camera_id: Mapped[str] = mapped_column(ForeignKey("cameras.id"), index=True)
    mode_r: Mapped[int] = mapped_column(SmallInteger)
    mode_g: Mapped[int] = mapped_column(SmallInteger)
    mode_b: Mapped[int] = mapped_column(SmallInteger)
    mean_r: Mapped[float] = mapped_column(Float)
    mean_g: Mapped[float] = mapped_column(Float)
    mean_b: Mapped[float] = mapped_column(Float)
    reason: Mapped[str | None] = mapped_column(String(200))
    """Why no conclusion was drawn, when none was."""
    details: Mapped[dict[str, Any] | None] = mapped_column(JSON)
    """Further numbers behind the verdict (features, quality gate readings)."""
    roi: Mapped[list[int] | list[list[int]] | None] = mapped_column(JSON)
    """The camera's region of interest the statistics were measured in; null: the whole frame."""
    usable: Mapped[bool] = mapped_column(Boolean, server_default=true())
    """False when the quality gate found the region unusable (night, glare, blank, greyscale,
    occluded; ``reason`` says which): its modes say nothing of the panel or the sky, and no
    baseline or calibration may be made from it."""

    frame: Mapped[Frame] = relationship(back_populates="verdict", lazy="raise")

    __mapper_args__ = {"polymorphic_on": "kind", "polymorphic_identity": CameraKind.rig}

    @property
    def modes(self) -> list[int]:
        return [self.mode_r, self.mode_g, self.mode_b]

    @property
    def means(self) -> list[float]:
        return [self.mean_r, self.mean_g, self.mean_b]


class RateBudget(Base):
    """How much of a camera's per-minute frame budget the processes have reserved: one row a
    camera, reset when a new minute starts (see ``app.platform.frames.rate_limit``)."""

    __tablename__ = "rate_budgets"

    camera_id: Mapped[str] = mapped_column(
        String(ID_LENGTH), ForeignKey("cameras.id", ondelete="CASCADE"), primary_key=True
    )
    window_start: Mapped[datetime] = mapped_column(UTCDateTime())
    """The minute the reservations count against."""
    used: Mapped[int] = mapped_column(Integer)
    """Frames reserved in that minute, by all processes together (may pass the limit: the
    excess was not granted)."""


class OutboxMessage(Base):
    """An event for a topic's webhook (``platform.outbox``), kept until delivered or too old:
    written in the transaction that made it happen, so an event is sent if and only if its
    cause was committed, and a restart loses none."""

    __tablename__ = "outbox_messages"
    __table_args__ = (Index("ix_outbox_messages_topic_delivered", "topic", "delivered"),)

    id: Mapped[str] = mapped_column(String(36), primary_key=True)
    topic: Mapped[str] = mapped_column(String(32))
    type: Mapped[str] = mapped_column(String(48))
    created_at: Mapped[datetime] = mapped_column(UTCDateTime(), index=True)
    payload: Mapped[dict[str, Any]] = mapped_column(JSON)
    delivered: Mapped[bool] = mapped_column(Boolean, default=False)
    attempts: Mapped[int] = mapped_column(Integer, default=0)
    next_attempt_at: Mapped[datetime | None] = mapped_column(UTCDateTime())
    last_error: Mapped[str | None] = mapped_column(String(500))


class WebhookSubscription(Base):
    """Where a topic's events go (one receiver per topic), and the secret that signs them."""

    __tablename__ = "webhook_subscriptions"

    topic: Mapped[str] = mapped_column(String(32), primary_key=True)
    url: Mapped[str] = mapped_column(String(2000))
    secret: Mapped[str | None] = mapped_column(String(200))
    """Standard Webhooks ``whsec_…``; none: unsigned."""
    updated_at: Mapped[datetime] = mapped_column(UTCDateTime())


class ViewerToken(TimestampMixin, Base):
    """A read-only token: it may open the farm and cells boards and their read endpoints, and
    nothing else (a kiosk's, a visitor's). Revoked by deleting its row."""

    __tablename__ = "viewer_tokens"

    id: Mapped[str] = mapped_column(String(36), primary_key=True)
    name: Mapped[str] = mapped_column(String(200))
    token_hash: Mapped[str] = mapped_column(String(64), unique=True)
    """SHA-256 of the token (shown once, never stored)."""


class SigninCode(Base):
    """A one-time code that a page exchanges for a new viewer token: a kiosk's link carries the
    code, never a token, so no long-lived secret lands in an address or a browser's history."""

    __tablename__ = "signin_codes"

    code_hash: Mapped[str] = mapped_column(String(64), primary_key=True)
    name: Mapped[str] = mapped_column(String(200))
    """The name the viewer token made from it will carry."""
    expires_at: Mapped[datetime] = mapped_column(UTCDateTime(), index=True)
