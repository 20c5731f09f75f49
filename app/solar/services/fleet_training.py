"""The fleet model's training: labelled photos of many panels in, a ``FleetModel`` out, with
the accuracy it will have on panels it never saw, measured with every choice made again inside
each fold."""

from __future__ import annotations

import math
import uuid
from collections.abc import Sequence
from dataclasses import dataclass
from datetime import datetime
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.special import expit

from app.platform.http.errors import Unprocessable
from app.solar.core.fleet import ALL_FEATURES, SHAPE_FEATURES, SNOW_FEATURES, pick
from app.solar.models import FleetModel
from app.solar.services import labels

MIN_FLEET_PER_CLASS = 5

NOVELTY = 0.05
"""How often a panel photo like the training photos may be called unlike them (``Shape``)."""

SHAPE_FOLDS = 100
"""At most this many folds hold the panel test's photos out: one panel at a time up to 100."""


def conformal_limit(scores: NDArray[np.float64], alpha: float = NOVELTY) -> float:
    """The ⌈(n + 1)(1 − α)⌉-th smallest of n held-out scores (the largest when that rank
    exceeds n): a new score drawn like them exceeds it with probability at most α
    (split-conformal rank argument: Angelopoulos & Bates, *A gentle introduction to
    conformal prediction*, 2021, §1)."""
    n = len(scores)
    k = math.ceil((n + 1) * (1 - alpha))
    return float(np.sort(scores)[min(k, n) - 1])


def shape_model(
    features: NDArray[np.float64], groups: NDArray[np.str_] | None, seed: int = 0
) -> dict[str, Any] | None:
    """What the training photos look like (``core.fleet.Shape``): their standardised
    ``SHAPE_FEATURES``, a Ledoit–Wolf shrunk covariance (scikit-learn) and the conformal
    limit of the Mahalanobis distances of photos held out one group (panel) at a time, up to
    ``SHAPE_FOLDS`` folds (each photo its own group without ``groups``): a panel photo like
    them lies beyond it with probability of about ``NOVELTY``. None when ``features``
    are not full ``ALL_FEATURES`` vectors.

    Shrinkage, because 30 features from a few dozen photos give a covariance too noisy to
    invert; held-out distances, because a photo's distance from a fit that saw it is short;
    one left out at a time, because a fit on all but one is what a new photo meets (5 folds'
    fits on 80 % made the limit loose: 3.4 % of held-out panel photos beyond it and 86.5 % of
    photos with no panel, against 5.5 % and 89.0 % so, ``bench/fleet_eval.py``)."""
    from sklearn.covariance import LedoitWolf
    from sklearn.model_selection import GroupKFold

    if features.shape[1] != len(ALL_FEATURES):
        return None
    x = pick(features, SHAPE_FEATURES)
    mean, scale = x.mean(axis=0), x.std(axis=0)
    scale = np.where(scale > 0, scale, 1.0)
    z = (x - mean) / scale
    g = np.arange(len(z)).astype(str) if groups is None else np.asarray(groups)
    held = np.zeros(len(z))
    folds = GroupKFold(n_splits=min(len(set(g.tolist())), SHAPE_FOLDS))
    for train, test in folds.split(z, groups=g):
        held[test] = LedoitWolf().fit(z[train]).mahalanobis(z[test])  # squared distances
    fit = LedoitWolf().fit(z)
    return {
        "mean": mean.tolist(),
        "scale": scale.tolist(),
        "location": fit.location_.tolist(),
        "precision": fit.precision_.tolist(),
        "limit": float(np.sqrt(conformal_limit(held))),
    }


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


SNOW_C = 0.1
"""The snow head's inverse regularisation: 7 snow photos in 77 do not bear a freer fit."""


def _heads(
    z: NDArray[np.float64], names: NDArray[np.str_], groups: NDArray[np.str_] | None
) -> dict[str, Any]:
    """Logistic heads on the standardised features ``z``: snow against the rest (on
    ``SNOW_FEATURES`` when ``z`` has all features: whiteness and cover, not the panel's
    texture), droppings against dust, each when at least 3 photos show it and 3 do not. The
    snow head keeps its ``floor``: the lowest p(snow) of a snow photo held out of its fit."""
    from sklearn.linear_model import LogisticRegression

    k = z.shape[1]
    everyone = np.ones(len(names), dtype=bool)
    snow = names == "snow"
    columns = (
        np.array([ALL_FEATURES.index(n) for n in SNOW_FEATURES])
        if k == len(ALL_FEATURES)
        else np.arange(k)
    )

    def head(
        positive: NDArray[np.bool_], rows: NDArray[np.bool_], cols: NDArray[np.int64], c: float
    ) -> dict[str, Any] | None:
        if positive[rows].sum() < 3 or (~positive[rows]).sum() < 3:
            return None
        fit = LogisticRegression(C=c, class_weight="balanced", max_iter=5000)
        fit.fit(z[rows][:, cols], positive[rows])
        coef = np.zeros(k)
        coef[cols] = fit.coef_[0]
        return {"coef": coef.tolist(), "intercept": float(fit.intercept_[0])}

    heads = {
        "snow": head(snow, everyone, columns, SNOW_C),
        "bird_drop": head(
            names == "bird_drop", np.isin(names, ("dust", "bird_drop")), np.arange(k), 0.3
        ),
    }
    if heads["snow"] is not None:
        heads["snow"]["floor"] = _snow_floor(z[:, columns], snow, groups)
    return {name: h for name, h in heads.items() if h is not None}


def _snow_floor(
    z: NDArray[np.float64], snow: NDArray[np.bool_], groups: NDArray[np.str_] | None
) -> float | None:
    """The lowest p(snow) of a snow photo held out of the head's fit, its group (panel) left
    out at a time (up to ``SHAPE_FOLDS`` folds, so that the cost is bounded); None for fewer
    than 2 groups of snow photos. A frame the fleet model
    would send to brushing with p(snow) at or above it is doubted: it may be snow as those
    photos were. One group out at a time, because a fit on all but one is what a new snow
    photo meets."""
    from sklearn.linear_model import LogisticRegression

    g = np.arange(len(snow)).astype(str) if groups is None else groups
    snowy = sorted(set(g[snow].tolist()))
    if len(snowy) < 2:
        return None
    folds = min(len(snowy), SHAPE_FOLDS)  # one group a fold, up to SHAPE_FOLDS fits
    held = []
    for k in range(folds):
        out = np.isin(g, snowy[k::folds])
        fit = LogisticRegression(C=SNOW_C, class_weight="balanced", max_iter=5000)
        fit.fit(z[~out], snow[~out])
        held.append(float(fit.predict_proba(z[out & snow])[:, 1].min()))
    return min(held)


BANDS = (0.1, 0.15, 0.2, 0.25, 0.3)
"""The not-sure bands a model may choose among (``choose_band``)."""

ANSWERED = 0.8
"""The least share of its training photos a model's band must still answer."""


def choose_band(p: NDArray[np.float64], dirty: NDArray[np.bool_], threshold: float = 0.5) -> float:
    """The not-sure band, from held-out p(needs cleaning) ``p`` of the training photos and
    their truth: of the ``BANDS`` that still answer at least ``ANSWERED`` of them, the one
    whose answers (|p − threshold| ≥ band) have the best balanced accuracy, the narrowest on
    a tie; the narrowest when none does. Chosen on the training photos only, so that the
    accuracy of the sure answers on other panels is measured, not assumed."""
    from sklearn.metrics import balanced_accuracy_score

    best, best_score = BANDS[0], -1.0
    for band in BANDS:
        sure = np.abs(p - threshold) >= band
        if sure.mean() < ANSWERED or len(set(dirty[sure].tolist())) < 2:
            continue
        score = float(balanced_accuracy_score(dirty[sure], p[sure] >= threshold))
        if score > best_score + 1e-12:
            best, best_score = band, score
    return best


@dataclass(frozen=True, slots=True)
class Judge:
    """The clean-or-dirty part of a fleet model: the fitted pipeline (scaler, SVM), Platt's
    (a, c) and the not-sure band."""

    pipeline: Any
    platt: tuple[float, float]
    band: float

    def probability(self, x: NDArray[np.float64]) -> NDArray[np.float64]:
        a, c = self.platt
        decision = np.asarray(self.pipeline.decision_function(x), dtype=np.float64)
        return np.asarray(expit(a * decision + c), dtype=np.float64)


def fit_judge(
    x: NDArray[np.float64], dirty: NDArray[np.bool_], groups: NDArray[np.str_] | None, folds: int
) -> Judge:
    """C and γ by ``folds``-fold cross-validation (grouped when ``groups``), Platt's sigmoid
    on the chosen machine's cross-validated decisions, the band on the probabilities those
    give: every choice from ``x`` alone."""
    from sklearn.linear_model import LogisticRegression
    from sklearn.model_selection import cross_val_predict

    grouped = groups is not None
    search = fleet_search(x.shape[1], grouped=grouped, folds=folds)
    search.fit(x, dirty, **({"groups": groups} if grouped else {}))
    best = search.best_estimator_
    cv = fleet_folds(0, grouped, folds)
    decisions = cross_val_predict(best, x, dirty, groups=groups, cv=cv, method="decision_function")
    platt = LogisticRegression(C=1e6).fit(decisions.reshape(-1, 1), dirty)
    a, c = float(platt.coef_[0, 0]), float(platt.intercept_[0])
    p = expit(a * decisions + c)
    return Judge(best, (a, c), choose_band(p, dirty))


@dataclass(frozen=True, slots=True)
class Nested:
    """Per outer fold: balanced accuracy of every answer, of the sure answers, the share
    answered; and the balanced accuracy when the farm's labelled frames were left out of
    training (None without them)."""

    every: NDArray[np.float64]
    sure: NDArray[np.float64]
    answered: NDArray[np.float64]
    without_farm: NDArray[np.float64] | None


def nested(
    x: NDArray[np.float64],
    dirty: NDArray[np.bool_],
    groups: NDArray[np.str_] | None,
    farm: NDArray[np.bool_] | None = None,
) -> Nested:
    """The whole training (``fit_judge``) run again inside each of 5 outer folds and scored
    on the fold it never saw: what a model trained so gets on new panels (with ``groups``).
    ``farm`` marks the farm's labelled frames: each fold is fitted once more without them
    and scored on the same held-out photos, farm frames included."""
    from sklearn.metrics import balanced_accuracy_score

    inner = 3 if groups is not None else FLEET_FOLDS  # a training part may hold 4 groups
    every, sure, answered, without = [], [], [], []
    outer = fleet_folds(1, groups is not None)
    for train, test in outer.split(x, dirty, groups):
        gt = None if groups is None else groups[train]
        judge = fit_judge(x[train], dirty[train], gt, inner)
        p = judge.probability(x[test])
        every.append(balanced_accuracy_score(dirty[test], p >= 0.5))
        said = np.abs(p - 0.5) >= judge.band
        answered.append(float(said.mean()))
        truth = dirty[test][said]
        sure.append(
            balanced_accuracy_score(truth, p[said] >= 0.5) if len(set(truth)) > 1 else np.nan
        )
        if farm is not None and farm.any():
            own = train[~farm[train]]
            try:
                alone = fit_judge(
                    x[own], dirty[own], None if groups is None else groups[own], inner
                )
            except ValueError:  # too few photos of a class without the farm's
                without.append(np.nan)
                continue
            without.append(balanced_accuracy_score(dirty[test], alone.probability(x[test]) >= 0.5))
    return Nested(
        np.array(every),
        np.array(sure),
        np.array(answered),
        np.array(without) if without else None,
    )


def _mean(values: NDArray[np.float64] | None) -> float | None:
    """The mean of the finite ``values``; None when there are none."""
    if values is None or not np.isfinite(values).any():
        return None
    return float(np.nanmean(values))


def fit_fleet(
    features: NDArray[np.float64],
    labels: Sequence[str],
    *,
    now: datetime,
    groups: Sequence[str] | None = None,
    farm: Sequence[bool] | None = None,
) -> FleetModel:
    """The fleet model (``core.fleet.KernelModel``) from labelled photos of many panels.

    Needs cleaning (dust, bird_drop) against clean, on the photos that are not snow: a
    standardised RBF support-vector machine with balanced classes (scikit-learn), C and γ
    chosen by 5-fold cross-validated balanced accuracy, its decisions Platt-scaled to a
    probability on cross-validated decisions, its not-sure band chosen on those
    (``fit_judge``). Heads on the same features: snow against the rest, droppings against
    dust, each when ≥ 3 photos show it. The panel test (``shape_model``) on all of them.

    ``cv_balanced_accuracy`` (with its 95 % interval), ``cv_sure_balanced_accuracy`` and
    ``cv_answered`` are those of the whole training, nested (``nested``). ``farm`` marks the
    farm's labelled frames: ``cv_without_farm`` is the figure had they not been given.

    ``groups`` names each photo's panel (or any group of near-duplicates): every fold then
    keeps a group's photos together. Without it each photo is its own panel; several photos
    of one panel then flatter the choice, the accuracy and the probabilities, as a fold
    tests on panels it trained on."""
    names, counts = _checked_labels(features, labels)
    judged = names != "snow"
    x, dirty = features[judged], np.isin(names[judged], ("dust", "bird_drop"))
    g = None if groups is None else np.asarray(groups, dtype=str)
    gx = None if g is None else g[judged]  # the groups of the photos judged, as x
    if gx is not None:
        check_fleet_groups(gx, dirty)
    from_farm = None if farm is None else np.asarray(farm, dtype=bool)[judged]
    scores = nested(x, dirty, gx, from_farm)
    low, high = fold_interval(scores.every)
    judge = fit_judge(x, dirty, gx, FLEET_FOLDS)
    scaler, svm = judge.pipeline.named_steps["scale"], judge.pipeline.named_steps["svm"]
    scale = np.where(scaler.scale_ > 0, scaler.scale_, 1.0)
    z = (features - scaler.mean_) / scale
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
            "platt": list(judge.platt),
            "band": judge.band,
            "shape": shape_model(features, g),
        },
        heads=_heads(z, names, g),
        threshold=0.5,
        n_clean=counts["clean"],
        n_dirty=counts["dust"] + counts["bird_drop"],
        n_snow=counts["snow"],
        n_bird_drop=counts["bird_drop"],
        cv_balanced_accuracy=float(np.mean(scores.every)),
        cv_low=low,
        cv_high=high,
        cv_sure_balanced_accuracy=_mean(scores.sure),
        cv_answered=float(np.mean(scores.answered)),
        n_farm=0 if from_farm is None else int(np.asarray(farm, dtype=bool).sum()),
        cv_without_farm=_mean(scores.without_farm),
        n_groups=None if g is None else len(set(g.tolist())),
    )
