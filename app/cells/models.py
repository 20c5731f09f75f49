"""Robot-cell tables. The schema is built only by the Alembic migrations in ``migrations/``."""

from __future__ import annotations

from datetime import datetime
from typing import Any

from sqlalchemy import (
    JSON,
    String,
)
from sqlalchemy.orm import Mapped, mapped_column

from app.platform.db.base import Base, UTCDateTime
from app.platform.db.models import ID_LENGTH


class Calibration(Base):
    """A camera (or stereo pair) calibrated from checkerboard views."""

    __tablename__ = "calibrations"

    id: Mapped[str] = mapped_column(String(36), primary_key=True)
    created_at: Mapped[datetime] = mapped_column(UTCDateTime(), index=True)
    kind: Mapped[str] = mapped_column(String(16))
    """single or stereo."""
    result: Mapped[dict[str, Any]] = mapped_column(JSON)
    """K, dist, RMS, per-view RMS, standard deviations, views used and rejected (and for a
    stereo pair both cameras, R, T and the baseline)."""


class Rig(Base):
    """A measuring rig: the 4-camera cross or any set of calibrated cameras."""

    __tablename__ = "rigs"

    id: Mapped[str] = mapped_column(String(ID_LENGTH), primary_key=True)
    kind: Mapped[str] = mapped_column(String(16))
    """cross or calibrated."""
    spec: Mapped[dict[str, Any]] = mapped_column(JSON)
    created_at: Mapped[datetime] = mapped_column(UTCDateTime())
    updated_at: Mapped[datetime | None] = mapped_column(UTCDateTime())
    """When its geometry was last replaced."""
