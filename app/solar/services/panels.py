"""Panels: verdicts by baseline or fleet model, the state machine's effects, status, trend."""

from __future__ import annotations

import uuid
from collections.abc import Sequence
from dataclasses import dataclass
from datetime import datetime
from typing import Any

import numpy as np
from sqlalchemy import ColumnElement, Select, and_, case, func, or_, select
from sqlalchemy.orm import Session

from app.platform.db.models import Camera, Frame
from app.platform.frames.camera_info import Region, describe_region, region_now
from app.platform.frames.kinds import Prepared
from app.platform.frames.verdicts import stats_columns
from app.platform.http.errors import NotFound
from app.platform.lookup import get_or_404
from app.platform.memo import ById
from app.platform.timing import Timing
from app.solar.core import power
from app.solar.core.fleet import UNSURE, Head, KernelModel, LogisticModel, Shape
from app.solar.core.panel_state import (
    PanelFacts,
    PanelState,
    TaskAction,
    on_verdict,
    state_of,
    task_phase,
)
from app.solar.models import (
    OPEN_TASK_STATUSES,
    Baseline,
    CleaningTask,
    FleetModel,
    Panel,
    PanelVerdict,
    TaskStatus,
)
from app.solar.services import events, labels, soiling
from app.solar.services.cleaning import shown_as
from app.solar.services.trends import Trend, soiling_trend
from app.stats import hotelling


def lock_panel(session: Session, panel_id: str) -> Panel:
    """The panel row, locked for this transaction (PostgreSQL; SQLite's writer lock suffices)."""
    return get_or_404(session, Panel, panel_id, "panel", lock=True)


def open_task(session: Session, panel_id: str, *, lock: bool = False) -> CleaningTask | None:
    q = select(CleaningTask).where(CleaningTask.open_panel_id == panel_id)
    return session.scalars(q.with_for_update() if lock else q).one_or_none()


def state_column(now: datetime, *, debounce: int, fleet_available: bool) -> ColumnElement[str]:
    """``panel_state.state_of`` as SQL, over ``panels`` left-joined to their open task
    (``CleaningTask.open_panel_id``): every panel's state in one query, to filter and count by.
    ``tests/api/test_solar.py`` checks it against the panel's status for every combination of
    facts."""
    has_baseline = Panel.baseline_id.is_not(None)
    whens: list[tuple[ColumnElement[bool], Any]] = [
        (shown_as("pending", now), PanelState.needs_cleaning),
        (
            or_(shown_as("claimed", now), CleaningTask.status == TaskStatus.completed),
            PanelState.cleaning,
        ),
    ]
    if not fleet_available:  # no model to judge a panel without a baseline
        whens.append((~has_baseline, PanelState.no_baseline))
    whens += [
        (
            Panel.last_clean.is_(None),
            case((has_baseline, PanelState.clean), else_=PanelState.unknown),
        ),
        (
            and_(
                Panel.last_clean.is_(False),
                or_(Panel.ineffective.is_(True), Panel.dirty_streak >= debounce),
            ),
            PanelState.needs_cleaning,
        ),
    ]
    return case(*whens, else_=PanelState.clean)


def _with_state(session: Session, timing: Timing) -> tuple[Select[Panel, str], ColumnElement[str]]:
    """Panels left-joined to their open task, with their state now (``state_column``)."""
    state = state_column(
        timing.now(),
        debounce=timing.debounce,
        fleet_available=latest_fleet_model(session) is not None,
    ).label("state")
    q = select(Panel, state).outerjoin(CleaningTask, CleaningTask.open_panel_id == Panel.id)
    return q, state


def listed_with_state(
    session: Session,
    timing: Timing,
    *,
    states: Sequence[PanelState],
    retired: bool,
    limit: int,
    offset: int,
) -> list[tuple[Panel, PanelState]]:
    """Panels by id, each with its state now; only those in ``states`` when given."""
    q, state = _with_state(session, timing)
    if not retired:
        q = q.where(Panel.retired_at.is_(None))
    if states:
        q = q.where(state.in_(states))
    rows = session.execute(q.order_by(Panel.id).limit(limit).offset(offset)).all()
    return [(panel, PanelState(s)) for panel, s in rows]


def state_now(session: Session, panel: Panel, timing: Timing) -> PanelState:
    """One panel's state now (as its status reads)."""
    q, _ = _with_state(session, timing)
    return PanelState(session.execute(q.where(Panel.id == panel.id)).one()[1])


def state_counts(session: Session, timing: Timing) -> dict[PanelState, int]:
    """How many panels in service are in each state now (every state, zeros included)."""
    q, state = _with_state(session, timing)
    counted = (
        q.with_only_columns(state, func.count()).where(Panel.retired_at.is_(None)).group_by(state)
    )
    found = {PanelState(s): n for s, n in session.execute(counted).all()}
    return {s: found.get(s, 0) for s in PanelState}


def latest_fleet_model(session: Session) -> FleetModel | None:
    return session.scalars(
        select(FleetModel).order_by(FleetModel.created_at.desc(), FleetModel.id).limit(1)
    ).first()


def as_core_baseline(row: Baseline) -> hotelling.Baseline:
    return hotelling.Baseline(
        n=row.n,
        mean_modes=np.asarray(row.mean_modes, dtype=np.float64),
        covariance=np.asarray(row.covariance, dtype=np.float64),
        significance=row.significance,
        f_critical=row.f_critical,
        condition_number=row.condition_number,
        shrinkage=row.shrinkage,
    )


_MODELS: ById[LogisticModel | KernelModel] = ById()
"""Fleet models as read, by id: a fleet model never changes once trained."""


def as_core_model(row: FleetModel) -> LogisticModel | KernelModel:
    """The stored fleet model: a kernel model with its heads, or a linear one from before."""
    return _MODELS.get(row.id, lambda: _read_model(row))


def _read_model(row: FleetModel) -> LogisticModel | KernelModel:
    if row.kernel is None:
        return LogisticModel(
            feature_names=tuple(row.feature_names),
            mean=np.asarray(row.mean),
            scale=np.asarray(row.scale),
            coef=np.asarray(row.coef),
            intercept=row.intercept,
            threshold=row.threshold,
        )
    k, heads = row.kernel, row.heads or {}

    def head(name: str) -> Head | None:
        h = heads.get(name)
        return None if h is None else Head(np.asarray(h["coef"], np.float64), h["intercept"])

    return KernelModel(
        feature_names=tuple(row.feature_names),
        mean=np.asarray(row.mean, np.float64),
        scale=np.asarray(row.scale, np.float64),
        support=np.asarray(k["support"], np.float64),
        dual=np.asarray(k["dual"], np.float64),
        intercept=float(k["intercept"]),
        gamma=float(k["gamma"]),
        platt=(float(k["platt"][0]), float(k["platt"][1])),
        snow=head("snow"),
        bird_drop=head("bird_drop"),
        threshold=row.threshold,
        training=None if "training" not in k else np.asarray(k["training"], np.float64),
        reach=k.get("reach"),
        shape=None if k.get("shape") is None else _shape(k["shape"]),
        band=float(k.get("band", UNSURE)),
        snow_floor=heads.get("snow", {}).get("floor"),
    )


def _shape(stored: dict[str, Any]) -> Shape:
    return Shape(
        mean=np.asarray(stored["mean"], np.float64),
        scale=np.asarray(stored["scale"], np.float64),
        location=np.asarray(stored["location"], np.float64),
        precision=np.asarray(stored["precision"], np.float64),
        limit=float(stored["limit"]),
    )


def facts(
    panel: Panel, task: CleaningTask | None, now: datetime, *, fleet_available: bool
) -> PanelFacts:
    return PanelFacts(
        has_model=panel.baseline_id is not None or fleet_available,
        has_baseline=panel.baseline_id is not None,
        dirty_streak=panel.dirty_streak,
        last_clean=panel.last_clean,
        ineffective=panel.ineffective,
        task=task_phase(task.status, task.lease_expires_at, now) if task else None,
    )


def close_task(task: CleaningTask, status: TaskStatus, outcome: str, now: datetime) -> None:
    """Close an open task (closed, cancelled) with its outcome; the panel may get a new one."""
    task.status = status
    task.outcome = outcome
    task.closed_at = now
    task.open_panel_id = None


def apply_verdict(
    session: Session,
    panel: Panel,
    task: CleaningTask | None,
    clean: bool,
    now: datetime,
    timing: Timing,
    *,
    fleet_available: bool,
) -> tuple[CleaningTask | None, str | None]:
    """Run the state machine for one usable verdict; returns the panel's open task after it,
    and what the verdict did to the cleaning (opened a task, or found cleaning does not pay
    yet: ``soiling.gate``)."""
    before = facts(panel, task, now, fleet_available=fleet_available)
    t = on_verdict(before, clean, debounce=timing.debounce)
    panel.dirty_streak, panel.last_clean, panel.ineffective = (
        t.dirty_streak,
        t.last_clean,
        t.ineffective,
    )
    note = None
    if t.action is TaskAction.open:
        gate = soiling.gate(session, panel, now.date(), dirty=t.dirty_streak)
        if not gate.open:
            return None, f"dirty, no task opened: {gate.evidence}"[:300]
        note = f"opened a cleaning task: {gate.evidence}"[:300]
        task = CleaningTask(
            id=str(uuid.uuid4()),
            panel_id=panel.id,
            open_panel_id=panel.id,
            status=TaskStatus.pending,
            created_at=now,
            attempts=0,
            evidence=gate.evidence[:300],
        )
        session.add(task)
        events.task_event(session, task, "task.opened", now)
    elif task is not None and t.action is not TaskAction.none:
        if t.action is TaskAction.cancel:
            # a stale claim (expired lease) is cancelled too: the panel is clean
            close_task(task, TaskStatus.cancelled, "not_needed", now)
        elif t.action is TaskAction.close_effective:
            close_task(task, TaskStatus.closed, "effective", now)
            events.task_event(session, task, "cleaning.effective", now)
        else:
            close_task(task, TaskStatus.closed, "ineffective", now)
            events.task_event(session, task, "cleaning.ineffective", now)
        task = None
    return task, note


def is_late(panel: Panel, task: CleaningTask | None, captured_at: datetime) -> bool:
    """Whether a frame was taken too early to drive the panel's state: before the latest frame
    that did (a camera's backlog, uploaded after newer frames), or before the cleaning that
    awaits confirmation was done. Debounce and confirmation follow the panel in the order it
    was seen, not the order frames arrive: a clean frame from before the dust, uploaded after
    the robot finished, confirmed a cleaning it never saw."""
    if panel.last_judged_at is not None and captured_at < panel.last_judged_at:
        return True
    if task is None or task.status != TaskStatus.completed or task.completed_at is None:
        return False
    return captured_at < task.completed_at


def baseline_for(session: Session, panel: Panel, region: Region) -> Baseline | None:
    """The baseline that judges frames measured in ``region``: the panel's newest one measured
    there. A panel watched by cameras with different views (regions) has one in use per view;
    most panels have one camera, and their newest baseline is it (no further query)."""
    if panel.baseline_id is None:
        return None
    newest = session.get(Baseline, panel.baseline_id)
    assert newest is not None
    if newest.roi == region:
        return newest
    older = session.execute(  # ids and regions only: the fits are read for the one chosen
        select(Baseline.id, Baseline.roi)
        .where(Baseline.panel_id == panel.id, Baseline.id != newest.id)
        .order_by(Baseline.created_at.desc(), Baseline.id.desc())
    ).all()
    chosen = next((bid for bid, roi in older if roi == region), None)
    return None if chosen is None else session.get(Baseline, chosen)


def judging(session: Session, panel: Panel, camera_id: str) -> Baseline:
    """The baseline that judges the frames of the panel's camera ``camera_id`` (404 when the
    camera is not the panel's, or no baseline was measured in its region)."""
    camera = session.get(Camera, camera_id)
    if camera is None or camera.panel_id != panel.id:
        raise NotFound(f"panel {panel.id!r} has no camera {camera_id!r}")
    region = region_now(camera)
    row = baseline_for(session, panel, region)
    if row is None:
        raise NotFound(
            f"no baseline of panel {panel.id!r} was measured in camera {camera_id!r}'s "
            f"{describe_region(region)}"
        )
    return row


@dataclass(frozen=True, slots=True)
class Unfit:
    """Why a baseline may not judge: ``code`` (baseline_stale, baseline_too_broad) and what to
    do about it."""

    code: str
    baseline_id: str
    detail: str


def baseline_unfit(row: Baseline) -> Unfit | None:
    """Why a baseline may not judge, or None: trained on modes of reduced images (stale), or
    too broad to notice a useful dust veil (``core.power``)."""
    if not row.full_resolution:
        return Unfit(
            "baseline_stale",
            row.id,
            f"baseline {row.id} is stale: trained on modes of frames decoded at reduced scale; "
            "retrain it from new frames or images (POST /panels/{id}/baseline)",
        )
    if row.detectable_veil is not None:
        broad = power.too_broad(row.detectable_veil, row.covariance)
        if broad is not None:
            return Unfit(
                "baseline_too_broad",
                row.id,
                f"baseline {row.id} is too broad to judge: {broad}; retrain it from photos of "
                "this panel by its camera",
            )
    return None


def classify_frame(session: Session, prepared: Prepared, timing: Timing) -> PanelVerdict:
    """A panel camera's verdict: the panel's own T² baseline of the camera's view (region),
    else the fleet model.

    Also advances the panel's state machine (debounce, tasks). Runs in the writer's transaction.
    """
    camera, frame, decoded = prepared.camera, prepared.frame, prepared.decoded
    verdict = PanelVerdict(
        frame_id=frame.id,
        camera_id=camera.id,
        panel_id=camera.panel_id,
        clean=None,
        late=False,
        **stats_columns(decoded.stats),
    )
    if camera.panel_id is None:
        verdict.reason = "camera is not attached to a panel"
        return verdict
    now = frame.received_at
    panel = lock_panel(session, camera.panel_id)
    if panel.retired_at is not None:  # the camera moved off it, and it retired, since the check
        verdict.reason = f"panel {panel.id!r} is retired"
        return verdict
    task = open_task(session, panel.id, lock=True)
    # the baseline of this camera's view (region); a view without one, like a panel without
    # any, is judged by the fleet model when there is one
    found = baseline_for(session, panel, camera.region)
    unfit = baseline_unfit(found) if found is not None else None
    row = None if unfit is not None else found  # a baseline that cannot judge judges nothing
    model_row = None if row is not None else latest_fleet_model(session)
    fleet_available = model_row is not None
    if decoded.quality is not None:
        verdict.reason = decoded.quality
    elif row is not None:
        result = hotelling.classify(as_core_baseline(row), decoded.stats.modes)
        verdict.method, verdict.baseline_id = "baseline", row.id
        verdict.clean, verdict.t2, verdict.f_stat = result.clean, result.t2, result.f_stat
        verdict.p_value, verdict.threshold = result.p_value, result.threshold
    elif model_row is not None and decoded.features is not None:
        model = as_core_model(model_row)
        p_dirty = float(model.probability(decoded.features))
        verdict.method, verdict.p_dirty = "fleet", p_dirty
        verdict.threshold = model.threshold
        verdict.condition = model.condition(decoded.features)
        said = None
        if verdict.condition == "snow":  # not a case for brushing: no verdict on soiling
            said = "snow-covered: no brushing until it melts"
        elif (doubt := model.doubt(decoded.features)) is not None:
            said, verdict.condition = doubt, None  # the panel's state and task stay as they are
            latest = panel.last_doubted_at
            if latest is None or frame.captured_at > latest:
                panel.last_doubted_at = frame.captured_at
        else:
            verdict.clean = p_dirty < model.threshold
        why = f"judged by the fleet model: {unfit.detail}" if unfit is not None else None
        verdict.reason = "; ".join(filter(None, [why, said]))[:200] or None
    elif unfit is not None:
        verdict.reason = unfit.detail[:200]
    elif panel.baseline_id is not None:  # modes of another part of the view: not comparable
        verdict.reason = (
            f"no baseline of this panel was measured in this camera's "
            f"{describe_region(camera.region)}: train one from its frames "
            f"(POST /panels/{panel.id}/baseline)"
        )[:200]
    else:
        verdict.reason = "no baseline: train one (POST /panels/{id}/baseline) or a fleet model"
    verdict.late = verdict.clean is not None and is_late(panel, task, frame.captured_at)
    if verdict.clean is not None and not verdict.late:
        panel.last_judged_at = frame.captured_at
        held = task
        task, verdict.cleaning = apply_verdict(
            session, panel, task, verdict.clean, now, timing, fleet_available=fleet_available
        )
        if held is not None and held.outcome == "effective" and held.completed_at is not None:
            # the robot's cleaning teaches the fleet model: before it dirty, after it clean
            labels.learn_from_cleaning(session, panel.id, held.completed_at, frame, now)
    after = facts(panel, task, now, fleet_available=fleet_available)
    verdict.state = state_of(after, debounce=timing.debounce).value
    return verdict


def latest_verdict(session: Session, panel_id: str) -> tuple[Frame, PanelVerdict] | None:
    row = session.execute(
        select(Frame, PanelVerdict)
        .join(PanelVerdict, PanelVerdict.frame_id == Frame.id)
        .where(PanelVerdict.panel_id == panel_id)
        .order_by(Frame.received_at.desc(), Frame.captured_at.desc())
        .limit(1)
    ).first()
    return (row[0], row[1]) if row else None


@dataclass(frozen=True, slots=True)
class View:
    """One of the panel's cameras in service: the baseline judging its frames, and their
    trend."""

    camera_id: str
    baseline_id: str | None
    trend: Trend
    unfit: Unfit | None = None
    """Why that baseline judges nothing, when it does not."""


@dataclass(frozen=True, slots=True)
class Status:
    panel: Panel
    state: PanelState
    task: CleaningTask | None
    last: tuple[Frame, PanelVerdict] | None
    trend: Trend
    views: list[View]
    warnings: list[Unfit]
    """The panel's baselines that judge nothing, and why."""


def views(session: Session, panel: Panel, now: datetime) -> list[View]:
    """Each camera in service of the panel, with its view's baseline and that one's trend (a
    panel watched from several views has a baseline, and a trend, per view)."""
    cameras = session.scalars(
        select(Camera)
        .where(Camera.panel_id == panel.id, Camera.retired_at.is_(None))
        .order_by(Camera.id)
    ).all()
    out = []
    for camera in cameras:
        baseline = baseline_for(session, panel, region_now(camera))
        trend = (
            soiling_trend(session, panel, now, baseline)
            if baseline is not None
            else Trend(0, None, None, None, None)
        )
        unfit = baseline_unfit(baseline) if baseline is not None else None
        out.append(View(camera.id, baseline.id if baseline else None, trend, unfit))
    return out


def panel_status(session: Session, panel_id: str, timing: Timing) -> Status:
    panel = get_or_404(session, Panel, panel_id, "panel")
    now = timing.now()
    task = open_task(session, panel_id)
    newest = session.get(Baseline, panel.baseline_id) if panel.baseline_id else None
    unfit = baseline_unfit(newest) if newest is not None else None
    fleet_available = (newest is None or unfit is not None) and latest_fleet_model(
        session
    ) is not None
    state = state_of(
        facts(panel, task, now, fleet_available=fleet_available), debounce=timing.debounce
    )
    seen = views(session, panel, now)
    warnings = {u.baseline_id: u for u in [unfit, *(v.unfit for v in seen)] if u is not None}
    return Status(
        panel,
        state,
        task,
        latest_verdict(session, panel_id),
        soiling_trend(session, panel, now),
        seen,
        list(warnings.values()),
    )


def task_view(task: CleaningTask, now: datetime) -> dict[str, Any]:
    phase = task_phase(task.status, task.lease_expires_at, now)
    return {
        "task_id": task.id,
        "panel_id": task.panel_id,
        "status": (phase.value if phase else task.status.value),
        "robot_id": task.robot_id,
        "created_at": task.created_at,
        "claimed_at": task.claimed_at,
        "lease_expires_at": task.lease_expires_at,
        "completed_at": task.completed_at,
        "closed_at": task.closed_at,
        "outcome": task.outcome,
        "attempts": task.attempts,
        "fail_reason": task.fail_reason,
        "evidence": task.evidence,
    }


def open_tasks(session: Session, *, limit: int) -> Sequence[CleaningTask]:
    return session.scalars(
        select(CleaningTask)
        .where(CleaningTask.status.in_(OPEN_TASK_STATUSES))
        .order_by(CleaningTask.created_at, CleaningTask.id)
        .limit(limit)
    ).all()
