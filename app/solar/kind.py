"""Panel cameras' part of the ingest path (``KindHandler``), handed to the platform by
``app.main``: its fleet features, and its verdict's shape. Panel frames are decoded at full size:
the T² statistic is of the modes of the picture's own pixels (chapter 5 §III)."""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import replace

import numpy as np
from numpy.typing import NDArray
from sqlalchemy import select
from sqlalchemy.orm import Session

from app.platform.db.models import Camera, Verdict
from app.platform.frames.camera_info import CameraInfo
from app.platform.frames.cameras import check_in_service
from app.platform.frames.kinds import KindHandler, Pixels, verdict_common
from app.platform.http.errors import NotFound, Unprocessable
from app.platform.schemas import PanelVerdictOut
from app.solar.core import fleet
from app.solar.models import Baseline, Panel, PanelVerdict, Robot
from app.solar.services import labels, panels


def _features(pixels: Pixels) -> NDArray[np.float64] | None:
    """The fleet model's features, unless the camera's view has a baseline of its own."""
    return None if pixels.camera.has_reference else fleet.features(pixels.region)


def _describe(session: Session, camera: Camera, info: CameraInfo) -> CameraInfo:
    """``has_reference``: the panel has a baseline of the camera's view (region) fit to judge,
    so the fleet model's features need not be computed."""
    panel = session.get(Panel, camera.panel_id) if camera.panel_id is not None else None
    row = None if panel is None else panels.baseline_for(session, panel, info.region)
    if row is None or panels.baseline_unfit(row) is not None:
        return info
    return replace(info, has_reference=True)


def _check_camera(session: Session, panel_id: str) -> None:
    try:  # locked: a panel being retired meanwhile either sees this camera or refuses it
        panel = panels.lock_panel(session, panel_id)
    except NotFound:
        raise Unprocessable(f"panel {panel_id!r} does not exist; create it first") from None
    check_in_service(panel)


def _panel_exists(session: Session, panel_id: str) -> bool:
    return session.get(Panel, panel_id) is not None


def robot_of(session: Session, digest: str) -> str | None:
    """The robot a token (its SHA-256 hash) belongs to: a caller of role ``robot``."""
    robot_id: str | None = session.scalar(select(Robot.id).where(Robot.token_hash == digest))
    return robot_id


def verdict_out(verdict: Verdict) -> PanelVerdictOut:
    """A panel verdict row as the frame endpoints answer it."""
    assert isinstance(verdict, PanelVerdict)
    return PanelVerdictOut(
        panel_id=verdict.panel_id,
        clean=verdict.clean,
        t2=verdict.t2,
        f_stat=verdict.f_stat,
        p_value=verdict.p_value,
        threshold=verdict.threshold,
        state=verdict.state,
        method=verdict.method,
        baseline_id=verdict.baseline_id,
        p_dirty=verdict.p_dirty,
        condition=verdict.condition,
        late=bool(verdict.late),
        cleaning=verdict.cleaning,
        **verdict_common(verdict),
    )


def _baseline_frames(session: Session) -> Iterator[str]:
    """The frames baselines were trained from, and those the farm labelled (to learn from)."""
    for ids in session.scalars(select(Baseline.frame_ids)):
        yield from ids or []
    yield from labels.labelled_frames(session)


HANDLER = KindHandler(
    conclude=panels.classify_frame,
    verdict_out=verdict_out,
    features=_features,
    describe=_describe,
    check_camera=_check_camera,
    link_exists=_panel_exists,
    verdict_table=PanelVerdict,
    kept_frames=_baseline_frames,
)
