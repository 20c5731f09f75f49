"""Request and response bodies of the domain, on the platform's base models."""

from __future__ import annotations

from datetime import datetime
from typing import Annotated, Any, Literal

import numpy as np
from pydantic import Field, field_validator, model_validator

from app.cells.core.triangulation import decompose_projection
from app.platform.schemas import Id, Out, Schema


class EllipseOut(Out):
    center: list[float] = Field(description="[x, y] [px].")
    axes: list[float] = Field(description="Full lengths of the two axes [px].")
    angle: float = Field(description="Rotation of the first axis [°].")


class OutlineOut(Out):
    shape: Literal["polygon", "curved"]
    corners: list[list[float]] = Field(
        description="[[x, y], ...] counter-clockwise as seen in the image (y down) [px]."
    )
    lines: list[list[float]] = Field(description="Sides [[x1, y1, x2, y2], ...] [px].")
    contour: list[list[float]] = Field(description="Outer contour, simplified [px].")
    ellipses: list[EllipseOut] = Field(description="Ellipses fitted to curved arcs.")
    roi_offset: list[int] = Field(description="[x, y] of the ROI; coordinates include it.")
    canny_thresholds: list[float] = Field(description="[low, high] in OpenCV's units.")
    shadow_theta: float | None = Field(description="θ of the image shift (eq. 3.1), if used.")
    part: Literal["dark", "light"] = Field(
        description="Whether the part was taken as darker or lighter than its background."
    )
    residual_px: float = Field(
        description="RMS distance of the outline's edge pixels from the fitted shape [px]."
    )
    edge_support: float = Field(
        description="Share of the fitted shape's length backed by an edge pixel within "
        "1.5 px [0–1]. An image that supports no outline is answered 422 outline_not_found."
    )


Finite = Annotated[float, Field(allow_inf_nan=False)]


ROTATION_TOLERANCE = 1e-4
"""How far RᵀR may stray from I: rotations written out to 5–6 decimals pass."""


class PanTiltHead(Schema):
    pivot: list[Finite] = Field(
        min_length=3,
        max_length=3,
        description="[X, Y, Z] where the head's pan and tilt axes cross, in the rig's frame "
        "[world units]. The camera's K, R and t are its calibration at pan = tilt = 0; pan "
        "turns about the rig's Z axis, then tilt about the panned X axis (eq. 4.49).",
    )


class CalibratedCamera(Schema):
    P: list[list[Finite]] | None = Field(
        default=None,
        exclude=True,
        description="Instead of K, R and t: the 3 × 4 projection matrix P = λ K [R | t], as "
        "multi-view data sets publish it (visible points at w > 0); decomposed into K, R and t, "
        "which the answer shows. A mirror-handed or singular P is refused (422).",
    )
    K: list[list[Finite]] = Field(description="3 × 3 camera matrix [px].")
    dist: list[Finite] = Field(
        default_factory=lambda: [0.0] * 5, description="[k1, k2, p1, p2, k3]."
    )
    R: list[list[Finite]] = Field(description="3 × 3 rotation, world → camera.")
    t: list[Finite] = Field(description="Translation, x_cam = R X + t [world units].")
    image_size: list[Annotated[int, Field(ge=1, le=100_000)]] | None = Field(
        default=None,
        min_length=2,
        max_length=2,
        description="[width, height] [px] of the images K was calibrated for: the laser "
        "endpoints refuse images of another size (422 wrong_image_size).",
    )
    head: PanTiltHead | None = Field(
        default=None,
        description="The camera sits on a pan/tilt head: every triangulation and laser "
        "request then gives its pan and tilt (pan_tilt_deg).",
    )

    @model_validator(mode="before")
    @classmethod
    def _from_projection(cls, data: Any) -> Any:
        """A camera given as ``P`` (3 × 4, as multi-view data sets publish it) instead of K, R
        and t: decomposed (``decompose_projection``); its images are taken as undistorted."""
        if not isinstance(data, dict) or "P" not in data:
            return data
        given = [k for k in ("K", "R", "t") if k in data]
        if given:
            raise ValueError(f"give P, or K, R and t; not both (also given: {', '.join(given)})")
        rest = {k: v for k, v in data.items() if k != "P"}
        try:
            k, r, t = decompose_projection(np.asarray(data["P"], dtype=np.float64))
        except (TypeError, ValueError) as exc:
            raise ValueError(f"P: {exc}") from None
        return {**rest, "K": k.tolist(), "R": r.tolist(), "t": t.tolist()}

    @field_validator("K", "R")
    @classmethod
    def _three_by_three(cls, m: list[list[float]]) -> list[list[float]]:
        if len(m) != 3 or any(len(r) != 3 for r in m):
            raise ValueError("must be 3 × 3")
        return m

    @field_validator("t")
    @classmethod
    def _three(cls, v: list[float]) -> list[float]:
        if len(v) != 3:
            raise ValueError("must have 3 numbers")
        return v

    @field_validator("dist")
    @classmethod
    def _five(cls, v: list[float]) -> list[float]:
        if len(v) not in (4, 5):
            raise ValueError("must be [k1, k2, p1, p2] or [k1, k2, p1, p2, k3]")
        return v

    @field_validator("K")
    @classmethod
    def _a_camera_matrix(cls, k: list[list[float]]) -> list[list[float]]:
        """Eq. 2.9's form: fx, fy > 0 (a negative focal length puts every point behind the
        camera) and a last row [0, 0, 1]."""
        if not (k[0][0] > 0 and k[1][1] > 0):
            raise ValueError(f"fx = {k[0][0]:g} and fy = {k[1][1]:g} must both be positive")
        if k[1][0] != 0 or k[2] != [0, 0, 1]:
            raise ValueError("must be [[fx, s, cx], [0, fy, cy], [0, 0, 1]]")
        return k

    @field_validator("R")
    @classmethod
    def _a_rotation(cls, r: list[list[float]]) -> list[list[float]]:
        """A proper rotation: orthonormal within ``ROTATION_TOLERANCE`` and det R = +1 (−1 is a
        mirror, which no camera's pose is)."""
        m = np.asarray(r, dtype=np.float64)
        off = float(np.abs(m.T @ m - np.eye(3)).max())
        if off > ROTATION_TOLERANCE:
            raise ValueError(f"is not a rotation: RᵀR differs from I by up to {off:.2g}")
        if np.linalg.det(m) < 0:
            raise ValueError("is a mirror (det R = −1), not a rotation")
        return r


class RobotFrame(Schema):
    """Where a calibrated rig stands in a robot's base: one of its cameras' hand-eye
    calibration (eye to hand, ``POST /calibrations/hand-eye``)."""

    hand_eye_id: str = Field(max_length=64, description="The hand-eye calibration's id.")
    camera: int = Field(0, ge=0, le=63, description="Which of the rig's cameras it calibrated.")
    rig_unit_m: float = Field(
        1.0,
        gt=0,
        le=1000,
        allow_inf_nan=False,
        description="The rig's unit of length in metres (0.001 for a rig calibrated in mm): "
        "the robot's base is in metres.",
    )


class RigSpec(Schema):
    """A rig's geometry: what ``PUT /rigs/{id}`` replaces."""

    kind: Literal["cross", "calibrated"]
    f_px: Annotated[float, Field(gt=0, allow_inf_nan=False)] | None = None
    ax: Annotated[float, Field(gt=0, allow_inf_nan=False)] | None = None
    ay: Annotated[float, Field(gt=0, allow_inf_nan=False)] | None = None
    principal_point: list[Finite] | None = Field(
        default=None, min_length=2, max_length=2, description="[cx, cy] [px]."
    )
    image_size: list[Annotated[int, Field(ge=1, le=100_000)]] | None = Field(
        default=None,
        min_length=2,
        max_length=2,
        description="Cross rig: [width, height] [px] of the images f_px and principal_point "
        "are in, the same for the four cameras: the laser endpoints refuse images of another "
        "size (422 wrong_image_size). Calibrated rigs give it per camera.",
    )
    cameras: list[CalibratedCamera] | None = None
    robot: RobotFrame | None = Field(
        default=None,
        description="Calibrated rigs: the hand-eye calibration of one of its cameras, so that "
        "triangulate answers in the robot's base too (frame=robot).",
    )
    calibration_id: str | None = Field(
        default=None,
        max_length=64,
        description="Instead of ``cameras``: a stereo calibration (POST /calibrations/stereo). "
        "Its left camera is the world frame (R = I, t = 0) and the right one sits at its R "
        "and T, in the units of the board's square_size.",
    )


class RigCreate(RigSpec):
    id: Id


class RigReplace(RigSpec):
    id: Id | None = Field(
        default=None, description="May be sent (the body POST /rigs took); must be the rig's."
    )


class RigOut(Out):
    id: str
    kind: str
    spec: dict[str, object]
    created_at: datetime
    updated_at: datetime | None = Field(
        default=None, description="When its geometry was last replaced (PUT), if ever."
    )


PanTilt = Annotated[
    list[Annotated[list[Finite], Field(min_length=2, max_length=2)] | None] | None,
    Field(
        description="Calibrated rigs with cameras on pan/tilt heads: per camera [pan, tilt] "
        "[°] as the head stood for these observations, null for a camera without a head.",
    ),
]


class TriangulateIn(Schema):
    observations: list[list[list[Finite] | None]] = Field(
        description="Per point, per camera: [u, v] in pixels, or null when not seen.",
        max_length=200_000,
    )
    pan_tilt_deg: PanTilt = None
    method: Literal["least_squares", "weighted", "mean"] = Field(
        default="least_squares",
        description="Cross rigs: all 8 coordinates (ML), inverse-variance weights, or the "
        "plain mean of the ten estimates (eq. 4.47).",
    )
    frame: Literal["rig", "robot"] = Field(
        default="rig",
        description="rig: the rig's own frame and unit; robot: the robot's base [m], for a "
        "rig carrying a hand-eye calibration (``robot``).",
    )


class TriangulateOut(Out):
    frame: Literal["rig", "robot"] = Field(
        default="rig", description="The frame of ``points``: the rig's, or the robot's base [m]."
    )
    points: list[list[float] | None]
    reprojection_rms_px: list[float | None]
    null_reasons: list[Literal["too_few_views", "behind_camera", "no_depth"] | None] = Field(
        default_factory=list,
        description="Per point, why it is null: seen by fewer than two cameras; its rays meet "
        "behind (or at) a camera that saw it (mismatched pixels); no depth (no disparity: at "
        "infinity, or the same pixel everywhere). Null for a point found.",
    )
    z_estimates: list[list[float | None]] | None = Field(
        default=None, description="Cross rigs: the ten pairwise depths (eqs. 4.14–4.41)."
    )
    z_spread: list[float | None] | None = None


class LaserDotOut(Out):
    point: list[float] = Field(description="[X, Y, Z] in the rig's frame.")
    pixels: list[list[float] | None] = Field(description="The dot in each camera [u, v], or null.")
    reprojection_rms_px: float


class LaserGridOut(Out):
    points: list[list[float]] = Field(description="Every grid node located, [X, Y, Z].")
    labels: list[list[int]] = Field(
        description="Each point's [row, column] on the grid. The surface the laser dot lands on "
        "is labelled from the dot (0, 0); each other connected surface from its own first node."
    )
    surfaces: list[int] = Field(description="Each point's connected surface; −1: isolated.")
    reprojection_rms_px: list[float]
    surface_area: float = Field(
        description="3-D area of the part's surface the grid covers (above the base plane) "
        "[units²]."
    )
    side_area: float = Field(
        description="Walls from the part's outline down to the base plane [units²]."
    )
    footprint_area: float = Field(description="The part's outline on the base plane [units²].")
    volume: float = Field(description="Between the part's surface and the base plane [units³].")
    base_plane: list[float] = Field(
        description="[a, b, c, d]: a X + b Y + c Z + d = 0, unit normal towards the cameras."
    )
    height_max: float = Field(
        description="The part's height above the base plane (98th percentile of its nodes)."
    )
    nodes_per_view: list[int]
    boundary_traced: int = Field(
        description="Outline crossings placed where a laser line ends in the images."
    )
    boundary_guessed: int = Field(description="Outline crossings placed at mid-cell.")
    warnings: list[str]


class ShapeMatchIn(Schema):
    points: list[list[Finite]] = Field(
        min_length=6, max_length=10_000, description="3-D corner points [[X, Y, Z], ...]."
    )


class ShapeFitOut(Out):
    shape: Literal["box", "prism", "cylinder"]
    dimensions: dict[str, float]
    centre: list[float]
    axes: list[list[float]] = Field(description="The shape's local x, y, z axes (rows).")
    rms: float = Field(description="RMS distance of the points from the fitted shape.")
    hidden_corners: int = Field(
        description="The shape's corners no point lies near (unseen, or not the part's)."
    )
