"""Request and response bodies of the domain, on the platform's base models."""

from __future__ import annotations

import datetime as dt
from datetime import datetime
from typing import Annotated, Literal

from pydantic import Field, model_validator

from app.platform.schemas import Id, Lat, Lon, Out, PanelVerdictOut, Schema

Location = Annotated[
    str,
    Field(
        max_length=200,
        description="Where the panel is in words a robot or its crew can use.",
        examples=["row 3, string B, 7th from the east"],
    ),
]


Kwp = Annotated[
    float,
    Field(
        gt=0,
        le=1_000_000,
        description="Rated DC power at standard test conditions [kW] (a panel 0.4, a string "
        "of them more): pvlib models what it would make from insolation.",
    ),
]
Tilt = Annotated[float, Field(ge=0, le=90, description="Tilt from horizontal [°].")]
Azimuth = Annotated[
    float, Field(ge=0, lt=360, description="The direction it faces [° east of north]: 180 south.")
]


class PanelCreate(Schema):
    id: Id
    name: Annotated[str, Field(max_length=200)] | None = None
    lat: Lat | None = None
    lon: Lon | None = None
    location: Location | None = None
    kwp: Kwp | None = None
    tilt: Tilt | None = None
    azimuth: Azimuth | None = None


class PanelUpdate(Schema):
    """The fields to change: a field left out keeps its value, ``null`` clears it. A panel's id
    never changes."""

    name: Annotated[str, Field(max_length=200)] | None = None
    lat: Lat | None = None
    lon: Lon | None = None
    location: Location | None = None
    kwp: Kwp | None = None
    tilt: Tilt | None = None
    azimuth: Azimuth | None = None


PanelStateName = Literal["no_baseline", "clean", "needs_cleaning", "cleaning", "unknown"]


class PanelOut(Out):
    id: str
    name: str | None
    lat: float | None
    lon: float | None
    location: str | None = None
    kwp: float | None = None
    tilt: float | None = None
    azimuth: float | None = None
    created_at: datetime
    retired_at: datetime | None = Field(
        None, description="When the panel was retired (DELETE); null while in service."
    )
    state: PanelStateName = Field(
        description="Its state now, as ``GET /panels/{id}/status`` reads it (a retired panel's "
        "is history)."
    )
    last_clean: bool | None = Field(
        None, description="The latest usable verdict said clean (false: dirty); null before one."
    )
    dirty_streak: int = Field(
        0, description="Usable verdicts in a row that said dirty, toward the cleaning trigger."
    )
    streak_needed: int = Field(
        3, description="How many in a row open a cleaning task (the farm's debounce)."
    )
    doubted: bool = Field(
        False,
        description="The latest frame of the panel was one the fleet model would not judge "
        "(GET /fleet/doubts lists it, to be labelled).",
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


class BaselineFromFrames(Schema):
    frame_ids: list[Annotated[str, Field(max_length=64)]] = Field(min_length=1, max_length=10_000)


class BaselineWarning(Out):
    code: Literal["baseline_stale", "baseline_too_broad"]
    baseline_id: str
    detail: str


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
    full_resolution: bool = Field(
        description="Trained on modes of full-size images. False: a baseline from before modes "
        "were taken at full size, stale, judging nothing until retrained."
    )
    detectable_veil: float | None = Field(
        default=None,
        description="The smallest dust veil (strength s: each pixel blended s of the way to "
        "brown-grey dust) its F test detects with probability 0.9, estimated at training.",
    )
    warnings: list[BaselineWarning] = Field(
        default_factory=list,
        description="Why it judges nothing, if so: baseline_stale, or baseline_too_broad (its "
        "photos vary far more than one panel's, or it would notice only a veil over 0.3); the "
        "fleet model judges the panel instead, when there is one.",
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
    evidence: str | None = Field(
        None,
        description="What opened it: the cameras' dirty verdicts, and the output's word when "
        "the farm's trigger weighs it (PUT /solar/economics).",
    )


class PanelPlace(Out):
    """Where a task's panel is, for the robot that holds it."""

    id: str
    name: str | None
    lat: float | None
    lon: float | None
    location: str | None


class ClaimOut(Out):
    task_id: str
    panel_id: str
    lease_expires_at: datetime
    panel: PanelPlace | None = Field(
        None, description="The panel's name and place (lat, lon and the operator's words)."
    )


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
    streak_needed: int = Field(
        3, description="Dirty verdicts in a row that open a cleaning task (the debounce)."
    )
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
    warnings: list[BaselineWarning] = Field(
        default_factory=list,
        description="The panel's baselines that judge nothing, and why (the fleet model judges "
        "instead, when there is one): stale (trained on modes of reduced images), or too broad.",
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
    n_dirty: int = Field(description="Photos needing cleaning: dust and bird_drop.")
    n_bird_drop: int = 0
    n_snow: int = 0
    cv_balanced_accuracy: float | None = Field(
        description="Needs cleaning against clean: balanced accuracy over 5 folds, every choice "
        "of the training (C and γ, Platt's sigmoid, the not-sure band) made again inside each "
        "(nested); on panels it never saw when trained with groups."
    )
    cv_low: float | None = Field(
        default=None,
        description="The 95 % interval of cv_balanced_accuracy over its 5 folds (Student's t), "
        "low end: what panels it never saw may get. Null for models trained before.",
    )
    cv_high: float | None = Field(default=None, description="Its high end.")
    cv_sure_balanced_accuracy: float | None = Field(
        default=None,
        description="Balanced accuracy of the answers it is sure of (outside its not-sure "
        "band), nested as cv_balanced_accuracy. Null for models trained before.",
    )
    cv_answered: float | None = Field(
        default=None,
        description="The share of held-out photos it is sure of, nested. Null for models "
        "trained before.",
    )
    band: float | None = Field(
        default=None,
        description="A frame whose p(needs cleaning) lies within this of threshold is not sure "
        "(no verdict, the reason given); chosen on its training photos. Null for models "
        "trained before (0.2).",
    )
    snow_floor: float | None = Field(
        default=None,
        description="A frame it would send to brushing is not sure from this p(snow) up: the "
        "lowest p(snow) a snow photo held out of its training had. Null without snow photos.",
    )
    n_farm: int = Field(default=0, description="Photos that were the farm's labelled frames.")
    cv_without_farm: float | None = Field(
        default=None,
        description="cv_balanced_accuracy had the farm's labelled frames not been learnt from, "
        "on the same held-out photos: what the farm's labels did. Null without them.",
    )
    n_groups: int | None = Field(
        default=None,
        description="Groups (panels) the folds kept together; null when trained without "
        "groups, each photo then its own panel.",
    )
    threshold: float


class HistoryBucket(Out):
    start: datetime
    end: datetime
    frames: int
    clean: int = Field(description="Judged clean.")
    dirty: int = Field(description="Judged in need of cleaning.")
    not_judged: int = Field(description="No verdict: night, glare, snow, no model.")
    t2_mean: float | None = Field(description="Mean T² of those judged by the baseline (eq. 5.19).")
    t2_max: float | None
    p_value_min: float | None = Field(description="Smallest p-value (eq. 5.20's F).")
    p_dirty_mean: float | None = Field(description="Mean p_dirty of those judged by the fleet.")
    kwh: float | None = Field(None, description="Day buckets: the day's measured energy [kWh].")
    expected_kwh: float | None = Field(None, description="What the clean panel would have made.")
    performance_index: float | None = Field(
        None, description="kwh / expected_kwh, null on a day left out (outage, low light)."
    )
    soiling_ratio: float | None = Field(
        None, description="The fitted soiling ratio of the day (1: as clean as after cleaning)."
    )
    soiling_low: float | None = Field(None, description="95 % interval of the ratio.")
    soiling_high: float | None = None
    cleaned: bool = Field(
        False,
        description="A soiling interval began on the day: a cleaning (robot, rain, or "
        "a recovery of the output).",
    )


FleetLabel = Literal["clean", "dust", "bird_drop", "snow"]


class DoubtOut(Out):
    """A frame the fleet model would not judge: neither clean nor dirty with confidence, or
    unlike every photo it learnt from."""

    frame_id: str
    camera_id: str
    panel_id: str | None
    captured_at: datetime
    p_dirty: float | None = Field(
        description="The model's probability of dirty, for what it is worth."
    )
    reason: str | None = Field(description="Why the model doubted it.")
    label: FleetLabel | None = Field(description="The farm's label, once given.")
    image: str = Field(description="The frame's region, to look at (GET, admin or viewer).")


class LabelIn(Schema):
    label: FleetLabel


class LabelOut(Out):
    frame_id: str
    label: str
    source: str = Field(description="operator or robot.")
    labelled_at: datetime


class LabelCounts(Out):
    counts: dict[str, int] = Field(description="Frames the farm labelled, by label.")
    total: int


Energy = Annotated[float, Field(ge=0, le=1e9)]
Insolation = Annotated[float, Field(ge=0, le=15)]


class EnergyDayIn(Schema):
    """A panel's (or a string's) output on one day."""

    date: dt.date = Field(description="The day (YYYY-MM-DD), in the farm's local time.")
    kwh: Energy = Field(description="Measured energy [kWh].")
    expected_kwh: Energy | None = Field(
        None,
        description="What the clean panel would have made [kWh] (the inverter's or SCADA's "
        "model). Left out, pvlib models it from poa_kwh_m2 (the panel needs kwp) or "
        "ghi_kwh_m2 (kwp, tilt, azimuth, lat and lon).",
    )
    poa_kwh_m2: Insolation | None = Field(None, description="Plane-of-array insolation [kWh/m²].")
    ghi_kwh_m2: Insolation | None = Field(
        None, description="Global horizontal insolation [kWh/m²]."
    )
    rain_mm: Annotated[float, Field(ge=0, le=2000)] | None = Field(
        None, description="Rain [mm]: a recovery on a rainy day is put down to rain."
    )

    @model_validator(mode="after")
    def _expected_can_hold_it(self) -> EnergyDayIn:
        if self.expected_kwh == 0 and self.kwh > 0:
            raise ValueError(
                "expected_kwh: 0 expected cannot hold a measured kwh above 0 (its ratio is "
                "infinite); leave expected_kwh out to have it modelled"
            )
        return self


class EnergyDayOut(Out):
    day: dt.date
    kwh: float
    expected_kwh: float
    expected_from: Literal["given", "poa", "ghi"] = Field(
        description="given, or modelled by pvlib from plane-of-array (poa) or global "
        "horizontal (ghi) insolation."
    )
    poa_kwh_m2: float | None
    ghi_kwh_m2: float | None
    rain_mm: float | None


class EnergyStored(Out):
    panel_id: str
    stored: int = Field(description="Days stored (a day sent again replaced the old one).")
    modelled: int = Field(description="Of those, days whose expected energy pvlib modelled.")
    first: dt.date | None
    last: dt.date | None


class SoilingIntervalOut(Out):
    start: dt.date
    end: dt.date
    cause: Literal["start", "robot", "rain", "detected"] = Field(
        description="What began it: the first day of output, a robot's completed cleaning, a "
        "recovery of the output on a rainy day, or one with no known cause."
    )
    days: int = Field(description="Days of output its line was fitted to.")
    rate_per_day: float | None = Field(
        description="Soiling rate [1/day] (−0.003: 0.3 % of the output lost a day); null "
        "with fewer than 7 days."
    )
    rate_low: float | None = Field(description="95 % interval of the rate (Sen's).")
    rate_high: float | None


class RecommendationOut(Out):
    clean: bool = Field(description="Cleaning pays now.")
    by: dt.date | None = Field(
        description="The day cleaning starts to pay (today's when it does now); null when the "
        "output shows no soiling to pay for."
    )
    reason: str
    optimal_interval_days: float | None = Field(
        description="τ* = √(2C / (ρ E P)): the cleaning interval of least cost per day for "
        "the rate of soiling measured."
    )
    lost_value: float | None = Field(description="Value of the energy lost since the cleaning.")
    cleaning_cost: float | None = Field(description="A cleaning of this panel.")
    currency: str | None = None


class SoilingOut(Out):
    panel_id: str
    as_of: dt.date | None = Field(description="The last day of output analysed.")
    soiling_ratio: float | None = Field(
        description="Output over what the panel made just after its last cleaning (1: clean), "
        "on the last day; null without enough output (``reason`` says why)."
    )
    low: float | None = Field(description="95 % interval of the ratio.")
    high: float | None
    rate_per_day: float | None = Field(description="The current interval's soiling rate [1/day].")
    loss_kwh_per_day: float | None = Field(
        description="Energy lost a day at the current ratio, on a day like the last fortnight's."
    )
    loss_since_cleaning_kwh: float | None
    since_cleaning_days: int | None = Field(
        description="Days from the current interval's start (the last cleaning) to ``as_of``."
    )
    last_cleaning: dt.date | None = Field(
        description="The current interval's first day, when a cleaning (robot, rain or seen "
        "in the output) began it."
    )
    days: int = Field(description="Days of output stored for the panel.")
    intervals: list[SoilingIntervalOut]
    recommendation: RecommendationOut | None = Field(
        description="Whether cleaning pays; null without a soiling ratio."
    )
    reason: str | None = None


class EconomicsIn(Schema):
    energy_price_per_kwh: float = Field(gt=0, le=1000, description="What a kWh is worth.")
    cleaning_cost: float = Field(ge=0, le=1e7, description="What a cleaning costs.")
    cost_per: Literal["panel", "visit"] = Field(
        "panel",
        description="panel: each panel's cleaning costs ``cleaning_cost``; visit: a robot's "
        "visit does, shared by ``panels_per_visit`` panels.",
    )
    panels_per_visit: int = Field(1, ge=1, le=100_000)
    currency: Annotated[str, Field(pattern=r"^[A-Z]{3}$")] | None = Field(
        None, description="ISO 4217 code, for the pages."
    )
    trigger: Literal["camera", "camera_and_pays"] = Field(
        "camera",
        description="camera: the cameras' dirty verdicts open a cleaning task; "
        "camera_and_pays: they do when the panel has no output in the last 7 days, or when "
        "its output says cleaning pays.",
    )


class EconomicsOut(EconomicsIn):
    per_panel_cost: float = Field(description="What one panel's cleaning costs.")
    updated_at: datetime
