"""Measuring rigs: their geometry as registered, kept, replaced and read back as core objects."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray
from sqlalchemy import select
from sqlalchemy.exc import IntegrityError
from sqlalchemy.orm import Session

from app.cells.core import hand_eye, laser_grid, pantilt
from app.cells.core.triangulation import (
    CrossRig,
    RigArrays,
    View,
    baseline,
    triangulate_cross,
    triangulate_views,
)
from app.cells.models import Calibration, Rig
from app.cells.schemas import RigSpec, RobotFrame
from app.cells.services import calibrations
from app.platform.db.base import utcnow
from app.platform.http.errors import Conflict, Unprocessable
from app.platform.lookup import get_or_404


def spec_of(session: Session, body: RigSpec) -> dict[str, Any]:
    """The geometry a rig keeps, checked: a cross's f_px, ax, ay, principal point; or the
    calibrated cameras, given or from a stereo calibration."""
    if body.kind == "cross":
        if body.cameras is not None or body.calibration_id is not None or body.robot is not None:
            raise Unprocessable("a cross rig takes f_px, ax, ay and principal_point")
        if body.f_px is None or body.ax is None or body.ay is None:
            raise Unprocessable("a cross rig needs f_px, ax and ay")
        cx, cy = body.principal_point or [0.0, 0.0]
        return {
            "f_px": body.f_px,
            "ax": body.ax,
            "ay": body.ay,
            "principal_point": [cx, cy],
            "image_size": body.image_size,
        }
    if body.image_size is not None:
        raise Unprocessable("a calibrated rig gives image_size per camera (cameras[i].image_size)")
    robot = {}
    if body.robot is not None:
        given = body.cameras
        cams = (
            [c.model_dump() for c in given]
            if given is not None
            else calibrations.stereo_cameras(session, body.calibration_id or "")
            if body.calibration_id is not None
            else []
        )
        robot = {"robot": robot_frame(session, body.robot, cams)}
    if body.calibration_id is not None:
        if body.cameras is not None:
            raise Unprocessable("give the cameras or a calibration_id, not both")
        cameras = calibrations.stereo_cameras(session, body.calibration_id)
        return {"cameras": cameras, "calibration_id": body.calibration_id, **robot}
    if not body.cameras or len(body.cameras) < 2:
        raise Unprocessable(
            "a calibrated rig needs at least 2 cameras, or the calibration_id of a stereo pair"
        )
    for i, c in enumerate(body.cameras):
        r = np.array(c.R)
        if not np.allclose(r @ r.T, np.eye(3), atol=1e-6) or np.linalg.det(r) < 0:
            raise Unprocessable(f"camera {i}: R is not a rotation")
        if np.linalg.det(np.array(c.K)) == 0:
            raise Unprocessable(f"camera {i}: K is singular")
    cameras = [c.model_dump() for c in body.cameras]
    rig = RigArrays.of([_view(c) for c in cameras])
    if baseline(rig.rs, rig.ts) == 0:
        raise Unprocessable(
            "every camera has the same lens centre (−Rᵀt): with no baseline between them no "
            "point can be triangulated; check each camera's t"
        )
    return {"cameras": cameras, **robot}


K_TOLERANCE = 0.01
"""A rig camera's K may differ from the hand-eye calibration's by this share and be the same
camera."""


def robot_frame(
    session: Session, robot: RobotFrame, cameras: list[dict[str, Any]]
) -> dict[str, Any]:
    """The rig's frame in the robot's base: ``rig_to_base`` (4×4) maps a rig point, in metres,
    into the base: ``X · [R_k | u t_k]`` with ``X`` the hand-eye's base ← camera and camera
    ``k`` at ``R_k``, ``t_k`` in the rig (its unit ``u`` metres)."""
    if robot.camera >= len(cameras):
        raise Unprocessable(f"robot.camera: the rig has {len(cameras)} cameras")
    row = session.get(Calibration, robot.hand_eye_id)
    if row is None or row.kind != "hand_eye":
        raise Unprocessable(
            f"robot.hand_eye_id: no hand-eye calibration {robot.hand_eye_id!r}",
            code="no_such_calibration",
        )
    if row.result["setup"] != "eye_to_hand":
        raise Unprocessable(
            "robot.hand_eye_id: an eye-in-hand calibration places the camera on the flange, "
            "which moves; a rig's cameras stand still: give a fixed camera's (eye_to_hand)"
        )
    cam = cameras[robot.camera]
    measured = session.get(Calibration, row.result["calibration_id"])
    if measured is not None:
        k_he = np.array((measured.result.get("left") or measured.result)["K"], dtype=np.float64)
        k_rig = np.array(cam["K"], dtype=np.float64)
        if np.abs(k_rig - k_he).max() > K_TOLERANCE * float(k_he[0, 0]):
            raise Unprocessable(
                f"robot: camera {robot.camera}'s K is not the hand-eye calibration's camera's: "
                "calibrate that camera, or name the rig's camera it is"
            )
    x = np.array(row.result["camera_to_base"], dtype=np.float64)
    pose = hand_eye.rigid(
        np.array(cam["R"], dtype=np.float64),
        robot.rig_unit_m * np.array(cam["t"], dtype=np.float64),
    )
    return {**robot.model_dump(), "rig_to_base": (x @ pose).tolist()}


def in_base(row: Rig, points: NDArray[np.float64]) -> NDArray[np.float64]:
    """Rig points (N, 3) in the robot's base [m]; 422 for a rig without a hand-eye."""
    robot = row.spec.get("robot")
    if robot is None:
        raise Unprocessable(
            "frame=robot: the rig carries no hand-eye calibration (PUT /rigs/{id} with robot)"
        )
    m = np.array(robot["rig_to_base"], dtype=np.float64)
    metres = points * float(robot["rig_unit_m"])
    return np.asarray(metres @ m[:3, :3].T + m[:3, 3], dtype=np.float64)


def create(session: Session, rig_id: str, body: RigSpec) -> Rig:
    if session.get(Rig, rig_id) is not None:
        raise Conflict(f"a rig with id {rig_id!r} already exists")
    row = Rig(id=rig_id, kind=body.kind, spec=spec_of(session, body), created_at=utcnow())
    session.add(row)
    try:
        session.flush()
    except IntegrityError:  # a concurrent request inserted the same id first
        raise Conflict(f"a rig with id {rig_id!r} already exists") from None
    return row


def get(session: Session, rig_id: str, *, lock: bool = False) -> Rig:
    return get_or_404(session, Rig, rig_id, "rig", lock=lock)


def replace(session: Session, rig_id: str, body: RigSpec) -> Rig:
    """New geometry for a rig (the cameras were moved or calibrated again): every measurement
    from now on uses it. Nothing measured is kept with a rig, so nothing else changes."""
    row = get(session, rig_id, lock=True)
    row.kind, row.spec, row.updated_at = body.kind, spec_of(session, body), utcnow()
    session.flush()
    return row


def delete(session: Session, rig_id: str) -> None:
    session.delete(get(session, rig_id, lock=True))
    session.flush()


def listed(session: Session, *, limit: int, offset: int) -> Sequence[Rig]:
    return session.scalars(select(Rig).order_by(Rig.id).limit(limit).offset(offset)).all()


def cameras(row: Rig) -> int:
    return 4 if row.kind == "cross" else len(row.spec["cameras"])


def cross_of(row: Rig) -> CrossRig:
    s = row.spec
    return CrossRig(
        f=s["f_px"], ax=s["ax"], ay=s["ay"], cx=s["principal_point"][0], cy=s["principal_point"][1]
    )


def views_of(row: Rig, pan_tilt_deg: list[list[float] | None] | None = None) -> list[View]:
    """The rig's calibrated cameras, those on pan/tilt heads turned to ``pan_tilt_deg`` (per
    camera [pan, tilt] in degrees, None without a head): 422 when a head's angles are missing
    or angles are given for a camera without one."""
    cameras = row.spec["cameras"]
    heads = [c.get("head") for c in cameras]
    if pan_tilt_deg is None:
        pan_tilt_deg = [None] * len(cameras)
    if len(pan_tilt_deg) != len(cameras):
        raise Unprocessable(f"pan_tilt_deg: {len(pan_tilt_deg)} entries for {len(cameras)} cameras")
    views = []
    for i, (camera, head, angles) in enumerate(zip(cameras, heads, pan_tilt_deg, strict=True)):
        view = _view(camera)
        if head is None and angles is not None:
            raise Unprocessable(f"pan_tilt_deg[{i}]: camera {i} is not on a pan/tilt head")
        if head is not None:
            if angles is None:
                raise Unprocessable(
                    f"pan_tilt_deg[{i}]: camera {i} is on a pan/tilt head: give its pan and tilt"
                )
            pan, tilt = np.radians(angles)
            r, t = pantilt.head_pose(view.R, view.t, head["pivot"], float(pan), float(tilt))
            view = View(view.K, view.dist, r, t)
        views.append(view)
    return views


def _view(camera: dict[str, Any]) -> View:
    return View(*(np.array(camera[k], dtype=np.float64) for k in ("K", "dist", "R", "t")))


def sizes_of(row: Rig) -> list[tuple[int, int] | None]:
    """Per camera, the image size its K was calibrated for, when known."""
    if row.kind == "cross":
        size = row.spec.get("image_size")  # none on rigs registered before it was asked
        return [(int(size[0]), int(size[1])) if size else None] * 4
    return [
        (int(c["image_size"][0]), int(c["image_size"][1])) if c.get("image_size") else None
        for c in row.spec["cameras"]
    ]


def geometry_of(
    row: Rig, pan_tilt_deg: list[list[float] | None] | None = None
) -> laser_grid.Geometry:
    if row.kind == "cross":
        if pan_tilt_deg is not None:
            raise Unprocessable("pan_tilt_deg: the cross's cameras are on no pan/tilt heads")
        return laser_grid.cross_geometry(cross_of(row))
    return laser_grid.views_geometry(views_of(row, pan_tilt_deg))


NULL_REASONS = {
    "too_few_views": "seen by fewer than two cameras",
    "behind_camera": "its rays meet behind (or at) a camera that saw it: the pixels are "
    "mismatched (cameras in the wrong order, or another point's pixel)",
    "no_depth": "no depth: the views see it with no disparity (at infinity, or the same pixel "
    "in every camera)",
}
"""Why a point is null, by code (``Triangulated.reasons``)."""


@dataclass(frozen=True, slots=True)
class Triangulated:
    points: NDArray[np.float64]
    """(N, 3) in the rig's frame; NaN rows where no point was found."""
    reprojection_rms: NDArray[np.float64]
    reasons: list[str | None]
    """Per point, why it is NaN (a key of ``NULL_REASONS``), or None when it was found."""
    z_estimates: NDArray[np.float64] | None = None
    """Cross rigs: (N, 10), the pairwise depths."""
    z_spread: NDArray[np.float64] | None = None


def _reasons(
    points: NDArray[np.float64], few: NDArray[np.bool_], behind: NDArray[np.bool_]
) -> list[str | None]:
    found = np.asarray(np.isfinite(points).all(axis=1), dtype=np.bool_)
    return [
        None if ok else "too_few_views" if short else "behind_camera" if back else "no_depth"
        for ok, short, back in zip(found, few, behind, strict=True)
    ]


def triangulate(
    row: Rig,
    obs: NDArray[np.float64],
    method: str,
    pan_tilt_deg: list[list[float] | None] | None = None,
) -> Triangulated:
    """Points from pixel observations (N, cameras, 2) [px], NaN for a view that missed one;
    cameras on pan/tilt heads turned to ``pan_tilt_deg``."""
    few = np.isfinite(obs).all(axis=-1).sum(axis=1) < 2
    if row.kind != "cross":
        res = triangulate_views(views_of(row, pan_tilt_deg), obs)
        return Triangulated(res.points, res.reprojection_rms, _reasons(res.points, few, res.behind))
    if pan_tilt_deg is not None:
        raise Unprocessable("pan_tilt_deg: the cross's cameras are on no pan/tilt heads")
    rig = cross_of(row)
    # a point seen once is solved from a stand-in (its depth would be undetermined) and dropped
    safe = np.where(few[:, None, None], rig.project(np.array([[0.0, 0.0, 1.0]]))[0], obs)
    with np.errstate(all="ignore"):
        r = triangulate_cross(rig, safe, method=method)
    points, est = r.points.copy(), r.z_estimates.copy()
    points[few], est[few] = np.nan, np.nan
    return Triangulated(
        points,
        np.where(few, np.nan, r.reprojection_rms),
        _reasons(points, few, r.behind),
        est,
        np.where(few, np.nan, r.z_spread),
    )
