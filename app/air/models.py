"""Air-quality tables. The schema is built only by the Alembic migrations in ``migrations/``."""

from __future__ import annotations

from datetime import datetime
from typing import Any

from sqlalchemy import (
    JSON,
    Boolean,
    Float,
    ForeignKey,
    Integer,
    SmallInteger,
    String,
    false,
    true,
)
from sqlalchemy.orm import Mapped, mapped_column, relationship

from app.platform.db.base import Base, UTCDateTime
from app.platform.db.models import CameraKind, Verdict


class SkyVerdict(Verdict):
    __tablename__ = "sky_verdicts"

    frame_id: Mapped[str] = mapped_column(ForeignKey("verdicts.frame_id"), primary_key=True)
    level: Mapped[int | None] = mapped_column(SmallInteger)
    category: Mapped[str | None] = mapped_column(String(16))
    statistic: Mapped[float | None] = mapped_column(Float)
    """F of the accepting level's T² test (eq. 6.20)."""
    p_value: Mapped[float | None] = mapped_column(Float)
    calibration_id: Mapped[str | None] = mapped_column(ForeignKey("air_calibrations.id"))
    smoothed_level: Mapped[float | None] = mapped_column(Float)
    """The camera's NowCast-style level after this frame (``airquality.nowcasts``)."""
    uncertain: Mapped[bool] = mapped_column(Boolean, default=False, server_default=false())
    """The regression doubted its category (``reason`` says why): its probability is below
    ``public.SURE``, or the frame lies outside the calibration (no level then)."""
    probability: Mapped[float | None] = mapped_column(Float)
    """The probability of its category under the regression's predictive distribution."""
    smoothed_estimate: Mapped[float | None] = mapped_column(Float)
    smoothed_low: Mapped[float | None] = mapped_column(Float)
    smoothed_high: Mapped[float | None] = mapped_column(Float)
    """The camera's smoothed estimate after this frame and its range (``public.smooth``), in
    ``estimate_unit``."""
    smoothed_probability: Mapped[float | None] = mapped_column(Float)
    """The probability of the smoothed level's category."""
    poor_probability: Mapped[float | None] = mapped_column(Float)
    """The smoothed probability of Poor or worse: what alerts follow."""
    estimate: Mapped[float | None] = mapped_column(Float)
    """The regression's estimate in ``estimate_unit`` (PM2.5 µg/m³, US AQI or level)."""
    estimate_low: Mapped[float | None] = mapped_column(Float)
    estimate_high: Mapped[float | None] = mapped_column(Float)
    """Its prediction interval (``airquality.INTERVAL``)."""
    estimate_unit: Mapped[str | None] = mapped_column(String(8))
    span: Mapped[list[str] | None] = mapped_column(JSON)
    """[clearest, worst]: the categories an uncertain verdict's interval spans
    (``airquality.Estimate.span``)."""

    __mapper_args__ = {"polymorphic_identity": CameraKind.sky, "polymorphic_load": "inline"}


class AirCalibration(Base):
    """Level clusters from labelled sky images (eqs. 6.12–6.13)."""

    __tablename__ = "air_calibrations"

    id: Mapped[str] = mapped_column(String(36), primary_key=True)
    created_at: Mapped[datetime] = mapped_column(UTCDateTime(), index=True)
    clusters: Mapped[list[dict[str, Any]]] = mapped_column(JSON)
    """[{levels, level, n, mean_modes, covariance, f_critical, significance, ...}]"""
    warnings: Mapped[list[str]] = mapped_column(JSON)
    n_images: Mapped[int] = mapped_column(Integer)
    method: Mapped[str] = mapped_column(String(16), default="clusters", server_default="clusters")
    """How frames are graded: the T² clusters ([Fayed 2013]) or the regression."""
    regression: Mapped[dict[str, Any] | None] = mapped_column(JSON)
    """{mean, scale, coef, intercept} of the ridge regression on the sky features."""
    selection: Mapped[dict[str, Any] | None] = mapped_column(JSON)
    """How the method was chosen when none was asked for: {chosen, scores, score, folds}
    (``selection.Selection.kept``)."""
    frame_ids: Mapped[list[str] | None] = mapped_column(JSON)
    city_wide: Mapped[bool] = mapped_column(Boolean, default=True, server_default=true())
    """Made for no camera in particular: it grades every camera without one of its own."""

    cameras: Mapped[list[AirCalibrationCamera]] = relationship(lazy="raise")
    """The sky cameras this calibration grades (made for given cameras: ``city_wide`` false)."""

    @property
    def camera_ids(self) -> list[str]:
        return sorted(c.camera_id for c in self.cameras)


class AirCalibrationCamera(Base):
    """A sky camera graded by a calibration of its own (its view, its white balance) rather
    than by the city-wide one."""

    __tablename__ = "air_calibration_cameras"

    calibration_id: Mapped[str] = mapped_column(ForeignKey("air_calibrations.id"), primary_key=True)
    camera_id: Mapped[str] = mapped_column(ForeignKey("cameras.id"), primary_key=True, index=True)
    roi: Mapped[list[int] | list[list[int]] | None] = mapped_column(JSON)
    """The camera's region of interest when the calibration was made for it: it grades the
    camera's frames only while the camera measures them there."""


class AirAlert(Base):
    """A camera's smoothed level entered Poor or Very Poor (``raised``), or, after that, came
    back clearly out of Poor (``cleared``)."""

    __tablename__ = "air_alerts"

    id: Mapped[str] = mapped_column(String(36), primary_key=True)
    camera_id: Mapped[str] = mapped_column(ForeignKey("cameras.id"), index=True)
    frame_id: Mapped[str] = mapped_column(ForeignKey("frames.id"))
    created_at: Mapped[datetime] = mapped_column(UTCDateTime(), index=True)
    kind: Mapped[str] = mapped_column(String(8), default="raised", server_default="raised")
    """``raised`` or ``cleared``."""
    smoothed_level: Mapped[float] = mapped_column(Float)
    category: Mapped[str] = mapped_column(String(16))
    probability: Mapped[float | None] = mapped_column(Float)
    """The smoothed probability of Poor or worse that raised or cleared it (null: the
    clusters' levels did)."""
    """The category entered (raised), or the category the air is back in (cleared)."""
    delivered: Mapped[bool] = mapped_column(Boolean, default=False)
    attempts: Mapped[int] = mapped_column(Integer, default=0)
    last_error: Mapped[str | None] = mapped_column(String(500))
    next_attempt_at: Mapped[datetime | None] = mapped_column(UTCDateTime())
    """When the webhook delivery is to be tried next (backoff after a failure)."""


class AirStation(Base):
    """A reference monitor: measured PM2.5 at a place, what calibrates the cameras near it and
    anchors the map."""

    __tablename__ = "air_stations"

    id: Mapped[str] = mapped_column(String(64), primary_key=True)
    name: Mapped[str | None] = mapped_column(String(200))
    lat: Mapped[float] = mapped_column(Float)
    lon: Mapped[float] = mapped_column(Float)
    created_at: Mapped[datetime] = mapped_column(UTCDateTime())


class StationReading(Base):
    """A station's PM2.5 [µg/m³] at a time: one per (station, at); an import of the same time
    replaces it."""

    __tablename__ = "air_station_readings"

    station_id: Mapped[str] = mapped_column(
        ForeignKey("air_stations.id", ondelete="CASCADE"), primary_key=True
    )
    at: Mapped[datetime] = mapped_column(UTCDateTime(), primary_key=True)
    pm25: Mapped[float] = mapped_column(Float)
