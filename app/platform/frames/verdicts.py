"""The one dispatch point from a prepared frame to its verdict, by camera kind.

Runs on the group-commit writer (inside the batch's transaction): a classifier may read its
baseline or calibration and update state rows, and returns an unsaved verdict row. Anything
CPU-heavy belongs in ``ingest.analyse``, which runs in parallel before.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING

from sqlalchemy.orm import Session

from app.platform.db.models import CameraKind, Verdict
from app.platform.frames.stats import ChannelStats
from app.platform.http.errors import Unprocessable
from app.platform.policy import Policy

if TYPE_CHECKING:
    from app.platform.frames.ingest import Prepared

Classifier = Callable[[Session, "Prepared", Policy], Verdict]


def stats_columns(stats: ChannelStats) -> dict[str, float | int]:
    m, u = stats.modes, stats.means
    return {
        "mode_r": int(m[0]),
        "mode_g": int(m[1]),
        "mode_b": int(m[2]),
        "mean_r": float(u[0]),
        "mean_g": float(u[1]),
        "mean_b": float(u[2]),
    }


def _panel(session: Session, prepared: Prepared, policy: Policy) -> Verdict:
    from app.solar.panels import classify_frame

    return classify_frame(session, prepared, policy)


def _sky(session: Session, prepared: Prepared, policy: Policy) -> Verdict:
    from app.air.service import classify_frame

    return classify_frame(session, prepared, policy)


def _rig(session: Session, prepared: Prepared, policy: Policy) -> Verdict:
    return Verdict(
        frame_id=prepared.frame.id,
        camera_id=prepared.camera.id,
        **stats_columns(prepared.decoded.stats),
    )


CLASSIFIERS: dict[CameraKind, Classifier] = {
    CameraKind.panel: _panel,
    CameraKind.sky: _sky,
    CameraKind.rig: _rig,
}


def conclude(session: Session, prepared: Prepared, policy: Policy) -> Verdict:
    """The verdict on a prepared frame, by its camera's kind."""
    verdict = CLASSIFIERS[prepared.camera.kind](session, prepared, policy)
    verdict.roi = prepared.camera.region
    verdict.usable = prepared.decoded.quality is None
    return verdict


def check_usable(unusable: Sequence[tuple[str, str | None]]) -> None:
    """Refuse a model made from frames the quality gate found unusable (frame id, its reason):
    the modes of a night, glare or blank frame say nothing of the panel or the sky. Uploaded
    images are refused alike (``decode_all``)."""
    if unusable:
        problems = [f"{frame_id}: {reason or 'unusable'}" for frame_id, reason in unusable]
        raise Unprocessable(
            "unusable frames: " + "; ".join(problems[:10]),
            code="unusable_frames",
            unusable=[frame_id for frame_id, _ in unusable],
        )
