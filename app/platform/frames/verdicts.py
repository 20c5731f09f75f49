"""What every kind's verdict shares: the channel statistics it keeps, and the refusal of models
made from frames the quality gate found unusable."""

from __future__ import annotations

from collections.abc import Sequence

from app.platform.frames.stats import ChannelStats
from app.platform.http.errors import Unprocessable


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
