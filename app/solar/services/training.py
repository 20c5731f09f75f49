"""Training from labelled images: a panel's baseline, the fleet model, the T² evaluation."""

from __future__ import annotations

import math
import uuid
from collections.abc import Sequence
from dataclasses import dataclass
from datetime import datetime
from typing import Any

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
from app.solar.core.fleet import ALL_FEATURES
from app.solar.models import Baseline, FleetModel, PanelVerdict
from app.solar.services import events, labels
from app.solar.services.panels import baseline_unfit, lock_panel
from app.stats import hotelling

MIN_FLEET_PER_CLASS = 5


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


NOVELTY = 0.05
"""How often a photo like the training photos may be called unlike them (``reach``)."""


def reach(
    z: NDArray[np.float64], alpha: float = NOVELTY, groups: NDArray[np.str_] | None = None
) -> float:
    """How far a frame may lie from its nearest training photo (rows of ``z``, (n, K), standard
    units) and still be among them (``KernelModel.doubt``): a conformal novelty threshold.

    Each photo's distance to its nearest other photo is what a new photo like them would show;
    the ⌈(n + 1)(1 − α)⌉-th smallest of the n is exceeded by such a photo with probability at
    most α (split-conformal rank argument: Angelopoulos & Bates, *A gentle introduction to
    conformal prediction*, 2021, §1; the largest of them when n < 1/α − 1). The largest alone
    let street views posted to a panel camera be judged dirty (``bench/fleet_eval.py``). With
    ``groups`` (each photo's panel), the nearest photo of another group: a new panel is like
    the training panels, not like a second photo of one of them."""
    from sklearn.metrics import pairwise_distances_chunked

    n = len(z)
    group = np.arange(n) if groups is None else np.asarray(groups)  # else each its own

    def to_other_groups(d: NDArray[np.float64], start: int) -> NDArray[np.float64]:
        rows = group[start : start + len(d)]
        return np.asarray(np.where(rows[:, None] == group[None, :], np.inf, d).min(axis=1))

    nearest = np.sort(
        np.concatenate(list(pairwise_distances_chunked(z, reduce_func=to_other_groups)))
    )
    k = math.ceil((n + 1) * (1 - alpha))
    return float(nearest[min(k, n) - 1])


FLEET_FOLDS = 5
"""Folds of the fleet model's choices and of its reported accuracy."""

FLEET_LABELS = labels.LABELS
"""What a fleet photo may be labelled; ``dirty`` is read as dust."""


def fleet_folds(seed: int, grouped: bool, folds: int = FLEET_FOLDS) -> Any:
    """Stratified folds (scikit-learn), shuffled by ``seed``; ``grouped``: a group's photos
    (one panel's) all in one fold, so that a fold's score is on panels the fit never saw."""
    from sklearn.model_selection import StratifiedGroupKFold, StratifiedKFold

    kind = StratifiedGroupKFold if grouped else StratifiedKFold
    return kind(n_splits=folds, shuffle=True, random_state=seed)


def fleet_search(k: int, grouped: bool = False, folds: int = FLEET_FOLDS) -> Any:
    """The fleet classifier before its choice of C and γ, for ``k`` features: a standardised
    RBF support-vector machine with balanced classes, C and γ to be chosen by ``folds``-fold
    cross-validated balanced accuracy (scikit-learn's ``GridSearchCV``); ``grouped``: by folds
    that keep a group together (``fleet_folds``), its ``fit`` then given ``groups``."""
    from sklearn.model_selection import GridSearchCV
    from sklearn.pipeline import Pipeline
    from sklearn.preprocessing import StandardScaler
    from sklearn.svm import SVC

    return GridSearchCV(
        Pipeline([("scale", StandardScaler()), ("svm", SVC(class_weight="balanced"))]),
        {"svm__C": [1.0, 3.0, 10.0], "svm__gamma": [0.3 / k, 1.0 / k, 3.0 / k]},
        cv=fleet_folds(0, grouped, folds),
        scoring="balanced_accuracy",
    )


def fold_interval(scores: NDArray[np.float64], level: float = 0.95) -> tuple[float, float]:
    """The ``level`` interval of the mean of ``scores`` (one per fold), Student's t on their
    spread, clipped to [0, 1]: how far the figure could be from what unseen panels get, with
    as few folds as there are."""
    from scipy import stats

    k = len(scores)
    mean = float(np.mean(scores))
    half = float(stats.t.ppf(0.5 + level / 2, k - 1) * np.std(scores, ddof=1) / np.sqrt(k))
    return max(0.0, mean - half), min(1.0, mean + half)


def check_fleet_groups(groups: NDArray[np.str_], dirty: NDArray[np.bool_]) -> None:
    """Refuse groups too few to fold: each of clean and needs cleaning in at least
    ``FLEET_FOLDS`` groups (photos of snow aside), so that every fold can test both."""
    for name, rows in (("clean", ~dirty), ("needing cleaning", dirty)):
        if (n := len(set(groups[rows].tolist()))) < FLEET_FOLDS:
            raise Unprocessable(
                f"the photos {name} come from {n} groups; the folds that keep a group "
                f"together need at least {FLEET_FOLDS}",
                code="too_few_groups",
            )


def _checked_labels(
    features: NDArray[np.float64], labels: Sequence[str]
) -> tuple[NDArray[np.str_], dict[str, int]]:
    """The labels as the model reads them (dirty is dust) and each label's count; Unprocessable
    for too few photos of a class or non-finite features."""
    names = np.array(["dust" if label == "dirty" else label for label in labels])
    counts = {label: int((names == label).sum()) for label in FLEET_LABELS}
    n_clean, n_dirty = counts["clean"], counts["dust"] + counts["bird_drop"]
    if min(n_dirty, n_clean) < MIN_FLEET_PER_CLASS:
        raise Unprocessable(
            f"need at least {MIN_FLEET_PER_CLASS} clean and {MIN_FLEET_PER_CLASS} dust or "
            f"bird_drop images; got {n_clean} clean, {n_dirty} needing cleaning"
        )
    if not np.isfinite(features).all():
        raise Unprocessable("some images gave non-finite features")
    return names, counts


def _heads(z: NDArray[np.float64], names: NDArray[np.str_]) -> dict[str, Any]:
    """Logistic heads on the standardised features ``z``: snow against the rest, droppings
    against dust, each when at least 3 photos show it and 3 do not."""
    from sklearn.linear_model import LogisticRegression

    def head(positive: NDArray[np.bool_], rows: NDArray[np.bool_]) -> dict[str, Any] | None:
        if positive[rows].sum() < 3 or (~positive[rows]).sum() < 3:
            return None
        fit = LogisticRegression(C=0.3, class_weight="balanced", max_iter=5000)
        fit.fit(z[rows], positive[rows])
        return {"coef": fit.coef_[0].tolist(), "intercept": float(fit.intercept_[0])}

    everyone = np.ones(len(names), dtype=bool)
    heads = {
        "snow": head(names == "snow", everyone),
        "bird_drop": head(names == "bird_drop", np.isin(names, ("dust", "bird_drop"))),
    }
    return {name: h for name, h in heads.items() if h is not None}


def fit_fleet(
    features: NDArray[np.float64],
    labels: Sequence[str],
    *,
    now: datetime,
    groups: Sequence[str] | None = None,
) -> FleetModel:
    """The fleet model (``core.fleet.KernelModel``) from labelled photos of many panels.

    Needs cleaning (dust, bird_drop) against clean, on the photos that are not snow: a
    standardised RBF support-vector machine with balanced classes (scikit-learn), C and γ
    chosen by 5-fold cross-validated balanced accuracy, its decisions Platt-scaled to a
    probability on cross-validated decisions. ``cv_balanced_accuracy`` is that of the whole
    choice, nested: outer 5 folds, the choice made again inside each (on 3 folds with groups).
    Heads on the same
    features: snow against the rest, droppings against dust, each when ≥ 3 photos show it.

    ``groups`` names each photo's panel (or any group of near-duplicates): every fold then
    keeps a group's photos together, and the reach is measured to other groups' photos.
    Without it each photo is its own panel; several photos of one panel then flatter the
    choice, the accuracy and the probabilities, as a fold tests on panels it trained on."""
    from sklearn.linear_model import LogisticRegression
    from sklearn.model_selection import cross_val_predict, cross_val_score

    names, counts = _checked_labels(features, labels)
    n_clean, n_dirty = counts["clean"], counts["dust"] + counts["bird_drop"]
    k = features.shape[1]
    judged = names != "snow"
    x, dirty = features[judged], np.isin(names[judged], ("dust", "bird_drop"))
    g = None if groups is None else np.asarray(groups, dtype=str)
    gx = None if g is None else g[judged]  # the groups of the photos judged, as x
    if gx is not None:
        check_fleet_groups(gx, dirty)
    grouped = gx is not None
    fit_groups = {"groups": gx} if grouped else {}
    search = fleet_search(k, grouped=grouped)
    # an outer fold's training part may hold only 4 groups of a class: 3 inner folds
    inner = fleet_search(k, grouped=True, folds=3) if grouped else search
    outer = fleet_folds(1, grouped)
    cv = cross_val_score(
        inner, x, dirty, groups=gx, cv=outer, scoring="balanced_accuracy", params=fit_groups
    )
    low, high = fold_interval(cv)
    search.fit(x, dirty, **fit_groups)
    best = search.best_estimator_
    folds = fleet_folds(0, grouped)
    decisions = cross_val_predict(best, x, dirty, groups=gx, cv=folds, method="decision_function")
    platt = LogisticRegression(C=1e6).fit(decisions.reshape(-1, 1), dirty)
    scaler, svm = best.named_steps["scale"], best.named_steps["svm"]
    scale = np.where(scaler.scale_ > 0, scaler.scale_, 1.0)
    z = (features - scaler.mean_) / scale
    heads = _heads(z, names)
    return FleetModel(
        id=str(uuid.uuid4()),
        created_at=now,
        feature_names=list(ALL_FEATURES),
        mean=scaler.mean_.tolist(),
        scale=scale.tolist(),
        coef=[],
        intercept=0.0,
        kernel={
            "support": svm.support_vectors_.tolist(),
            "dual": svm.dual_coef_[0].tolist(),
            "intercept": float(svm.intercept_[0]),
            "gamma": float(svm.gamma),
            "platt": [float(platt.coef_[0, 0]), float(platt.intercept_[0])],
            "training": z.tolist(),
            "reach": reach(z, groups=g),
        },
        heads=heads,
        threshold=0.5,
        n_clean=n_clean,
        n_dirty=n_dirty,
        n_snow=counts["snow"],
        n_bird_drop=counts["bird_drop"],
        cv_balanced_accuracy=float(np.mean(cv)),
        cv_low=low,
        cv_high=high,
        n_groups=None if g is None else len(set(g.tolist())),
    )
