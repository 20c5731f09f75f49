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
)
from sqlalchemy.orm import Mapped, mapped_column, relationship

from app.db.base import Base, UTCDateTime, utcnow

ID_LENGTH = 64


class CameraKind(enum.StrEnum):
    panel = "panel"
    sky = "sky"
    rig = "rig"


class TimestampMixin:
    created_at: Mapped[datetime] = mapped_column(UTCDateTime(), default=utcnow)
    """When the row was written [UTC]."""


class Panel(TimestampMixin, Base):
    __tablename__ = "panels"

    id: Mapped[str] = mapped_column(String(ID_LENGTH), primary_key=True)
    name: Mapped[str | None] = mapped_column(String(200))
    lat: Mapped[float | None] = mapped_column(Float)
    """Latitude [°], WGS 84."""
    lon: Mapped[float | None] = mapped_column(Float)
    """Longitude [°], WGS 84."""


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
    roi: Mapped[list[int] | None] = mapped_column(JSON)
    """Region of interest [x, y, w, h] in pixels of the full frame, or none for the whole frame."""
    token_hash: Mapped[str] = mapped_column(String(64), unique=True)
    """SHA-256 of the camera's token (the token itself is shown once and never stored)."""

    panel: Mapped[Panel | None] = relationship(lazy="raise")


class Robot(TimestampMixin, Base):
    __tablename__ = "robots"

    id: Mapped[str] = mapped_column(String(ID_LENGTH), primary_key=True)
    name: Mapped[str | None] = mapped_column(String(200))
    token_hash: Mapped[str] = mapped_column(String(64), unique=True)


class Frame(Base):
    __tablename__ = "frames"
    __table_args__ = (Index("ix_frames_camera_id_captured_at", "camera_id", "captured_at"),)

    id: Mapped[str] = mapped_column(String(36), primary_key=True)
    camera_id: Mapped[str] = mapped_column(ForeignKey("cameras.id"))
    captured_at: Mapped[datetime] = mapped_column(UTCDateTime())
    received_at: Mapped[datetime] = mapped_column(UTCDateTime(), index=True)
    width: Mapped[int] = mapped_column(Integer)
    """[px]"""
    height: Mapped[int] = mapped_column(Integer)
    """[px]"""
    size_bytes: Mapped[int] = mapped_column(BigInteger)
    sha256: Mapped[str] = mapped_column(String(64), index=True)
    stored_path: Mapped[str | None] = mapped_column(String(200))
    """Path of the JPEG relative to the data directory (content-addressed), or none."""

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

    frame: Mapped[Frame] = relationship(back_populates="verdict", lazy="raise")

    __mapper_args__ = {"polymorphic_on": "kind", "polymorphic_identity": CameraKind.rig}

    @property
    def modes(self) -> list[int]:
        return [self.mode_r, self.mode_g, self.mode_b]

    @property
    def means(self) -> list[float]:
        return [self.mean_r, self.mean_g, self.mean_b]


class PanelVerdict(Verdict):
    __tablename__ = "panel_verdicts"

    frame_id: Mapped[str] = mapped_column(ForeignKey("verdicts.frame_id"), primary_key=True)
    panel_id: Mapped[str | None] = mapped_column(ForeignKey("panels.id"), index=True)
    clean: Mapped[bool | None] = mapped_column(Boolean)
    t2: Mapped[float | None] = mapped_column(Float)
    f_stat: Mapped[float | None] = mapped_column(Float)
    p_value: Mapped[float | None] = mapped_column(Float)
    threshold: Mapped[float | None] = mapped_column(Float)
    state: Mapped[str | None] = mapped_column(String(32))

    __mapper_args__ = {"polymorphic_identity": CameraKind.panel, "polymorphic_load": "inline"}


class SkyVerdict(Verdict):
    __tablename__ = "sky_verdicts"

    frame_id: Mapped[str] = mapped_column(ForeignKey("verdicts.frame_id"), primary_key=True)
    level: Mapped[int | None] = mapped_column(SmallInteger)
    category: Mapped[str | None] = mapped_column(String(16))

    __mapper_args__ = {"polymorphic_identity": CameraKind.sky, "polymorphic_load": "inline"}
