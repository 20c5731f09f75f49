"""Solar tables. The schema is built only by the Alembic migrations in ``migrations/``."""

from __future__ import annotations

import enum
from datetime import date, datetime
from typing import Any

from sqlalchemy import (
    JSON,
    Boolean,
    Date,
    Enum,
    Float,
    ForeignKey,
    Index,
    Integer,
    String,
    false,
)
from sqlalchemy.orm import Mapped, mapped_column

from app.platform.db.base import Base, UTCDateTime
from app.platform.db.models import ID_LENGTH, CameraKind, TimestampMixin, Verdict


class Panel(TimestampMixin, Base):
    """A solar panel. Its public state is derived (``core.panel_state``) from these columns
    and its open cleaning task, so robots claiming tasks never write the panel row."""

    __tablename__ = "panels"

    id: Mapped[str] = mapped_column(String(ID_LENGTH), primary_key=True)
    name: Mapped[str | None] = mapped_column(String(200))
    lat: Mapped[float | None] = mapped_column(Float)
    """Latitude [°], WGS 84."""
    lon: Mapped[float | None] = mapped_column(Float)
    """Longitude [°], WGS 84."""
    location: Mapped[str | None] = mapped_column(String(200), default=None)
    """Where the panel is in words a robot or its crew can use ("row 3, string B, 7th")."""
    kwp: Mapped[float | None] = mapped_column(Float, default=None)
    """Rated DC power at standard test conditions [kW]: what pvlib scales insolation by."""
    tilt: Mapped[float | None] = mapped_column(Float, default=None)
    """Tilt from horizontal [°]."""
    azimuth: Mapped[float | None] = mapped_column(Float, default=None)
    """The direction it faces [° east of north]: 180 faces south."""
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
    last_doubted_at: Mapped[datetime | None] = mapped_column(UTCDateTime(), default=None)
    """When the latest frame the fleet model doubted was captured: the panel's latest word is
    doubt while it is after ``last_judged_at``."""
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
    detectable_veil: Mapped[float | None] = mapped_column(Float)
    """The smallest dust veil its F test detects with probability 0.9 (``core.power``); none on
    baselines from before it was estimated."""
    full_resolution: Mapped[bool] = mapped_column(Boolean, default=True, server_default=false())
    """Trained on the modes of full-size images (chapter 5 §III). Baselines from before were
    trained on modes of images decoded at 1/2–1/8 scale, the modes of block averages: stale,
    judging nothing until retrained (rows not written by this code default to false)."""


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
    evidence: Mapped[str | None] = mapped_column(String(300), default=None)
    """What opened it: the cameras' verdicts, and the output's word when the farm weighs it."""


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
    """Photos needing cleaning: dust and droppings."""
    cv_balanced_accuracy: Mapped[float | None] = mapped_column(Float)
    cv_low: Mapped[float | None] = mapped_column(Float, default=None)
    """The 95 % interval of ``cv_balanced_accuracy`` over its folds (Student's t): low end."""
    cv_high: Mapped[float | None] = mapped_column(Float, default=None)
    """Its high end."""
    cv_sure_balanced_accuracy: Mapped[float | None] = mapped_column(Float, default=None)
    """Nested balanced accuracy of the answers outside the not-sure band."""
    cv_answered: Mapped[float | None] = mapped_column(Float, default=None)
    """The share of held-out photos outside the not-sure band (nested)."""
    n_farm: Mapped[int] = mapped_column(Integer, default=0, server_default="0")
    """Photos that were the farm's labelled frames."""
    cv_without_farm: Mapped[float | None] = mapped_column(Float, default=None)
    """``cv_balanced_accuracy`` had the farm's labelled frames not been learnt from (the same
    held-out photos)."""
    kernel: Mapped[dict[str, Any] | None] = mapped_column(JSON)
    """A kernel model (``core.fleet.KernelModel``): support, dual, intercept, gamma, platt,
    band and shape (older ones: training and reach instead); none for the linear models of
    before (``coef``, ``intercept``)."""
    heads: Mapped[dict[str, Any] | None] = mapped_column(JSON)
    """Logistic heads on the same standardised features: snow (vs the rest) and bird_drop
    (vs dust), each {coef, intercept}, when trained."""
    n_snow: Mapped[int] = mapped_column(Integer, default=0, server_default="0")
    n_bird_drop: Mapped[int] = mapped_column(Integer, default=0, server_default="0")
    n_groups: Mapped[int | None] = mapped_column(Integer, default=None)
    """Groups (panels) its folds kept together; none when each photo was its own."""

    @property
    def band(self) -> float | None:
        """The not-sure band it chose on its photos (None: a model from before)."""
        value = (self.kernel or {}).get("band")
        return None if value is None else float(value)

    @property
    def snow_floor(self) -> float | None:
        """The p(snow) from which a frame it would send to brushing is doubted."""
        value = ((self.heads or {}).get("snow") or {}).get("floor")
        return None if value is None else float(value)


class Robot(TimestampMixin, Base):
    __tablename__ = "robots"

    id: Mapped[str] = mapped_column(String(ID_LENGTH), primary_key=True)
    name: Mapped[str | None] = mapped_column(String(200))
    token_hash: Mapped[str] = mapped_column(String(64), unique=True)
    retired_at: Mapped[datetime | None] = mapped_column(UTCDateTime(), default=None)
    """When the robot was taken out of service: its token no longer works and the tasks it
    held went back to the queue."""


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
    condition: Mapped[str | None] = mapped_column(String(16))
    """What the fleet model saw: clean, dust, bird_drop, snow (or dirty, from a model that
    tells no more)."""
    full_resolution: Mapped[bool] = mapped_column(Boolean, default=True, server_default=false())
    """Its modes are of the full-size frame; verdicts from before, of a 1/2–1/8 scale decode:
    a baseline cannot be trained from those."""
    cleaning: Mapped[str | None] = mapped_column(String(300), default=None)
    """What this verdict did to the cleaning: opened a task (and on what evidence), or found
    the panel dirty while the output said cleaning does not pay yet."""

    __mapper_args__ = {"polymorphic_identity": CameraKind.panel, "polymorphic_load": "inline"}


class FrameLabel(Base):
    """What a panel frame truly shows, as the farm said it: an operator labelling a frame the
    fleet model doubted, or a robot's cleaning (the frames just before it dirty, just after it
    clean). Labelled frames are kept past retention: they are what the model can learn from."""

    __tablename__ = "frame_labels"

    frame_id: Mapped[str] = mapped_column(ForeignKey("frames.id"), primary_key=True)
    label: Mapped[str] = mapped_column(String(16))
    """clean, dust, bird_drop or snow."""
    source: Mapped[str] = mapped_column(String(16))
    """operator (through the API or the farm board) or robot (a cleaning's before and after)."""
    labelled_at: Mapped[datetime] = mapped_column(UTCDateTime(), index=True)


class EnergyDay(Base):
    """A panel's output on one day, with what it would have made clean: the soiling ratio's
    input. One row a panel and day; a day sent again replaces it."""

    __tablename__ = "panel_energy_days"

    panel_id: Mapped[str] = mapped_column(ForeignKey("panels.id"), primary_key=True)
    day: Mapped[date] = mapped_column(Date, primary_key=True)
    """The day, in the farm's local time as its export gives it."""
    kwh: Mapped[float] = mapped_column(Float)
    """Measured energy [kWh]."""
    expected_kwh: Mapped[float] = mapped_column(Float)
    """What the clean panel would have made [kWh]: given, or modelled by pvlib."""
    expected_from: Mapped[str] = mapped_column(String(8))
    """given, poa (pvlib from plane-of-array insolation) or ghi (from global horizontal)."""
    poa_kwh_m2: Mapped[float | None] = mapped_column(Float, default=None)
    ghi_kwh_m2: Mapped[float | None] = mapped_column(Float, default=None)
    rain_mm: Mapped[float | None] = mapped_column(Float, default=None)
    received_at: Mapped[datetime] = mapped_column(UTCDateTime())


class SolarEconomics(Base):
    """The farm's prices (one row): what its energy is worth, what a cleaning costs, and
    whether the cleaning trigger weighs them."""

    __tablename__ = "solar_economics"

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    energy_price_per_kwh: Mapped[float] = mapped_column(Float)
    cleaning_cost: Mapped[float] = mapped_column(Float)
    cost_per: Mapped[str] = mapped_column(String(8))
    """panel (each panel's cleaning costs ``cleaning_cost``) or visit (a robot's visit does,
    shared by ``panels_per_visit``)."""
    panels_per_visit: Mapped[int] = mapped_column(Integer)
    currency: Mapped[str | None] = mapped_column(String(3))
    trigger: Mapped[str] = mapped_column(String(16))
    """camera (the cameras' verdicts alone open a task) or camera_and_pays (a dirty panel gets
    a task when it has no recent output, or when cleaning it pays)."""
    updated_at: Mapped[datetime] = mapped_column(UTCDateTime())
