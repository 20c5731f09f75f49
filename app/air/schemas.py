"""Request and response bodies of the domain, on the platform's base models."""

from __future__ import annotations

from datetime import datetime
from typing import Annotated, Literal

from pydantic import Field, model_validator

from app.platform.http.deps import UtcTime
from app.platform.schemas import Id, Lat, Lon, Out, Schema, SkyEstimate


class AirCalibrationFromFrames(Schema):
    frame_ids: list[Annotated[str, Field(max_length=64)]] = Field(min_length=1, max_length=10_000)
    levels: list[Annotated[int, Field(ge=1, le=10)]] | None = Field(
        default=None, min_length=1, max_length=10_000
    )
    pm25: list[Annotated[float, Field(ge=0, allow_inf_nan=False)]] | None = Field(
        default=None,
        min_length=1,
        max_length=10_000,
        description="Instead of levels: the reference PM2.5 of each frame [µg/m³], mapped to "
        "levels by the US EPA AQI breakpoints (2024) or, with breakpoints=eu_eaqi, the European "
        "Air Quality Index's bands.",
    )
    aqi: list[Annotated[float, Field(ge=0, le=1000, allow_inf_nan=False)]] | None = Field(
        default=None,
        min_length=1,
        max_length=10_000,
        description="Instead of levels: the reference US AQI of each frame.",
    )

    @model_validator(mode="after")
    def _one_reference(self) -> AirCalibrationFromFrames:
        given = [k for k in ("levels", "pm25", "aqi") if getattr(self, k) is not None]
        if len(given) != 1:
            raise ValueError(
                "give one of levels, pm25 or aqi per frame"
                + (f" (given: {', '.join(given)})" if given else "")
            )
        return self


class AirClusterOut(Out):
    levels: list[int] = Field(description="Calibration levels pooled into this cluster.")
    level: int = Field(description="The level it reports.")
    n: int
    mean_modes: list[float] = Field(description="x̄ₘ, eq. 6.12 [level].")
    covariance: list[list[float]] = Field(description="Σ̂, eq. 6.13 [level²].")
    f_critical: float = Field(description="F₍₃,ₙ₋₃,ς₎, eq. 6.21.")
    significance: float


class AirRegressionOut(Out):
    unit: str = Field(
        default="level", description="What it is fitted in: pm25 [µg/m³], aqi or level."
    )
    breakpoints: str = Field(
        default="us_epa",
        description="The table its PM2.5 estimates become levels by: us_epa or eu_eaqi.",
    )
    n: int = Field(default=0, description="Images it was fitted to.")
    alpha: float | None = Field(
        default=None, description="Ridge penalty, chosen as σ is measured: days or images left out."
    )
    sigma: float | None = Field(
        default=None,
        description="Residual scale on data it was not fitted to, in ln(1 + unit) (level: "
        "levels); its prediction intervals' width.",
    )
    sigma_from: str | None = Field(
        default=None, description="days left out (stored frames of ≥ 3 days) or images left out."
    )
    groups: int | None = Field(
        default=None,
        description="The days (by the sun at each frame's camera) or upload groups left out "
        "one at a time to choose α and measure σ; null when images were left out.",
    )
    interval: float | None = Field(default=None, description="Coverage of its intervals.")
    dof: float | None = Field(
        default=None,
        description="Degrees of freedom of its predictive t (n − tr(H)): with sigma, the "
        "probabilities of its verdicts' categories.",
    )
    day_share: float | None = Field(
        default=None,
        description="The share of its held-out errors' variance that a day's frames have in "
        "common (1: all of it, as assumed when images were left out): how much a camera's "
        "smoothed range narrows as its frames accrue.",
    )
    features: list[str] = Field(
        default_factory=list,
        description="The sky features it was fitted on, in order: a calibration made before "
        "features were added grades by these.",
    )


class AirSelectionOut(Out):
    chosen: str = Field(description="The method that grades: regression or clusters.")
    scores: dict[str, float | None] = Field(
        description="Each method's score (lower is better; null: it could not be fitted)."
    )
    score: str = Field(
        description="What the score is: the mean absolute category error on days (or, without "
        "days, images) left out; a frame a method cannot grade counts as 2."
    )
    folds: int = Field(description="Groups of days left out in turn.")


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
    regression: AirRegressionOut | None = Field(
        default=None, description="The regression (method regression), else null."
    )
    selection: AirSelectionOut | None = Field(
        default=None,
        description="How the method was chosen when none was asked for (reference values): "
        "both scored on days left out, the better kept. Null when method was given, or for "
        "levels (the clusters, the dissertation's method).",
    )


class AirLatest(Out):
    camera_id: str
    name: str | None = None
    lat: float | None = None
    lon: float | None = None
    level: int | None = Field(
        description="The camera's public level: its smoothed reading (NowCast-style over the "
        "last 12 hours, as the map and the alerts use it), not the latest frame's alone "
        "(frame_level). Graded by a regression, the level of the most probable category's "
        "estimate. Null without a graded reading in the 3 hours before the latest one."
    )
    category: str | None = Field(
        description="The public category: the most probable under the camera's smoothed "
        "predictive distribution (a regression), else that of the smoothed level."
    )
    message: str | None = Field(
        description="What the public screen says, in public words: \"Today's Air Quality is "
        'Fair", "… is likely Fair" when the category\'s probability is below 0.8, "Air '
        'quality not measured here yet", or that there is no recent reading.'
    )
    captured_at: datetime | None = Field(description="When the latest reading was taken.")
    smoothed_level: float | None = Field(
        description="The public level unrounded; null when the latest reading is not current."
    )
    smoothed_category: str | None
    probability: float | None = Field(
        default=None,
        description="The probability of the public category (a regression's readings); null "
        "when not current or graded by the clusters.",
    )
    poor_probability: float | None = Field(
        default=None,
        description="The smoothed probability that the air is Poor or worse (what alerts follow).",
    )
    smoothed_estimate: SkyEstimate | None = Field(
        default=None,
        description="The camera's smoothed estimate (PM2.5 or AQI, the calibration's unit) "
        'and its 80 % range: the screen\'s "PM2.5 about 22 µg/m³, 15–31".',
    )
    frame_level: int | None = Field(
        description="The latest frame's own grade (null when it could not be graded, or lies "
        "outside the calibration: reason)."
    )
    frame_category: str | None = Field(
        description="The latest frame's own most probable category; null when ungraded."
    )
    uncertain: bool = Field(
        default=False,
        description="The public category's probability is below 0.8 (the message says "
        '"likely"); without one, the latest frame was doubted (reason).',
    )
    span: list[str] | None = Field(
        default=None,
        description="[clearest, worst]: the categories the latest frame's interval spans when "
        "they differ and it is current.",
    )
    estimate: SkyEstimate | None = Field(
        default=None, description="The latest frame's regression estimate, if any."
    )
    reason: str | None
    current: bool = Field(
        description="The latest reading was taken in the last 3 hours (before at, when given). "
        "When not, the level and category are those of that reading's time (see captured_at), "
        "and the smoothed figures are null: they would speak of the air now."
    )


class AirReading(Out):
    camera_id: str
    frame_id: str
    captured_at: datetime
    level: int | None
    category: str | None
    smoothed_level: float | None
    reason: str | None
    uncertain: bool = Field(
        default=False,
        description="The regression doubted this frame (reason): its category's probability "
        "is below 0.8 (it counts, with that probability), or it lies outside the calibration "
        "(no level: it counts nowhere).",
    )
    estimate: float | None = Field(
        default=None, description="The regression's estimate, in estimate_unit."
    )
    estimate_low: float | None = Field(default=None, description="Its 80 % interval's low end.")
    estimate_high: float | None = Field(default=None, description="Its high end.")
    estimate_unit: str | None = Field(default=None, description="pm25 [µg/m³], aqi or level.")
    calibration_id: str | None = Field(
        default=None, description="The calibration that graded it (re-grading changes it)."
    )
    probability: float | None = Field(
        default=None, description="The probability of its category (a regression's)."
    )
    smoothed_estimate: float | None = Field(
        default=None, description="The camera's smoothed estimate after it, in estimate_unit."
    )
    smoothed_low: float | None = Field(default=None, description="Its 80 % range's low end.")
    smoothed_high: float | None = Field(default=None, description="Its high end.")
    smoothed_probability: float | None = Field(
        default=None, description="The probability of the smoothed level's category."
    )
    poor_probability: float | None = Field(
        default=None, description="The smoothed probability of Poor or worse."
    )


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
        description="raised: the camera's smoothed probability of Poor or worse reached 0.45 "
        "(a regression grades it), or its smoothed level entered ``category`` (Poor or Very "
        "Poor; the clusters); cleared: after an alert, that probability fell to 0.225, or the "
        "level is back in ``category``, clear of Poor (5.0 or better)."
    )
    smoothed_level: float
    category: str
    probability: float | None = Field(
        default=None,
        description="The smoothed probability of Poor or worse that raised or cleared it "
        "(null when the clusters' levels did).",
    )
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


class AirRegradeOut(Schema):
    camera_id: str
    calibration_id: str | None = Field(
        description="The calibration that graded them (null: none grades the camera)."
    )
    since: datetime
    regraded: int = Field(description="Frames measured again and graded by it.")
    missing: int = Field(
        description="Frames whose bytes are no longer stored (retention): they keep their "
        "grade and its calibration_id."
    )
    next_since: datetime | None = Field(
        description="More frames remain: call again with this since (the last one re-graded "
        "is graded again, harmlessly). Null when done."
    )


class StationCreate(Schema):
    id: Id
    name: Annotated[str, Field(max_length=200)] | None = None
    lat: Lat
    lon: Lon


class StationUpdate(Schema):
    name: Annotated[str, Field(max_length=200)] | None = None
    lat: Lat | None = None
    lon: Lon | None = None


class StationReadingIn(Schema):
    at: UtcTime = Field(description="When it was measured (RFC 3339; without an offset, UTC).")
    pm25: float = Field(ge=0, allow_inf_nan=False, description="PM2.5 [µg/m³].")


class StationReadingOut(Out):
    at: datetime
    pm25: float


class StationOut(Out):
    id: str
    name: str | None
    lat: float
    lon: float
    latest: StationReadingOut | None = Field(
        default=None, description="Its newest reading; null before any."
    )


class ReadingsStored(Schema):
    station_id: str
    stored: int = Field(description="Distinct times stored (a time given twice counts once).")


class RollingOut(Schema):
    recalibrated: list[str] = Field(description="Cameras calibrated again from their stations.")
    drifting: list[str] = Field(
        description="Cameras flagged recalibrate: their readings had drifted from the station's."
    )
    skipped: dict[str, str] = Field(description="Cameras not recalibrated, and why.")
