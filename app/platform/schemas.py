"""Request and response bodies, on one project base model."""

from __future__ import annotations

from datetime import datetime
from typing import Annotated, Literal

import shapely
from pydantic import AfterValidator, BaseModel, ConfigDict, Field, field_validator, model_validator

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


SOURCE_SCHEMES = ("rtsp", "http", "https")


class SourceIn(Schema):
    """Where the service pulls the camera's frames from, every ``every_seconds``."""

    url: Annotated[str, Field(max_length=2048)] = Field(
        description="rtsp://… (H.264, MPEG-4), or http(s)://… serving an MJPEG stream or one "
        "JPEG snapshot per request. Credentials in it (user:password@) are taken out and kept "
        "as username and password.",
        examples=["rtsp://10.0.0.7:554/stream1", "http://10.0.0.8/snapshot.jpg"],
    )
    every_seconds: int = Field(ge=1, le=86_400, description="A frame every so many seconds.")
    username: Annotated[str, Field(max_length=200)] | None = None
    password: Annotated[str, Field(max_length=200)] | None = Field(
        default=None, description="Write-only: never returned, never logged."
    )

    @model_validator(mode="after")
    def _checked(self) -> SourceIn:
        from urllib.parse import unquote, urlsplit, urlunsplit

        if any(c.isspace() or ord(c) < 32 or ord(c) == 127 for c in self.url):
            raise ValueError("the source url must have no spaces or control characters")
        parts = urlsplit(self.url)
        if parts.scheme.lower() not in SOURCE_SCHEMES:
            raise ValueError(
                f"the source url's scheme must be rtsp, http or https; got {parts.scheme!r}"
            )
        try:
            host, port = parts.hostname, parts.port
        except ValueError:
            raise ValueError("the source url has a bad port") from None
        if not host:
            raise ValueError("the source url names no host")
        if parts.username is not None:  # kept apart from the url, write-only
            self.username = self.username or unquote(parts.username)
            self.password = self.password or unquote(parts.password or "") or None
            netloc = host if ":" not in host else f"[{host}]"
            netloc += f":{port}" if port is not None else ""
            self.url = urlunsplit(parts._replace(netloc=netloc))
        return self


class SourceOut(Out):
    url: str
    every_seconds: int
    username: str | None
    has_password: bool = Field(description="A password is set (it is never returned).")
    state: Literal["connecting", "ok", "unreachable", "bad_stream"] = Field(
        description="connecting: no frame taken yet; ok: the last pull gave a frame; "
        "unreachable: no answer, refused, timed out or an HTTP error; bad_stream: an answer "
        "that is not a JPEG, MJPEG or decodable video. A failing source is retried after "
        "a back-off (doubling, at most 5 minutes)."
    )
    last_error: str | None
    last_error_at: datetime | None
    last_frame_at: datetime | None = Field(description="When the last frame was taken.")
    last_frame_id: str | None
    next_due_at: datetime = Field(description="When the next frame is due.")


class CameraFields(Schema):
    """What an operator may say about a camera, at registration and later."""

    name: Annotated[str, Field(max_length=200)] | None = None
    lat: Lat | None = None
    lon: Lon | None = None
    panel_id: Id | None = Field(default=None, description="The panel this camera watches.")
    roi: RoiField = None
    source: SourceIn | None = Field(
        default=None,
        description="Pull frames from this stream or snapshot URL instead of waiting for the "
        "camera to post them (null: no source; it may post them still).",
    )

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


MAX_ROI_COORDINATE = 1_000_000
"""No image the service decodes is wider or taller than this [px] (the pixel limit is far
lower): a region past it can only be a mistake, and its area would overflow fixed-width ints."""


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
    if max(x + w, y + h) > MAX_ROI_COORDINATE:
        raise ValueError(f"roi must lie within {MAX_ROI_COORDINATE} pixels of the origin")
    return roi


def _polygon(points: list[list[int]]) -> list[list[int]]:
    """A region polygon: 3–64 vertices [x, y] ≥ 0, simple (no self-crossing), with area."""
    if not 3 <= len(points) <= 64:
        raise ValueError(f"a roi polygon needs 3 to 64 vertices; got {len(points)}")
    if any(len(p) != 2 for p in points):
        raise ValueError("every roi polygon vertex must be [x, y]")
    if any(x < 0 or y < 0 for x, y in points):
        raise ValueError("roi polygon vertices need x, y ≥ 0")
    if any(max(x, y) > MAX_ROI_COORDINATE for x, y in points):
        raise ValueError(f"roi polygon vertices must lie within {MAX_ROI_COORDINATE} pixels")
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
    source: SourceOut | None = Field(
        None, description="Where its frames are pulled from, and how that goes."
    )
    source_state: Literal["connecting", "ok", "unreachable", "bad_stream"] | None = Field(
        None, description="source.state, or null for a camera that only posts its frames."
    )
    attention: list[str] = Field(
        default_factory=list,
        description='What the camera\'s operator should do, and why: "recalibrate: …" when a '
        "sky camera's readings no longer agree with the reference station near it (moved, "
        "zoomed, a new white balance). Empty: nothing.",
    )

    @field_validator("attention", mode="before")
    @classmethod
    def _none_is_nothing(cls, value: object) -> object:
        return [] if value is None else value


class CameraCreated(CameraOut):
    token: str = Field(description="The camera's upload token. Shown once; store it now.")


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
    condition: str | None = Field(
        default=None,
        description="Fleet model: what it saw, clean, dust, bird_drop or snow (a snow-covered "
        "panel gets clean: null and opens no brushing task); dirty from older models.",
    )
    late: bool = Field(
        default=False,
        description="Taken before the panel's latest judged frame, or before the cleaning "
        "awaiting confirmation was done (a late upload): judged, but it did not change the "
        "panel's state or its tasks.",
    )
    cleaning: str | None = Field(
        default=None,
        description="What this verdict did to the cleaning: opened a task, and on what "
        "evidence (the cameras' verdicts, the output's word when the farm weighs it), or found "
        "the panel dirty while its output says cleaning does not pay yet.",
    )


class SkyEstimate(Out):
    """A regression's estimate of one frame's air, in the unit it was calibrated in."""

    unit: Literal["pm25", "aqi", "level"] = Field(
        description="pm25: PM2.5 [µg/m³]; aqi: US AQI; level: the 1–10 scale itself."
    )
    value: float
    low: float | None = Field(description="Lower end of the 80 % prediction interval.")
    high: float | None = Field(description="Upper end of the 80 % prediction interval.")


class SkyVerdictOut(VerdictBase):
    kind: Literal["sky"] = "sky"
    level: int | None = Field(
        description="The frame's level 1–10; null when it could not be graded (reason) or lies "
        "outside what the regression was calibrated on."
    )
    category: str | None = Field(
        description="The level's category: a regression's most probable one (see probability);"
        " null when ungraded or outside the calibration."
    )
    message: str | None = Field(
        description='"Today\'s Air Quality is <category>", "… is likely <category>" when its '
        "probability is below 0.8; that the camera is not sure when the frame lies outside "
        "its calibration."
    )
    calibration_id: str | None = Field(
        default=None,
        description="The calibration that graded the frame (the camera's own or "
        "the city-wide one).",
    )
    uncertain: bool = Field(
        default=False,
        description="The regression doubts this frame (reason says why): its category's "
        "probability is below 0.8 (it counts, with that probability, in the camera's public "
        "reading, history and map), or it lies outside what it was calibrated on (no level: "
        "it counts nowhere).",
    )
    probability: float | None = Field(
        default=None,
        description="The probability of category under the regression's predictive "
        "distribution (null for the T² clusters).",
    )
    span: list[str] | None = Field(
        default=None,
        description="[clearest, worst]: the categories the frame's 80 % interval spans when "
        "they differ; null otherwise.",
    )
    estimate: SkyEstimate | None = Field(
        default=None, description="The regression's estimate (null for the T² clusters)."
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
