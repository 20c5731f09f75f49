"""The one dispatch point from a frame's statistics to a verdict, by camera kind.

Each kind's classifier receives the session (for its baseline or calibration), the camera, the
new frame row and the frame's channel statistics, and returns an unsaved verdict row.
"""

from __future__ import annotations

from collections.abc import Callable

from sqlalchemy.orm import Session

from app.core.stats import ChannelStats
from app.db.models import CameraKind, Frame, PanelVerdict, SkyVerdict, Verdict
from app.services.camera_info import CameraInfo

Classifier = Callable[[Session, CameraInfo, Frame, ChannelStats], Verdict]


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


def _panel(session: Session, camera: CameraInfo, frame: Frame, stats: ChannelStats) -> Verdict:
    reason = "camera is not attached to a panel" if camera.panel_id is None else "no baseline"
    return PanelVerdict(
        frame_id=frame.id,
        camera_id=camera.id,
        panel_id=camera.panel_id,
        clean=None,
        reason=reason,
        state="no_baseline",
        **stats_columns(stats),
    )


def _sky(session: Session, camera: CameraInfo, frame: Frame, stats: ChannelStats) -> Verdict:
    return SkyVerdict(
        frame_id=frame.id,
        camera_id=camera.id,
        level=None,
        category=None,
        reason="air-quality model not calibrated",
        **stats_columns(stats),
    )


def _rig(session: Session, camera: CameraInfo, frame: Frame, stats: ChannelStats) -> Verdict:
    return Verdict(frame_id=frame.id, camera_id=camera.id, **stats_columns(stats))


CLASSIFIERS: dict[CameraKind, Classifier] = {
    CameraKind.panel: _panel,
    CameraKind.sky: _sky,
    CameraKind.rig: _rig,
}


def conclude(session: Session, camera: CameraInfo, frame: Frame, stats: ChannelStats) -> Verdict:
    """The verdict on ``frame`` from its statistics, by ``camera.kind``."""
    return CLASSIFIERS[camera.kind](session, camera, frame, stats)
