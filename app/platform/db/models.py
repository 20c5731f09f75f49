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
    false,
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


class Panel(TimestampMixin, Base):
    """A solar panel. Its public state is derived (``app.solar.core.panel_state``) from these columns
    and its open cleaning task, so robots claiming tasks never write the panel row."""

    __tablename__ = "panels"

    id: Mapped[str] = mapped_column(String(ID_LENGTH), primary_key=True)
    name: Mapped[str | None] = mapped_column(String(200))
    lat: Mapped[float | None] = mapped_column(Float)
    """Latitude [°], WGS 84."""
    lon: Mapped[float | None] = mapped_column(Float)
    """Longitude [°], WGS 84."""
    baseline_id: Mapped[str | None] = mapped_column(
        ForeignKey("baselines.id", use_alter=True), default=None
    )
    """The baseline verdicts use (the latest trained)."""
    dirty_streak: Mapped[int] = mapped_column(Integer, default=0, server_default="0")
    """Consecutive usable verdicts that said dirty (the debounce counter)."""
    last_clean: Mapped[bool | None] = mapped_column(Boolean, default=None)
    """The last usable verdict, or None before the first."""
    ineffective: Mapped[bool] = mapped_column(Boolean, default=False, server_default=false())
    """The last cleaning did not make the panel clean."""
    last_judged_at: Mapped[datetime | None] = mapped_column(UTCDateTime(), default=None)
    """When the latest frame whose verdict drove the state machine was captured: a frame taken
    before it (a camera's backlog uploaded late) is judged but does not drive it."""
    retired_at: Mapped[datetime | None] = mapped_column(UTCDateTime(), default=None)
    """When the panel was taken out of service (removed from the farm): its open cleaning task
    was cancelled, and no camera may be attached to it nor baseline trained for it."""


class Baseline(Base):
    """A panel's clean baseline (eqs. 5.12–5.13)."""

    __tablename__ = "baselines"

    id: Mapped[str] = mapped_column(String(36), primary_key=True)
    panel_id: Mapped[str] = mapped_column(ForeignKey("panels.id"), index=True)
    created_at: Mapped[datetime] = mapped_column(UTCDateTime())
    n: Mapped[int] = mapped_column(Integer)
    mean_modes: Mapped[list[float]] = mapped_column(JSON)
    covariance: Mapped[list[list[float]]] = mapped_column(JSON)
    significance: Mapped[float] = mapped_column(Float)
    f_critical: Mapped[float] = mapped_column(Float)
    condition_number: Mapped[float] = mapped_column(Float)
    shrinkage: Mapped[float] = mapped_column(Float)
    frame_ids: Mapped[list[str] | None] = mapped_column(JSON)
    """Stored frames it was trained from (kept by the retention sweep), or none for uploads."""
    roi: Mapped[list[int] | list[list[int]] | None] = mapped_column(JSON)
    """The region of interest its images were measured in (null: whole images). It judges only
    frames measured in the same region: modes of another part of the view are not comparable."""


class TaskStatus(enum.StrEnum):
    pending = "pending"
    claimed = "claimed"
    completed = "completed"
    """Done by the robot; the panel's next usable verdict confirms it."""
    closed = "closed"
    failed = "failed"
    cancelled = "cancelled"


OPEN_TASK_STATUSES = (TaskStatus.pending, TaskStatus.claimed, TaskStatus.completed)


class CleaningTask(Base):
    __tablename__ = "cleaning_tasks"
    __table_args__ = (Index("ix_cleaning_tasks_status_created_at", "status", "created_at"),)

    id: Mapped[str] = mapped_column(String(36), primary_key=True)
    panel_id: Mapped[str] = mapped_column(ForeignKey("panels.id"), index=True)
    open_panel_id: Mapped[str | None] = mapped_column(ForeignKey("panels.id"), unique=True)
    """The panel id while the task is open, else NULL: at most one open task per panel."""
    status: Mapped[TaskStatus] = mapped_column(
        Enum(TaskStatus, native_enum=False, length=16, validate_strings=True)
    )
    created_at: Mapped[datetime] = mapped_column(UTCDateTime())
    robot_id: Mapped[str | None] = mapped_column(ForeignKey("robots.id"))
    claimed_at: Mapped[datetime | None] = mapped_column(UTCDateTime())
    lease_expires_at: Mapped[datetime | None] = mapped_column(UTCDateTime())
    completed_at: Mapped[datetime | None] = mapped_column(UTCDateTime())
    closed_at: Mapped[datetime | None] = mapped_column(UTCDateTime())
    outcome: Mapped[str | None] = mapped_column(String(16))
    """effective, ineffective, not_needed, failed or panel_retired."""
    attempts: Mapped[int] = mapped_column(Integer, default=0)
    fail_reason: Mapped[str | None] = mapped_column(String(500))


class FleetModel(Base):
    """A clean/dirty model trained on labelled photos of many panels (``app.solar.core.fleet``)."""

    __tablename__ = "fleet_models"

    id: Mapped[str] = mapped_column(String(36), primary_key=True)
    created_at: Mapped[datetime] = mapped_column(UTCDateTime(), index=True)
    feature_names: Mapped[list[str]] = mapped_column(JSON)
    mean: Mapped[list[float]] = mapped_column(JSON)
    scale: Mapped[list[float]] = mapped_column(JSON)
    coef: Mapped[list[float]] = mapped_column(JSON)
    intercept: Mapped[float] = mapped_column(Float)
    threshold: Mapped[float] = mapped_column(Float)
    n_clean: Mapped[int] = mapped_column(Integer)
    n_dirty: Mapped[int] = mapped_column(Integer)
    cv_balanced_accuracy: Mapped[float | None] = mapped_column(Float)


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

    panel: Mapped[Panel | None] = relationship(lazy="raise")


class Robot(TimestampMixin, Base):
    __tablename__ = "robots"

    id: Mapped[str] = mapped_column(String(ID_LENGTH), primary_key=True)
    name: Mapped[str | None] = mapped_column(String(200))
    token_hash: Mapped[str] = mapped_column(String(64), unique=True)
    retired_at: Mapped[datetime | None] = mapped_column(UTCDateTime(), default=None)
    """When the robot was taken out of service: its token no longer works and the tasks it
    held went back to the queue."""


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
    method: Mapped[str | None] = mapped_column(String(16))
    """baseline (the panel's T² test) or fleet (the fleet model)."""
    baseline_id: Mapped[str | None] = mapped_column(ForeignKey("baselines.id"))
    p_dirty: Mapped[float | None] = mapped_column(Float)
    """The fleet model's probability that the panel needs cleaning."""
    late: Mapped[bool] = mapped_column(Boolean, default=False, server_default=false())
    """Taken before the panel's latest judged frame, or before the cleaning awaiting
    confirmation was done: judged, but it did not drive the panel's state."""

    __mapper_args__ = {"polymorphic_identity": CameraKind.panel, "polymorphic_load": "inline"}


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
    """How frames are graded: the T² clusters (the dissertation) or the regression."""
    regression: Mapped[dict[str, Any] | None] = mapped_column(JSON)
    """{mean, scale, coef, intercept} of the ridge regression on the sky features."""
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
    """The category entered (raised), or the category the air is back in (cleared)."""
    delivered: Mapped[bool] = mapped_column(Boolean, default=False)
    attempts: Mapped[int] = mapped_column(Integer, default=0)
    last_error: Mapped[str | None] = mapped_column(String(500))
    next_attempt_at: Mapped[datetime | None] = mapped_column(UTCDateTime())
    """When the webhook delivery is to be tried next (backoff after a failure)."""


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
