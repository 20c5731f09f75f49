"""Solar panels: registry, baselines, status, the cleaning trigger, evaluation."""

from __future__ import annotations

from functools import partial
from typing import Annotated, Any, Literal

from fastapi import APIRouter, Query, Request, Response
from fastapi.concurrency import run_in_threadpool
from sqlalchemy.orm import Session

from app.platform.db.models import CameraKind
from app.platform.db.session import release
from app.platform.frames import ingest
from app.platform.frames.camera_info import CameraInfo
from app.platform.http.deps import (
    ID_PATTERN,
    Admin,
    AnyReader,
    PanelId,
    Reader,
    RobotOrAdmin,
    SessionDep,
    SettingsDep,
    Shrinkage,
    Significance,
    TimeRangeQuery,
    TimingDep,
    image_work,
)
from app.platform.http.errors import Forbidden, NotFound, Unprocessable, UnsupportedMediaType
from app.platform.http.responses import (
    AUTH_ERRORS,
    BODY_ERRORS,
    CONFLICT,
    NOT_FOUND,
    PANEL_IN_USE,
    PANEL_RETIRED,
    UNPROCESSABLE,
    multipart_body,
)
from app.platform.http.uploads import content_type, images_or_frames, read_form
from app.platform.timing import Timing
from app.solar.core.panel_state import PanelState
from app.solar.kind import verdict_out
from app.solar.models import Baseline, Panel
from app.solar.schemas import (
    BaselineFromFrames,
    BaselineOut,
    BaselineWarning,
    EvaluationOut,
    HistoryBucket,
    PanelCreate,
    PanelOut,
    PanelStateCounts,
    PanelStatus,
    PanelUpdate,
    PanelVerdictSummary,
    TaskOut,
    TrendOut,
    Trigger,
    TwoSampleOut,
    ViewOut,
)
from app.solar.services import cleaning, history, lookup, panels, registry, soiling, training

router = APIRouter(tags=["panels"])

_FILES_BODY = multipart_body(json=BaselineFromFrames, files="files")


def _out(
    session: Session, timing: Timing, panel: Panel, state: PanelState | None = None
) -> PanelOut:
    return PanelOut(
        id=panel.id,
        name=panel.name,
        lat=panel.lat,
        lon=panel.lon,
        location=panel.location,
        kwp=panel.kwp,
        tilt=panel.tilt,
        azimuth=panel.azimuth,
        created_at=panel.created_at,
        retired_at=panel.retired_at,
        state=state if state is not None else panels.state_now(session, panel, timing),
        last_clean=panel.last_clean,
        dirty_streak=panel.dirty_streak,
        streak_needed=timing.debounce,
        doubted=panel.last_doubted_at is not None
        and (panel.last_judged_at is None or panel.last_doubted_at > panel.last_judged_at),
    )


@router.post(
    "/panels",
    status_code=201,
    response_model=PanelOut,
    responses={**AUTH_ERRORS, **CONFLICT, **UNPROCESSABLE},
)
def create_panel(body: PanelCreate, session: SessionDep, timing: TimingDep, _: Admin) -> PanelOut:
    """Register a solar panel."""
    return _out(session, timing, registry.create_panel(session, body))


@router.get("/panels", response_model=list[PanelOut], responses=AUTH_ERRORS)
def list_panels(
    session: SessionDep,
    timing: TimingDep,
    _: Reader,
    limit: Annotated[int, Query(ge=1, le=1000)] = 100,
    offset: Annotated[int, Query(ge=0, le=10_000_000)] = 0,
    retired: Annotated[
        bool, Query(description="Include retired panels (by default only those in service).")
    ] = False,
    state: Annotated[
        list[PanelState] | None,
        Query(
            max_length=5,
            description="Only panels in these states now (repeat it for several): "
            "``?state=needs_cleaning&state=cleaning``.",
        ),
    ] = None,
) -> list[PanelOut]:
    """List panels, ordered by id, each with its state now."""
    rows = panels.listed_with_state(
        session, timing, states=state or [], retired=retired, limit=limit, offset=offset
    )
    return [_out(session, timing, p, s) for p, s in rows]


@router.get("/panels/{panel_id}", response_model=PanelOut, responses={**AUTH_ERRORS, **NOT_FOUND})
def get_panel(
    panel_id: PanelId, session: SessionDep, timing: TimingDep, caller: AnyReader
) -> PanelOut:
    """One panel. A robot may read the panel of a task it holds (claimed, lease running)."""
    if caller.role == "robot" and not cleaning.holds_task_on(
        session, caller.id or "", panel_id, timing.now()
    ):
        raise Forbidden("a robot may read only the panel of a cleaning task it holds")
    return _out(session, timing, lookup.get_panel(session, panel_id))


@router.patch(
    "/panels/{panel_id}",
    response_model=PanelOut,
    responses={**AUTH_ERRORS, **NOT_FOUND, **PANEL_RETIRED, **UNPROCESSABLE},
)
def update_panel(
    panel_id: PanelId, body: PanelUpdate, session: SessionDep, timing: TimingDep, _: Admin
) -> PanelOut:
    """Change a panel's name, location or rating (JSON merge: fields left out keep their value,
    ``null`` clears one)."""
    return _out(session, timing, registry.update_panel(session, panel_id, body))


@router.get("/panel-states", response_model=PanelStateCounts, responses=AUTH_ERRORS)
def panel_states(session: SessionDep, timing: TimingDep, _: Reader) -> PanelStateCounts:
    """The farm at a glance: how many panels in service are in each state now (one query, for
    tens of thousands of panels; ``GET /panels?state=`` lists those of a state)."""
    counts = panels.state_counts(session, timing)
    return PanelStateCounts(
        counted_at=timing.now(),
        total=sum(counts.values()),
        states={s.value: n for s, n in counts.items()},
    )


@router.delete(
    "/panels/{panel_id}",
    status_code=204,
    response_class=Response,
    responses={**AUTH_ERRORS, **NOT_FOUND, **PANEL_IN_USE},
)
def retire_panel(panel_id: PanelId, session: SessionDep, timing: TimingDep, _: Admin) -> Response:
    """Retire a panel removed from the farm. Its open cleaning task is cancelled (outcome
    ``panel_retired``: no robot is sent to it, and one holding the task can neither complete
    nor fail it), no camera may be attached to it nor baseline trained for it (409
    ``panel_retired``), and it leaves the panel list (``?retired=true`` shows it). Its
    verdicts, baselines and tasks stay readable, and its id stays taken. Refused (409
    ``panel_in_use``) while cameras in service watch it. Retiring it again changes nothing."""
    registry.retire_panel(session, panel_id, timing)
    return Response(status_code=204)


def _train_from_files(
    session: Session,
    panel_id: str,
    camera_id: str | None,
    files: list[tuple[str | None, bytes]],
    significance: float,
    shrinkage: float,
    max_pixels: int,
    timing: Timing,
) -> BaselineOut:
    registry.panel_in_service(session, panel_id)
    camera = training.panel_camera(session, panel_id, camera_id)
    release(session)  # while decoding; training locks the panel and checks it again
    decoded = ingest.decode_all(files, camera, max_pixels=max_pixels)
    training.check_one_size([name for name, _ in files], decoded)
    modes = ingest.modes_of(decoded)
    row = training.train_baseline(
        session,
        panel_id,
        modes,
        significance=significance,
        shrinkage=shrinkage,
        frame_ids=None,
        roi=camera.region,
        now=timing.now(),
    )
    return baseline_out(row)


def _train_from_frames(
    session: Session,
    panel_id: str,
    frame_ids: list[str],
    significance: float,
    shrinkage: float,
    timing: Timing,
) -> BaselineOut:
    registry.panel_in_service(session, panel_id)
    modes, region = training.modes_of_frames(session, panel_id, frame_ids)
    row = training.train_baseline(
        session,
        panel_id,
        modes,
        significance=significance,
        shrinkage=shrinkage,
        frame_ids=frame_ids,
        roi=region,
        now=timing.now(),
    )
    return baseline_out(row)


@router.post(
    "/panels/{panel_id}/baseline",
    status_code=201,
    response_model=BaselineOut,
    responses={**AUTH_ERRORS, **NOT_FOUND, **PANEL_RETIRED, **BODY_ERRORS, **UNPROCESSABLE},
    openapi_extra=_FILES_BODY,
)
async def train_baseline(
    panel_id: PanelId,
    request: Request,
    session: SessionDep,
    settings: SettingsDep,
    timing: TimingDep,
    _: Admin,
    significance: Significance = 0.05,
    shrinkage: Shrinkage = 0.0,
    camera_id: Annotated[
        str | None, Query(description="Whose ROI applies to uploaded images.")
    ] = None,
) -> BaselineOut:
    """Train the panel's clean baseline (eqs. 5.12–5.13) from ≥ 4 clean images or frames.

    Multipart with repeated field ``files``, or JSON ``{"frame_ids": [...]}`` of stored frames.
    """
    given = await images_or_frames(
        request,
        BaselineFromFrames,
        upload_limit=settings.max_upload_bytes,
        body_limit=settings.max_body_bytes,
        max_files=1000,
        parts=("files",),
        expected="multipart/form-data (files) or application/json (frame_ids)",
    )
    if isinstance(given, BaselineFromFrames):
        return await run_in_threadpool(  # stored modes, no image: no image_work
            _train_from_frames,
            session,
            panel_id,
            given.frame_ids,
            significance,
            shrinkage,
            timing,
        )
    return await image_work(
        request,
        _train_from_files,
        session,
        panel_id,
        camera_id,
        given.required_files("files"),
        significance,
        shrinkage,
        settings.max_pixels,
        timing,
    )


@router.get(
    "/panels/{panel_id}/baseline",
    response_model=BaselineOut,
    responses={**AUTH_ERRORS, **NOT_FOUND},
)
def get_baseline(
    panel_id: PanelId,
    session: SessionDep,
    _: RobotOrAdmin,
    camera_id: Annotated[
        str | None,
        Query(
            pattern=ID_PATTERN,
            description="The baseline that judges this camera's frames (the panel's newest "
            "measured in its region) instead of the panel's newest.",
        ),
    ] = None,
) -> BaselineOut:
    """The panel's newest baseline, or the one judging a camera's frames. A panel watched by
    cameras with different regions of interest has one in use per region."""
    panel = lookup.get_panel(session, panel_id)
    if camera_id is None:
        if panel.baseline_id is None:
            raise NotFound(f"panel {panel_id!r} has no baseline")
        return baseline_out(session.get(Baseline, panel.baseline_id))
    return baseline_out(panels.judging(session, panel, camera_id))


def warning_out(unfit: panels.Unfit) -> BaselineWarning:
    return BaselineWarning(code=unfit.code, baseline_id=unfit.baseline_id, detail=unfit.detail)


def baseline_out(row: Baseline | None) -> BaselineOut:
    """A baseline with what keeps it from judging, if anything."""
    assert row is not None
    unfit = panels.baseline_unfit(row)
    out = BaselineOut.model_validate(row)
    return out.model_copy(update={"warnings": [] if unfit is None else [warning_out(unfit)]})


def status_out(status: panels.Status, timing: Timing) -> PanelStatus:
    last = None
    if status.last is not None:
        frame, verdict = status.last
        base: dict[str, Any] = verdict_out(verdict).model_dump()
        last = PanelVerdictSummary(**base, frame_id=frame.id, captured_at=frame.captured_at)
    now = timing.now()
    return PanelStatus(
        panel_id=status.panel.id,
        state=status.state.value,
        last_verdict=last,
        open_task=TaskOut(**panels.task_view(status.task, now)) if status.task else None,
        ineffective=status.panel.ineffective,
        dirty_streak=status.panel.dirty_streak,
        streak_needed=timing.debounce,
        retired_at=status.panel.retired_at,
        baseline_id=status.panel.baseline_id,
        trend=TrendOut.model_validate(status.trend),
        views=[
            ViewOut(
                camera_id=v.camera_id,
                baseline_id=v.baseline_id,
                trend=TrendOut.model_validate(v.trend),
            )
            for v in status.views
        ],
        warnings=[warning_out(w) for w in status.warnings],
    )


@router.get(
    "/panels/{panel_id}/history",
    response_model=list[HistoryBucket],
    responses={**AUTH_ERRORS, **NOT_FOUND, **UNPROCESSABLE},
)
def panel_history(
    panel_id: PanelId,
    session: SessionDep,
    span: TimeRangeQuery,
    _: AnyReader,
    bucket: Annotated[Literal["hour", "day"], Query(description="UTC hours or days.")] = "day",
) -> list[HistoryBucket]:
    """The panel's verdicts of frames taken in [since, until), summed by UTC hour or day,
    oldest first: clean, dirty and not judged, T² and p-values, fleet p_dirty; by day, beside
    them its output, performance index and soiling ratio (the farm board's charts)."""
    rows = history.history(session, panel_id, since=span.since, until=span.until, bucket=bucket)
    if bucket == "day":
        rows = soiling.with_output(session, panel_id, rows, since=span.since, until=span.until)
    return [HistoryBucket(**r) for r in rows]


@router.get(
    "/panels/{panel_id}/status",
    response_model=PanelStatus,
    responses={**AUTH_ERRORS, **NOT_FOUND},
)
def panel_status(
    panel_id: PanelId, session: SessionDep, timing: TimingDep, _: AnyReader
) -> PanelStatus:
    """The panel's state, last verdict, open task and soiling trend."""
    return status_out(panels.panel_status(session, panel_id, timing), timing)


@router.get(
    "/panels/{panel_id}/trigger",
    response_model=Trigger,
    responses={**AUTH_ERRORS, **NOT_FOUND},
)
def trigger(panel_id: PanelId, session: SessionDep, timing: TimingDep, _: RobotOrAdmin) -> Trigger:
    """Polled by the panel's cleaning mechanism: should it clean now? Read only."""
    lookup.get_panel(session, panel_id)
    task = panels.open_task(session, panel_id)
    if task is None:
        return Trigger(panel_id=panel_id, clean_now=False, task_id=None)
    phase = panels.task_view(task, timing.now())["status"]
    return Trigger(panel_id=panel_id, clean_now=phase in ("pending", "claimed"), task_id=task.id)


def _evaluate(
    clean_files: list[tuple[str | None, bytes]],
    dirty_files: list[tuple[str | None, bytes]],
    significance: float,
    shrinkage: float,
    max_pixels: int,
) -> EvaluationOut:
    camera = CameraInfo(id="upload", kind=CameraKind.panel, panel_id=None, roi=None)
    clean = ingest.modes_of(ingest.decode_all(clean_files, camera, max_pixels=max_pixels))
    dirty = ingest.modes_of(ingest.decode_all(dirty_files, camera, max_pixels=max_pixels))
    ev = training.evaluate(clean, dirty, significance=significance, shrinkage=shrinkage)
    return EvaluationOut(
        n_clean=ev.rates.n_clean,
        n_dirty=ev.rates.n_dirty,
        hotelling=TwoSampleOut(
            t2=ev.test.t2,
            f_stat=ev.test.f_stat,
            df1=ev.test.df1,
            df2=ev.test.df2,
            p_value=ev.test.p_value,
            mean_difference=ev.test.mean_difference.tolist(),
        ),
        dirty_called_clean=ev.rates.dirty_called_clean,
        clean_called_dirty=ev.rates.clean_called_dirty,
        clean_modes=ev.clean_modes.tolist(),
        dirty_modes=ev.dirty_modes.tolist(),
    )


@router.post(
    "/panels/evaluate",
    response_model=EvaluationOut,
    responses={**AUTH_ERRORS, **BODY_ERRORS, **UNPROCESSABLE},
    openapi_extra=multipart_body(clean="files", dirty="files"),
)
async def evaluate(
    request: Request,
    settings: SettingsDep,
    _: Admin,
    significance: Significance = 0.05,
    shrinkage: Shrinkage = 0.0,
) -> EvaluationOut:
    """Do clean and dirty images differ (two-sample T²), and how often does T² err?

    Multipart with repeated fields ``clean`` (≥ 5) and ``dirty`` (≥ 1) images.
    """
    if content_type(request) != "multipart/form-data":
        raise UnsupportedMediaType("send multipart/form-data with fields clean and dirty")
    form = await read_form(
        request, settings.max_upload_bytes, max_files=2000, parts=("clean", "dirty")
    )
    clean, dirty = form.files_of("clean"), form.files_of("dirty")
    if len(clean) < 5 or not dirty:
        raise Unprocessable(
            f"need at least 5 clean and 1 dirty image; got {len(clean)} clean, {len(dirty)} dirty"
        )
    return await image_work(
        request, partial(_evaluate, clean, dirty, significance, shrinkage, settings.max_pixels)
    )
