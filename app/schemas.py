"""Request and response bodies, on one project base model."""

from __future__ import annotations

from datetime import datetime
from typing import Annotated, Literal

from pydantic import BaseModel, ConfigDict, Field, field_validator

from app.db.models import CameraKind

Id = Annotated[str, Field(pattern=r"^[A-Za-z0-9._-]{1,64}$", examples=["roof-3"])]
Lat = Annotated[float, Field(ge=-90, le=90, description="Latitude [°], WGS 84.")]
Lon = Annotated[float, Field(ge=-180, le=180, description="Longitude [°], WGS 84.")]


class Schema(BaseModel):
    """Project base: no NaN or infinity anywhere, unknown fields refused."""

    model_config = ConfigDict(allow_inf_nan=False, extra="forbid", from_attributes=True)


class Out(Schema):
    model_config = ConfigDict(extra="ignore")


class CameraCreate(Schema):
    id: Id
    kind: CameraKind
    name: Annotated[str, Field(max_length=200)] | None = None
    lat: Lat | None = None
    lon: Lon | None = None
    panel_id: Id | None = Field(default=None, description="The panel this camera watches.")
    roi: list[int] | None = Field(
        default=None,
        description="Region of interest [x, y, w, h] in pixels of the full frame.",
        examples=[[0, 60, 640, 300]],
    )

    @field_validator("roi")
    @classmethod
    def _roi_shape(cls, roi: list[int] | None) -> list[int] | None:
        if roi is None:
            return None
        if len(roi) != 4:
            raise ValueError(f"roi must be [x, y, w, h]; got {len(roi)} numbers")
        x, y, w, h = roi
        if x < 0 or y < 0 or w < 1 or h < 1:
            raise ValueError("roi needs x, y ≥ 0 and w, h ≥ 1")
        return roi


class CameraOut(Out):
    id: str
    kind: CameraKind
    name: str | None
    lat: float | None
    lon: float | None
    panel_id: str | None
    roi: list[int] | None
    created_at: datetime


class CameraCreated(CameraOut):
    token: str = Field(description="The camera's upload token. Shown once; store it now.")


class PanelCreate(Schema):
    id: Id
    name: Annotated[str, Field(max_length=200)] | None = None
    lat: Lat | None = None
    lon: Lon | None = None


class PanelOut(Out):
    id: str
    name: str | None
    lat: float | None
    lon: float | None
    created_at: datetime


class RobotCreate(Schema):
    id: Id
    name: Annotated[str, Field(max_length=200)] | None = None


class RobotOut(Out):
    id: str
    name: str | None
    created_at: datetime


class RobotCreated(RobotOut):
    token: str = Field(description="The robot's token. Shown once; store it now.")


class VerdictBase(Out):
    modes: list[int] = Field(description="Most frequent level per channel [R, G, B] (0–255).")
    means: list[float] = Field(description="Mean level per channel [R, G, B].")
    reason: str | None = Field(default=None, description="Why no conclusion was drawn.")


class PanelVerdictOut(VerdictBase):
    kind: Literal["panel"] = "panel"
    panel_id: str | None
    clean: bool | None
    t2: float | None
    f_stat: float | None
    p_value: float | None
    threshold: float | None
    state: str | None


class SkyVerdictOut(VerdictBase):
    kind: Literal["sky"] = "sky"
    level: int | None
    category: str | None
    message: str | None


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
    database: Literal["ok", "unreachable"]
    version: str
