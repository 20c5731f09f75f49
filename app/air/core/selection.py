"""Which grading measures best: the candidate methods scored on data they were not fitted to.

A calibration from reference values (PM2.5 or AQI) can grade by the dissertation's T² level
clusters ([Fayed 2013] ch. 6, eqs. 6.12–6.22) or by the ridge regression on the sky features
(``airquality.fit_regression``). Both are fitted on all days but one group of days and judged
on the days left out, each frame's category against the reference's; the one with the smaller
score grades. A frame a method leaves ungraded (outside every cluster, or outside the
regression's calibration) counts as ``UNGRADED_ERROR`` categories off: a screen that names
nothing misleads as much as one two categories wrong.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from app.air.core import airquality, public
from app.stats import hotelling

METHODS = ("regression", "clusters")
"""The candidates, in the order a tie goes."""

UNGRADED_ERROR = 2.0
"""The error [categories] of a frame a method cannot grade."""

MAX_FOLDS = 7
"""Groups of days the comparison leaves out in turn at most (each fold fits both methods)."""

SCORE = "mean absolute category error on days left out"


@dataclass(frozen=True, slots=True)
class Selection:
    chosen: str
    scores: dict[str, float | None]
    """Each method's score (None: it could not be fitted on some fold)."""
    folds: int
    left_out: str
    """What a fold leaves out: "days" or "images"."""

    def kept(self) -> dict[str, object]:
        """As a calibration keeps and shows it."""
        return {
            "chosen": self.chosen,
            "scores": self.scores,
            "score": SCORE if self.left_out == "days" else SCORE.replace("days", "images"),
            "folds": self.folds,
        }


def _index(level: float) -> int:
    return public.NAMES.index(airquality.category(level))


def _folds(n: int, groups: NDArray[np.str_] | None) -> list[NDArray[np.intp]]:
    """Test indices of each fold: groups of days (whole days together, about equal in frames),
    or, without days, every k-th image (seeded order)."""
    if groups is not None:
        from sklearn.model_selection import GroupKFold

        k = min(MAX_FOLDS, len(set(groups.tolist())))
        return [te for _, te in GroupKFold(k).split(np.zeros(n), groups=groups)]
    order = np.random.default_rng(0).permutation(n)
    return [np.sort(order[i::5]) for i in range(min(5, n))]


def choose(
    modes: ArrayLike,
    features: ArrayLike | None,
    levels: ArrayLike,
    targets: ArrayLike,
    *,
    unit: str,
    table: str,
    groups: ArrayLike | None,
    significance: float,
    shrinkage: float,
) -> Selection:
    """Score each method (``METHODS``) on folds that leave out days (``groups``, each image's
    day, when they are at least ``airquality.MIN_GROUPS``) or else images, and choose the
    smaller score. ``levels``: each image's level from its reference; ``targets``: the
    reference values in ``unit`` the regression is fitted to."""
    x = np.asarray(modes, dtype=np.float64)
    lv = np.asarray(levels, dtype=np.int64)
    y = np.asarray(targets, dtype=np.float64)
    g = None if groups is None else np.asarray(groups).astype(str)
    by_day = g is not None and len(set(g.tolist())) >= airquality.MIN_GROUPS
    folds = _folds(len(lv), g if by_day else None)
    truth = np.array([_index(v) for v in lv])
    errors: dict[str, NDArray[np.float64] | None] = {m: np.zeros(len(lv)) for m in METHODS}
    for te in folds:
        tr = np.setdiff1d(np.arange(len(lv)), te)
        said = {
            "clusters": _clusters(x[tr], lv[tr], x[te], significance, shrinkage),
            "regression": None
            if features is None
            else _regression(
                np.asarray(features, dtype=np.float64),
                y,
                tr,
                te,
                unit=unit,
                table=table,
                groups=None if g is None or not by_day else g,
            ),
        }
        for m in METHODS:
            err = errors[m]
            shown = said[m]
            if err is None or shown is None:
                errors[m] = None
                continue
            err[te] = np.where(shown < 0, UNGRADED_ERROR, np.abs(shown - truth[te]))
    scores = {m: None if e is None else float(e.mean()) for m, e in errors.items()}
    usable = [m for m in METHODS if scores[m] is not None]
    if not usable:
        raise ValueError("neither method could be fitted on every fold")
    chosen = min(usable, key=lambda m: (scores[m], METHODS.index(m)))
    return Selection(chosen, scores, len(folds), "days" if by_day else "images")


def _clusters(
    modes_tr: NDArray[np.float64],
    levels_tr: NDArray[np.int64],
    modes_te: NDArray[np.float64],
    significance: float,
    shrinkage: float,
) -> NDArray[np.int64] | None:
    """Each test frame's category index by the clusters fitted on the rest (−1: none
    accepts it); None when they cannot be fitted."""
    try:
        cal = airquality.level_clusters(
            modes_tr, levels_tr, significance=significance, shrinkage=shrinkage
        )
    except (hotelling.BaselineError, ValueError):
        return None
    out = []
    for m in modes_te:
        level = airquality.grade(cal, m).level
        out.append(-1 if level is None else _index(level))
    return np.array(out, dtype=np.int64)


def _regression(
    features: NDArray[np.float64],
    targets: NDArray[np.float64],
    tr: NDArray[np.intp],
    te: NDArray[np.intp],
    *,
    unit: str,
    table: str,
    groups: NDArray[np.str_] | None,
) -> NDArray[np.int64] | None:
    """Each test frame's most probable category by the regression fitted on the rest, as
    verdicts give it (``public.public``; −1 outside its calibration); None when it cannot be
    fitted (fewer than 10 images or 3 levels)."""
    y_tr = targets[tr]
    if len(tr) < 10 or len({airquality.level_of(v, unit, table) for v in y_tr}) < 3:
        return None
    model, _ = airquality.fit_regression(
        features[tr],
        y_tr,
        unit=unit,
        table=table,
        groups=None if groups is None else groups[tr].tolist(),
    )
    out = []
    for f in features[te]:
        e = model.estimate(f)
        if e.outside or e.scale is None:
            out.append(-1 if e.outside else _index(e.level))
            continue
        p = public.public(public.Predictive(e.loc, e.scale, model.dof, unit, table))
        out.append(_index(p.level))
    return np.array(out, dtype=np.int64)
