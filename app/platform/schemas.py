"""Request and response bodies, on one project base model."""

from __future__ import annotations

from datetime import datetime
from typing import Annotated, Literal

import shapely
from pydantic import AfterValidator, BaseModel, ConfigDict, Field, field_validator

from app.platform.db.models import CameraKind


def _addressable(value: str) -> str:
    """An id that a URL can name: ``.`` and ``..`` match the id pattern, but every HTTP client
    resolves them as dot-segments (RFC 3986 §5.2.4), so ``/air/cameras/../latest`` is sent as
    ``/air/latest`` and the thing registered could never be reached."""
    if value in (".", ".."):
        raise ValueError(f"{value!r} cannot be an id: URLs resolve it as a dot-segment")
    return value


Id = Annotated[
    str,
    Field(
        pattern=r"^[A-Za-z0-9._-]{1,64}$",
        examples=["roof-3"],
        description="Letters, digits, '.', '_', '-'; not '.' or '..' alone (URLs resolve those).",
    ),
    AfterValidator(_addressable),
]
Lat = Annotated[float, Field(ge=-90, le=90, description="Latitude [°], WGS 84.")]
Lon = Annotated[float, Field(ge=-180, le=180, description="Longitude [°], WGS 84.")]


class Schema(BaseModel):
    """Project base: no NaN or infinity anywhere, no NUL in text, unknown fields refused."""

    model_config = ConfigDict(allow_inf_nan=False, extra="forbid", from_attributes=True)

    @field_validator("*", mode="after")
    @classmethod
    def _no_nul(cls, value: object) -> object:
        # PostgreSQL text cannot hold NUL; refuse it here rather than fail in the database
        if isinstance(value, str) and "\x00" in value:
            raise ValueError("must not contain NUL characters")
        return value


class Out(Schema):
    model_config = ConfigDict(extra="ignore")


RoiField = Annotated[
    list[int] | list[list[int]] | None,
    Field(
        description="Region of interest in pixels of the full frame: a rectangle [x, y, w, h], "
        "or a polygon [[x, y], ...] (3–64 vertices, simple, in order) — a sky above an "
        "irregular skyline, a panel seen in perspective.",
        examples=[[0, 60, 640, 300], [[0, 0], [640, 0], [640, 180], [320, 240], [0, 200]]],
    ),
]


class CameraFields(Schema):
    """What an operator may say about a camera, at registration and later."""

    name: Annotated[str, Field(max_length=200)] | None = None
    lat: Lat | None = None
    lon: Lon | None = None
    panel_id: Id | None = Field(default=None, description="The panel this camera watches.")
    roi: RoiField = None

    @field_validator("roi")
    @classmethod
    def _roi_shape(
        cls, roi: list[int] | list[list[int]] | None
    ) -> list[int] | list[list[int]] | None:
        return _roi(roi)


class CameraCreate(CameraFields):
    id: Id
    kind: CameraKind


class CameraUpdate(CameraFields):
    """The fields to change: a field left out keeps its value, ``null`` clears it (a camera
    without ``roi`` is judged on the whole frame). A camera's id never changes; its kind only
    while it has stored no frame (a camera registered as the wrong kind)."""

    kind: CameraKind | None = Field(
        default=None,
        description="Only while the camera has stored no frame (409 camera_has_frames after).",
    )


def _roi(roi: list[int] | list[list[int]] | None) -> list[int] | list[list[int]] | None:
    """A region: a rectangle [x, y, w, h] with x, y ≥ 0 and w, h ≥ 1, or a ``_polygon``."""
    if roi is None:
        return None
    if roi and isinstance(roi[0], list):
        return _polygon(roi)
    rect = [int(v) for v in roi if isinstance(v, int)]
    if len(rect) != 4 or len(roi) != 4:
        raise ValueError(f"roi must be [x, y, w, h] or [[x, y], ...]; got {len(roi)} numbers")
    x, y, w, h = rect
    if x < 0 or y < 0 or w < 1 or h < 1:
        raise ValueError("roi needs x, y ≥ 0 and w, h ≥ 1")
    return roi


def _polygon(points: list[list[int]]) -> list[list[int]]:
    """A region polygon: 3–64 vertices [x, y] ≥ 0, simple (no self-crossing), with area."""
    if not 3 <= len(points) <= 64:
        raise ValueError(f"a roi polygon needs 3 to 64 vertices; got {len(points)}")
    if any(len(p) != 2 for p in points):
        raise ValueError("every roi polygon vertex must be [x, y]")
    if any(x < 0 or y < 0 for x, y in points):
        raise ValueError("roi polygon vertices need x, y ≥ 0")
    shape = shapely.Polygon(points)
    if not shape.is_valid or shape.area < 1:
        raise ValueError(
            f"the roi polygon is not simple or has no area: {shapely.is_valid_reason(shape)}"
        )
    return points


class CameraOut(Out):
    id: str
    kind: CameraKind
    name: str | None
    lat: float | None
    lon: float | None
    panel_id: str | None
    roi: list[int] | list[list[int]] | None
    created_at: datetime
    retired_at: datetime | None = Field(
        None, description="When the camera was retired (DELETE); null while in service."
    )
    last_captured_at: datetime | None = Field(
        None, description="When its newest frame kept was taken; null when none is kept."
    )


class CameraCreated(CameraOut):
    token: str = Field(description="The camera's upload token. Shown once; store it now.")


class PanelCreate(Schema):
    id: Id
    name: Annotated[str, Field(max_length=200)] | None = None
    lat: Lat | None = None
    lon: Lon | None = None


class PanelUpdate(Schema):
    """The fields to change: a field left out keeps its value, ``null`` clears it. A panel's id
    never changes."""

    name: Annotated[str, Field(max_length=200)] | None = None
    lat: Lat | None = None
    lon: Lon | None = None


PanelStateName = Literal["no_baseline", "clean", "needs_cleaning", "cleaning", "unknown"]


class PanelOut(Out):
    id: str
    name: str | None
    lat: float | None
    lon: float | None
    created_at: datetime
    retired_at: datetime | None = Field(
        None, description="When the panel was retired (DELETE); null while in service."
    )
    state: PanelStateName = Field(
        description="Its state now, as ``GET /panels/{id}/status`` reads it (a retired panel's "
        "is history)."
    )


class PanelStateCounts(Out):
    counted_at: datetime
    total: int = Field(description="Panels in service.")
    states: dict[str, int] = Field(
        description="How many panels in service are in each state now (every state, zeros "
        "included): no_baseline, unknown, clean, needs_cleaning, cleaning."
    )


class RobotCreate(Schema):
    id: Id
    name: Annotated[str, Field(max_length=200)] | None = None


class RobotOut(Out):
    id: str
    name: str | None
    created_at: datetime
    retired_at: datetime | None = Field(
        None, description="When the robot was retired (DELETE); null while in service."
    )


class RobotCreated(RobotOut):
    token: str = Field(description="The robot's token. Shown once; store it now.")


class VerdictBase(Out):
    modes: list[int] = Field(description="Most frequent level per channel [R, G, B] (0–255).")
    means: list[float] = Field(description="Mean level per channel [R, G, B].")
    reason: str | None = Field(default=None, description="Why no conclusion was drawn.")
    roi: list[int] | list[list[int]] | None = Field(
        default=None,
        description="The camera's region of interest they were measured in (null: the whole "
        "frame).",
    )


class PanelVerdictOut(VerdictBase):
    kind: Literal["panel"] = "panel"
    panel_id: str | None
    clean: bool | None = Field(description="None with a reason: no baseline, or unusable frame.")
    t2: float | None = Field(description="Hotelling's t², eq. 5.19.")
    f_stat: float | None = Field(description="(n − 3)/(3(n − 1)) t² ~ F(3, n − 3), eq. 5.20.")
    p_value: float | None
    threshold: float | None = Field(
        description="F₍₃,ₙ₋₃,ς₎ (eq. 5.21); for the fleet model, the p_dirty cut-off."
    )
    state: str | None = Field(description="The panel's state after this verdict.")
    method: str | None = Field(default=None, description="baseline (T²) or fleet.")
    baseline_id: str | None = Field(
        default=None,
        description="The baseline that judged it: the panel's newest measured in the camera's "
        "region (a panel watched from several views has one per view).",
    )
    p_dirty: float | None = Field(default=None, description="Fleet model: p(needs cleaning).")
    late: bool = Field(
        default=False,
        description="Taken before the panel's latest judged frame, or before the cleaning "
        "awaiting confirmation was done (a late upload): judged, but it did not change the "
        "panel's state or its tasks.",
    )


class SkyVerdictOut(VerdictBase):
    kind: Literal["sky"] = "sky"
    level: int | None
    category: str | None
    message: str | None
    calibration_id: str | None = Field(
        default=None,
        description="The calibration that graded the frame (the camera's own or "
        "the city-wide one).",
    )


class RigVerdictOut(VerdictBase):
    kind: Literal["rig"] = "rig"


VerdictOut = Annotated[PanelVerdictOut | SkyVerdictOut | RigVerdictOut, Field(discriminator="kind")]


class FrameOut(Out):
    frame_id: str
    camera_id: str
    captured_at: datetime
    received_at: datetime
    width: int
    height: int
    sha256: str
    stored: bool
    verdict: VerdictOut


class Health(Out):
    status: Literal["ok", "degraded"]
    database: Literal["ok", "unreachable", "read_only", "full"]
    """``read_only``: the database answers but refuses writes (PostgreSQL: a standby, or set
    read-only; SQLite: its file or filesystem no longer written). ``full``: SQLite's disk has
    no room for a write."""
    frame_store: Literal["ok", "unreachable", "full"]
    """The frame store (a directory or an S3 bucket) answers and, for a directory, is writable
    and has more than the space kept free for the database (``full`` otherwise)."""
    version: str


class BaselineFromFrames(Schema):
    frame_ids: list[Annotated[str, Field(max_length=64)]] = Field(min_length=1, max_length=10_000)


class BaselineOut(Out):
    id: str
    panel_id: str
    created_at: datetime
    n: int = Field(description="Clean images used.")
    mean_modes: list[float] = Field(description="x̄ₘ, eq. 5.12 [level].")
    covariance: list[list[float]] = Field(description="Σ̂ with n − 1, eq. 5.13 [level²].")
    significance: float = Field(description="ς.")
    f_critical: float = Field(description="F₍₃,ₙ₋₃,ς₎, eq. 5.21.")
    condition_number: float
    shrinkage: float = Field(description="Variance added to Σ̂'s diagonal [level²].")
    frame_ids: list[str] | None
    roi: list[int] | list[list[int]] | None = Field(
        description="The region of interest its images were measured in (null: whole images); "
        "it judges only frames measured in the same region."
    )


class TaskOut(Out):
    task_id: str
    panel_id: str
    status: str = Field(description="pending, claimed, completed, closed, failed or cancelled.")
    robot_id: str | None
    created_at: datetime
    claimed_at: datetime | None
    lease_expires_at: datetime | None
    completed_at: datetime | None
    closed_at: datetime | None
    outcome: str | None = Field(
        description="effective, ineffective, not_needed, failed or panel_retired."
    )
    attempts: int
    fail_reason: str | None


class ClaimOut(Out):
    task_id: str
    panel_id: str
    lease_expires_at: datetime


class FailIn(Schema):
    reason: Annotated[str, Field(max_length=500)] | None = None


class TrendOut(Out):
    points: int = Field(description="Verdicts since the panel was last known clean.")
    slope_per_day: float | None = Field(description="Theil–Sen slope of F [1/day].")
    f_now: float | None = Field(description="Fitted F now.")
    threshold: float | None = Field(description="F₍₃,ₙ₋₃,ς₎.")
    crossing_at: datetime | None = Field(description="Forecast: fitted F reaches the threshold.")


class ViewOut(Out):
    camera_id: str
    baseline_id: str | None = Field(description="None: no baseline of its region yet.")
    trend: TrendOut


class PanelVerdictSummary(PanelVerdictOut):
    frame_id: str
    captured_at: datetime


class PanelStatus(Out):
    panel_id: str
    state: PanelStateName
    last_verdict: PanelVerdictSummary | None
    open_task: TaskOut | None
    ineffective: bool = Field(description="The last cleaning did not make the panel clean.")
    dirty_streak: int
    retired_at: datetime | None = Field(
        None, description="When the panel was retired; its state is then history."
    )
    baseline_id: str | None
    trend: TrendOut = Field(description="Of the panel's newest baseline's verdicts.")
    views: list[ViewOut] = Field(
        default_factory=list,
        description="Each camera in service: the baseline judging its frames (the panel's newest "
        "of its region) and their trend.",
    )


class Trigger(Out):
    panel_id: str
    clean_now: bool
    task_id: str | None


class TwoSampleOut(Out):
    t2: float
    f_stat: float
    df1: int
    df2: int
    p_value: float
    mean_difference: list[float] = Field(description="Dirty mean modes minus clean [level].")


class EvaluationOut(Out):
    n_clean: int
    n_dirty: int
    hotelling: TwoSampleOut
    dirty_called_clean: float = Field(description="Dirty images the clean baseline accepts.")
    clean_called_dirty: float = Field(
        description="Clean images refused by a baseline fitted without them (leave-one-out)."
    )
    clean_modes: list[list[float]]
    dirty_modes: list[list[float]]


class FleetModelOut(Out):
    id: str
    created_at: datetime
    feature_names: list[str]
    n_clean: int
    n_dirty: int
    cv_balanced_accuracy: float | None = Field(description="5-fold balanced accuracy.")
    threshold: float


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


class AirCalibrationFromFrames(Schema):
    frame_ids: list[Annotated[str, Field(max_length=64)]] = Field(min_length=1, max_length=10_000)
    levels: list[Annotated[int, Field(ge=1, le=10)]] = Field(min_length=1, max_length=10_000)


class AirClusterOut(Out):
    levels: list[int] = Field(description="Calibration levels pooled into this cluster.")
    level: int = Field(description="The level it reports.")
    n: int
    mean_modes: list[float] = Field(description="x̄ₘ, eq. 6.12 [level].")
    covariance: list[list[float]] = Field(description="Σ̂, eq. 6.13 [level²].")
    f_critical: float = Field(description="F₍₃,ₙ₋₃,ς₎, eq. 6.21.")
    significance: float


class AirCalibrationOut(Out):
    id: str
    created_at: datetime
    n_images: int
    clusters: list[AirClusterOut]
    warnings: list[str] = Field(description="Levels pooled for want of images, and the like.")
    method: str = Field(description="clusters (T², the dissertation) or regression.")
    city_wide: bool = Field(
        description="Made for no camera in particular: it grades every camera without one of "
        "its own."
    )
    camera_ids: list[str] = Field(description="The sky cameras it was made for and still grades.")


class AirLatest(Out):
    camera_id: str
    name: str | None = None
    lat: float | None = None
    lon: float | None = None
    level: int | None = Field(
        description="The camera's public level: its smoothed level (NowCast-style weighted "
        "average of the last 12 hours, as the map and the alerts use it) rounded, not the "
        "latest frame's alone (frame_level). Null without a graded reading in the 3 hours "
        "before the latest one."
    )
    category: str | None = Field(description="The category of the public level.")
    message: str | None = Field(
        description="Today's Air Quality is <category>: null when the latest reading is not "
        "current."
    )
    captured_at: datetime | None = Field(description="When the latest reading was taken.")
    smoothed_level: float | None = Field(
        description="The public level unrounded; null when the latest reading is not current."
    )
    smoothed_category: str | None
    frame_level: int | None = Field(
        description="The latest frame's own grade (null when it could not be graded: reason)."
    )
    frame_category: str | None
    reason: str | None
    current: bool = Field(
        description="The latest reading was taken in the last 3 hours. When not, the level and"
        " category are those of that reading's time (see captured_at), and message and the"
        " smoothed level are null: they would speak of today's air."
    )


class AirReading(Out):
    camera_id: str
    frame_id: str
    captured_at: datetime
    level: int | None
    category: str | None
    smoothed_level: float | None
    reason: str | None


class AirAggregate(Out):
    camera_id: str
    start: datetime
    end: datetime
    n: int
    mean_level: float
    min_level: float
    max_level: float
    category: str


class WebhookTestOut(Schema):
    webhook_id: str = Field(description="The test alert's webhook-id (and alert_id).")
    delivered: bool = Field(description="The receiver answered 2xx.")
    error: str | None = Field(description="Why it did not take the test alert.")
    signed: bool = Field(description="It carried webhook-signature (a secret is set).")


class AirAlertOut(Out):
    id: str
    camera_id: str
    frame_id: str
    created_at: datetime
    kind: Literal["raised", "cleared"] = Field(
        description="raised: the smoothed level entered ``category`` (Poor or Very Poor); "
        "cleared: after an alert, it is back in ``category``, clear of Poor (5.0 or better)."
    )
    smoothed_level: float
    category: str
    delivered: bool
    attempts: int
    delivery: Literal["delivered", "pending", "gave_up", "no_webhook"] = Field(
        description="delivered; pending (to be tried, or retried after a failure); gave_up"
        " (undelivered when its retry period ran out); no_webhook (none is configured)."
    )
    last_error: str | None = Field(
        description="Why the last attempt failed (with the admin token only; else null)."
    )
    next_attempt_at: datetime | None = Field(description="When a failed delivery is retried.")


Finite = Annotated[float, Field(allow_inf_nan=False)]


class CalibratedCamera(Schema):
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


class TriangulateIn(Schema):
    observations: list[list[list[Finite] | None]] = Field(
        description="Per point, per camera: [u, v] in pixels, or null when not seen.",
        max_length=200_000,
    )
    method: Literal["least_squares", "weighted", "mean"] = Field(
        default="least_squares",
        description="Cross rigs: all 8 coordinates (ML), inverse-variance weights, or the "
        "plain mean of the ten estimates (eq. 4.47).",
    )


class TriangulateOut(Out):
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
