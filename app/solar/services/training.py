"""Training from labelled images: a panel's baseline and the T² evaluation (the fleet model's
training is ``fleet_training``)."""

from __future__ import annotations

import uuid
from collections.abc import Sequence
from dataclasses import dataclass
from datetime import datetime

import numpy as np
from numpy.typing import NDArray
from sqlalchemy import select
from sqlalchemy.orm import Session

from app.platform.db.models import Camera, CameraKind, Frame
from app.platform.frames import verdicts
from app.platform.frames.camera_info import (
    CameraInfo,
    Region,
    describe_region,
    one_view,
    region_now,
    uploads_in,
)
from app.platform.frames.cameras import check_in_service
from app.platform.frames.kinds import Decoded
from app.platform.http.errors import Unprocessable
from app.solar.core import power
from app.solar.models import Baseline, PanelVerdict
from app.solar.services import events
from app.solar.services.panels import baseline_unfit, lock_panel
from app.stats import hotelling


def panel_camera(session: Session, panel_id: str, camera_id: str | None) -> CameraInfo:
    """The camera whose ROI and decoding apply to uploaded images of a panel.

    The named camera, else the panel's cameras in service when they all have one region (one
    camera, or several with the same view of it), else the whole frame.
    """
    if camera_id is not None:
        camera = session.get(Camera, camera_id)
        if camera is None or camera.panel_id != panel_id:
            raise Unprocessable(f"camera {camera_id!r} does not watch panel {panel_id!r}")
        return CameraInfo.of(camera)  # features wanted: training may be for the fleet
    cameras = session.scalars(
        select(Camera)
        .where(Camera.panel_id == panel_id, Camera.retired_at.is_(None))
        .order_by(Camera.id)
    ).all()
    return uploads_in(one_view(cameras), CameraKind.panel, panel_id)


def check_one_size(names: Sequence[str | None], decoded: Sequence[Decoded]) -> None:
    """A baseline's photos are of one camera's view: one size. 422 naming those of another
    size than the first (a different camera, or a crop, whose modes are of another scene)."""
    first = (decoded[0].header.width, decoded[0].header.height) if decoded else None
    odd = [
        f"{name or f'file {i + 1}'} ({d.header.width}×{d.header.height})"
        for i, (name, d) in enumerate(zip(names, decoded, strict=True))
        if (d.header.width, d.header.height) != first
    ]
    if odd and first is not None:
        raise Unprocessable(
            f"a baseline's photos are of one camera's view, one size: the first is "
            f"{first[0]}×{first[1]}, but {', '.join(odd[:10])}",
            code="mixed_sizes",
        )


def modes_of_frames(
    session: Session, panel_id: str, frame_ids: Sequence[str]
) -> tuple[NDArray[np.float64], Region]:
    """Mode vectors of stored frames of this panel's cameras, in the order given, and the one
    region of interest they were all measured in (422 when they differ)."""
    rows = session.execute(
        select(
            PanelVerdict.frame_id,
            PanelVerdict.mode_r,
            PanelVerdict.mode_g,
            PanelVerdict.mode_b,
            PanelVerdict.roi,
            PanelVerdict.usable,
            PanelVerdict.reason,
            PanelVerdict.full_resolution,
        )
        .join(Frame, Frame.id == PanelVerdict.frame_id)
        .where(PanelVerdict.frame_id.in_(frame_ids), PanelVerdict.panel_id == panel_id)
    ).all()
    found = {r[0]: (r[1], r[2], r[3]) for r in rows}
    missing = [f for f in frame_ids if f not in found]
    if missing:
        raise Unprocessable(
            f"frames not found for panel {panel_id!r}: {', '.join(missing[:10])}",
            missing=missing,
        )
    verdicts.check_usable([(r[0], r[6]) for r in rows if not r[5]])
    reduced = [r[0] for r in rows if not r[7]]
    if reduced:
        raise Unprocessable(
            f"{len(reduced)} frames were measured before modes were taken at full size (their "
            f"modes are of a 1/2–1/8 scale decode): {', '.join(reduced[:10])}; train from "
            "newer frames or upload the images",
            code="reduced_scale_frames",
            frames=reduced,
        )
    regions = {r[0]: r[4] for r in rows}
    region = regions[frame_ids[0]]
    elsewhere = [f for f in frame_ids if regions[f] != region]
    if elsewhere:
        raise Unprocessable(
            f"the frames were measured in different regions of interest: {frame_ids[0]} in "
            f"{describe_region(region)}, {elsewhere[0]} in {describe_region(regions[elsewhere[0]])}"
            " (the camera's roi changed between them); train from frames of one region",
            code="mixed_regions",
        )
    return np.array([found[f] for f in frame_ids], dtype=np.float64), region


def check_region_in_use(session: Session, panel_id: str, region: Region) -> None:
    """Refuse a baseline no camera of the panel could use: one measured in a region of
    interest none of the panel's cameras in service measures now (a panel with no camera yet
    may be trained for any)."""
    cameras = session.scalars(
        select(Camera).where(Camera.panel_id == panel_id, Camera.retired_at.is_(None))
    ).all()
    if cameras and all(region_now(c) != region for c in cameras):
        now = "; ".join(f"{c.id}: {describe_region(region_now(c))}" for c in cameras)
        raise Unprocessable(
            f"these images were measured in {describe_region(region)}, but the panel's cameras "
            f"now measure another region ({now}), so the baseline would judge none of their "
            "frames: train from frames taken since the roi changed, or upload images naming "
            "the camera (camera_id)",
            code="region_not_in_use",
        )


def train_baseline(
    session: Session,
    panel_id: str,
    modes: NDArray[np.float64],
    *,
    significance: float,
    shrinkage: float,
    frame_ids: list[str] | None,
    roi: Region,
    now: datetime,
) -> Baseline:
    """Fit and store the panel's baseline, measured in region ``roi``; verdicts use it from the
    next frame on."""
    panel = lock_panel(session, panel_id)
    check_in_service(panel)
    check_region_in_use(session, panel_id, roi)
    try:
        fit = hotelling.fit_baseline(modes, significance=significance, shrinkage=shrinkage)
    except hotelling.BaselineError as exc:
        raise Unprocessable(str(exc), code="bad_baseline") from None
    row = Baseline(
        id=str(uuid.uuid4()),
        panel_id=panel.id,
        created_at=now,
        n=fit.n,
        mean_modes=fit.mean_modes.tolist(),
        covariance=fit.covariance.tolist(),
        significance=fit.significance,
        f_critical=fit.f_critical,
        condition_number=fit.condition_number,
        shrinkage=fit.shrinkage,
        frame_ids=frame_ids,
        roi=roi,
        detectable_veil=power.detectable_veil(
            fit.n, fit.mean_modes, fit.covariance, fit.f_critical
        ),
    )
    session.add(row)
    session.flush()
    unfit = baseline_unfit(row)
    if unfit is not None and unfit.code == "baseline_too_broad":
        events.baseline_too_broad(session, panel.id, row.id, unfit.detail, now)
    # trained on clean images: the panel is clean now, and its debounce starts afresh
    panel.baseline_id = row.id
    panel.dirty_streak, panel.last_clean, panel.ineffective = 0, None, False
    return row


@dataclass(frozen=True, slots=True)
class Evaluation:
    test: hotelling.TwoSampleT2
    rates: hotelling.Misclassification
    clean_modes: NDArray[np.float64]
    dirty_modes: NDArray[np.float64]


def evaluate(
    clean: NDArray[np.float64], dirty: NDArray[np.float64], *, significance: float, shrinkage: float
) -> Evaluation:
    """Two-sample T² between the sets and the classifier's two error rates."""
    try:
        test = hotelling.two_sample_t2(clean, dirty)
        rates = hotelling.misclassification(
            clean, dirty, significance=significance, shrinkage=shrinkage
        )
    except ValueError as exc:  # BaselineError included: too few or degenerate sets
        raise Unprocessable(str(exc), code="bad_baseline") from None
    return Evaluation(test, rates, clean, dirty)
