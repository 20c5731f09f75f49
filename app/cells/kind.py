"""Rig cameras' part of the ingest path (``KindHandler``), handed to the platform by
``app.main``: a rig frame keeps its channel statistics; measuring is asked for explicitly."""

from __future__ import annotations

from sqlalchemy.orm import Session

from app.platform.db.models import Verdict
from app.platform.frames.kinds import (
    KindHandler,
    Prepared,
    reduced_to_statistics,
    verdict_common,
)
from app.platform.frames.verdicts import stats_columns
from app.platform.schemas import RigVerdictOut
from app.platform.timing import Timing


def conclude(session: Session, prepared: Prepared, timing: Timing) -> Verdict:
    """A rig frame's verdict: its statistics only."""
    return Verdict(
        frame_id=prepared.frame.id,
        camera_id=prepared.camera.id,
        **stats_columns(prepared.decoded.stats),
    )


def verdict_out(verdict: Verdict) -> RigVerdictOut:
    return RigVerdictOut(**verdict_common(verdict))


# a rig frame keeps its statistics only: a large one is decoded reduced (measuring decodes the
# stored frame again, at full size)
HANDLER = KindHandler(conclude=conclude, verdict_out=verdict_out, reduction=reduced_to_statistics)
