"""Air-quality grading on real photos with measured pollution (../shared/data/sky).

India–Nepal (74 photos, US AQI, 52 capture sessions): folds grouped by capture session (the
frames of one session are near-duplicates). The AQI classes map onto the 1–10 scale as the data
README suggests (Good 10, Moderate 8, USG 6, Unhealthy 4, Very Unhealthy 2, Severe 1). The sky
ROI is the top 40 % of each photo (many show more city than sky). Methods, on the same folds:
- ``modes, T² clusters``: the dissertation's method as the service runs it (``airquality``);
  "outside calibration" frames get no level and are left out of the correlation (coverage given);
- ``features, ridge``: the service's ``method=regression`` — a ridge regression across levels
  on the sky's modes, means, blue-to-red ratio, darkest-channel median and spread, and the
  contrast of the strip below the sky (distant objects fade in haze): ``airquality.sky_features``.
Reported: Spearman's ρ between the predicted level and the measured AQI (negative is right: a
high level is clean air) and the within-one-category accuracy; the same for a reference that
sees no pixel (``place only``: the mean level of the training photos from the same place), which
measures how much of the pooled ρ the confounding of class with place gives away; the
regression's ρ within each location with at least 10 photos (the setting of a camera that stays
where it is); and models fitted to the variation within places alone (features and level less
their place's mean over the training folds: ridge and a random forest), whose predicted
deviations are ranked against the AQI's deviation from its place's mean — whether the pixels
carry anything about the air once the place is known.
Milan series (151 frames of one fixed webcam over 28 days, hourly PM2.5 of the nearest
station): folds grouped by day and earlier days → later ones, the levels made from PM2.5 by
each breakpoint table in turn (US EPA AQI, European Air Quality Index).

    python bench/airquality_eval.py [--data ../shared/data/sky]
"""

from __future__ import annotations

import argparse
import csv
from dataclasses import dataclass
from datetime import datetime
from pathlib import Path
from zoneinfo import ZoneInfo

import numpy as np
from scipy.stats import spearmanr
from sklearn.ensemble import RandomForestRegressor
from sklearn.linear_model import RidgeCV
from sklearn.model_selection import GroupKFold
from sklearn.pipeline import make_pipeline
from sklearn.preprocessing import StandardScaler

from app.air.core import airquality, breakpoints, public, selection
from app.air.kind import band_below
from app.platform.frames.jpeg import decode_rgb
from app.platform.frames.stats import channel_stats
from app.stats import hotelling

ROOT = Path(__file__).resolve().parents[1]
LEVELS = {
    "a_Good": 10,
    "b_Moderate": 8,
    "c_Unhealthy_for_Sensitive_Groups": 6,
    "d_Unhealthy": 4,
    "e_Very_Unhealthy": 2,
    "f_Severe": 1,
}
CATEGORY_INDEX = {name: i for i, (_, name) in enumerate(airquality.CATEGORIES)}


def features(
    image: np.ndarray, sky: tuple[float, float], below: tuple[float, float]
) -> tuple[np.ndarray, np.ndarray]:
    """The service's features: modes of the sky region, ``airquality.sky_features`` of it and
    of the strip below it (the skyline)."""
    h = image.shape[0]
    region = np.ascontiguousarray(image[int(sky[0] * h) : int(sky[1] * h)])
    strip = np.ascontiguousarray(image[int(below[0] * h) : int(below[1] * h)])
    modes = channel_stats(region).modes.astype(np.float64)
    return modes, airquality.sky_features(region, strip)


def within_one(pred_levels: np.ndarray, true_levels: np.ndarray) -> float:
    p = [CATEGORY_INDEX[airquality.category(float(np.clip(v, 1, 10)))] for v in pred_levels]
    t = [CATEGORY_INDEX[airquality.category(float(v))] for v in true_levels]
    return float(np.mean(np.abs(np.array(p) - np.array(t)) <= 1))


def service_regression(f_tr: np.ndarray, lv_tr: np.ndarray, f_te: np.ndarray) -> np.ndarray:
    """Exactly what the service does with ``method=regression``: fit, then integer levels."""
    model, _ = airquality.fit_regression(f_tr, lv_tr)
    return np.array([model.level(f) for f in f_te], dtype=np.float64)


MILAN_SKY = (32, 330)
"""Rows of the Milan webcam's sky at 1920×1080: below the top overlay ribbon, above the
skyline; the camera's ROI (0, 32, 1920, 298)."""


def milan_features(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """Modes and ``SKY_FEATURES`` of a Milan frame as the service measures a camera with the
    ROI of ``MILAN_SKY``: the region, then the skyline strip below it (``kind.band_below``)."""
    _, image = decode_rgb(path.read_bytes(), max_pixels=10**8)
    top, bottom = MILAN_SKY
    roi = (0, top, image.shape[1], bottom - top)
    region = np.ascontiguousarray(image[top:bottom])
    modes = channel_stats(region).modes.astype(np.float64)
    return modes, airquality.sky_features(region, band_below(image, roi))


def milan_times(rows: list[dict[str, str]]) -> list[datetime]:
    """Each Milan frame's capture time: its date and local hour, in Milan's zone."""
    rome = ZoneInfo("Europe/Rome")
    return [
        datetime.fromisoformat(f"{r['date']}T{r['hour_local']}").replace(tzinfo=rome) for r in rows
    ]


def earlier_days(days: list[str]) -> int:
    """How many of the sorted ``days`` the earlier → later split fits on: two thirds."""
    return len(days) * 2 // 3


def spearman(a: np.ndarray, b: np.ndarray) -> float:
    """ρ over the pairs where both are finite; nan for fewer than 3 or a constant side."""
    ok = np.isfinite(a) & np.isfinite(b)
    if ok.sum() < 3 or np.ptp(a[ok]) == 0 or np.ptp(b[ok]) == 0:
        return float("nan")
    return float(spearmanr(a[ok], b[ok])[0])


def milan(root: Path, folds: int) -> None:
    """The fixed Milan webcam (``milan_series``) as the city's screen shows it."""
    with open(root / "labels.csv") as f:
        rows = list(csv.DictReader(f))
    modes, feats = (
        np.array(a) for a in zip(*(milan_features(root / r["file"]) for r in rows), strict=True)
    )
    data = Milan(
        modes,
        feats,
        np.array([float(r["pm25_ugm3"]) for r in rows]),
        np.array([r["date"] for r in rows]),
        milan_times(rows),
    )
    days = sorted(set(data.day.tolist()))
    print(
        f"Milan series: {len(rows)} frames over {len(days)} days; categories and alerts by the "
        f"{breakpoints.TABLES[TABLE]} (Milan's): Poor is above 25 µg/m³"
    )
    outer = [te for _, te in GroupKFold(folds).split(feats, groups=data.day)]
    k = earlier_days(days)
    later = np.flatnonzero(data.day >= days[k])
    for name, judged in (
        (f"{folds} outer folds grouped by day, every day judged once", outer),
        (f"earlier {k} days → later {len(days) - k}", [later]),
    ):
        milan_public(data, judged, name)
    every = np.arange(len(rows))
    print(
        f"  the alert threshold the same rule chooses on all {len(days)} days: "
        f"{choose_threshold(data, every):.2f} (the service's ALERT_RAISE: {public.ALERT_RAISE})"
    )


TABLE = "eu_eaqi"
"""The Milan camera's breakpoint table: the service's default for a camera in Europe."""
GRID = np.round(np.arange(0.15, 0.81, 0.05), 2)
"""Probabilities of Poor or worse an alert threshold is chosen among."""


@dataclass(frozen=True)
class Milan:
    modes: np.ndarray
    feats: np.ndarray
    pm: np.ndarray
    day: np.ndarray
    times: list[datetime]


@dataclass(frozen=True)
class Said:
    """What the service says of judged frames: each one's public (smoothed) reading by the
    regression, and each frame's category by the clusters (−1 ungraded)."""

    category: np.ndarray
    probability: np.ndarray
    value: np.ndarray
    low: np.ndarray
    high: np.ndarray
    poor: np.ndarray
    clusters: np.ndarray


NAMES = [name for _, name in airquality.CATEGORIES]


def cat_index(pm: float) -> int:
    return NAMES.index(airquality.category(breakpoints.level_of_pm25(max(pm, 0.0), TABLE)))


def say(d: Milan, train: np.ndarray, test: np.ndarray) -> Said:
    """Fit both methods on ``train`` as the service does and read ``test``'s frames as the
    service shows them: each frame's predictive t, smoothed with the frames of its day before
    it (``public.smooth``: the days are hours apart, beyond the 12 hours it weighs)."""
    model, _ = airquality.fit_regression(
        d.feats[train], d.pm[train], unit="pm25", groups=d.day[train].tolist(), table=TABLE
    )
    levels = np.array([breakpoints.level_of_pm25(v, TABLE) for v in d.pm[train]])
    try:
        cal = airquality.level_clusters(
            d.modes[train], levels, shrinkage=hotelling.QUANTISATION_VARIANCE
        )
    except hotelling.BaselineError:
        cal = None
    shape = public.Shape.of(model)
    reads: dict[str, list[public.Read]] = {}
    for i in test:
        e = model.estimate(d.feats[i])
        if not e.outside and e.scale is not None:
            reads.setdefault(d.day[i], []).append(public.Read(d.times[i], e.loc, e.scale))
    out = {k: np.full(len(test), np.nan) for k in ("cat", "p", "v", "lo", "hi", "poor", "cl")}
    for j, i in enumerate(test):
        p = public.smooth(reads.get(d.day[i], []), d.times[i], shape)
        if p is not None:
            r = public.public(p)
            out["cat"][j], out["p"][j] = NAMES.index(r.category), r.probability
            out["v"][j], out["lo"][j], out["hi"][j], out["poor"][j] = r.value, r.low, r.high, r.poor
        g = airquality.grade(cal, d.modes[i]).level if cal is not None else None
        out["cl"][j] = -1 if g is None else NAMES.index(airquality.category(g))
    return Said(out["cat"], out["p"], out["v"], out["lo"], out["hi"], out["poor"], out["cl"])


def alert_days(
    d: Milan, idx: np.ndarray, poor: np.ndarray, raise_at: float, clear_at: float
) -> set[str]:
    """The days an alert is raised on, replaying ``public.alert_kind`` frame by frame (an
    episode lapses overnight: the days are more than 12 hours apart)."""
    raised = set()
    for day in sorted(set(d.day[idx].tolist())):
        here = [j for j, i in enumerate(idx) if d.day[i] == day and np.isfinite(poor[j])]
        here.sort(key=lambda j: d.times[idx[j]])
        episode, earlier = False, []
        for j in here:
            kind = public.alert_kind(
                poor[j], reversed(earlier), episode, raise_at=raise_at, clear_at=clear_at
            )
            episode = (episode or kind == "raised") and kind != "cleared"
            if kind == "raised":
                raised.add(day)
            earlier.append(poor[j])
    return raised


def bad_and_clean(d: Milan, idx: np.ndarray) -> tuple[set[str], set[str]]:
    """Days with two or more station hours above 25 µg/m³; days whose maximum is ≤ 20."""
    bad, clean = set(), set()
    for day in set(d.day[idx].tolist()):
        pm = d.pm[idx][d.day[idx] == day]
        if (pm > 25).sum() >= 2:
            bad.add(day)
        if pm.max() <= 20:
            clean.add(day)
    return bad, clean


def choose_threshold(d: Milan, train: np.ndarray) -> float:
    """The alert threshold chosen on ``train``'s days alone: their out-of-fold readings
    (folds of days inside them), the threshold that maximises the share of bad days alerted
    less twice the share of clean days alerted (a false alarm costs the screen's credit);
    of several equally good, the middle one (the most margin either way). It clears at half
    of it (``public.ALERT_CLEAR``'s ratio)."""
    poor = np.full(len(train), np.nan)
    for tr, te in GroupKFold(5).split(train, groups=d.day[train]):
        poor[te] = say(d, train[tr], train[te]).poor
    bad, clean = bad_and_clean(d, train)
    scores = []
    for t in GRID:
        days = alert_days(d, train, poor, float(t), float(t) / 2)
        scores.append(len(days & bad) / max(len(bad), 1) - 2 * len(days & clean) / len(clean))
    best = np.flatnonzero(np.isclose(scores, max(scores)))
    return float(GRID[best[len(best) // 2]])


def milan_public(d: Milan, judged: list[np.ndarray], name: str) -> None:
    """The public reading of each judged group of days, from methods and thresholds chosen on
    the other days alone."""
    idx = np.concatenate(judged)
    said: list[Said] = []
    chosen, thresholds = [], []
    for te in judged:
        tr = np.setdiff1d(np.arange(len(d.pm)), te)
        levels = [breakpoints.level_of_pm25(v, TABLE) for v in d.pm[tr]]
        pick = selection.choose(
            d.modes[tr], d.feats[tr], levels, d.pm[tr], unit="pm25", table=TABLE,
            groups=d.day[tr].tolist(), significance=0.05,
            shrinkage=hotelling.QUANTISATION_VARIANCE,
        )  # fmt: skip
        chosen.append(pick)
        thresholds.append(choose_threshold(d, tr))
        said.append(say(d, tr, te))
    cat = np.concatenate([s.category for s in said])
    truth = np.array([cat_index(v) for v in d.pm[idx]])
    named = np.isfinite(cat)
    err = cat[named] - truth[named]  # positive: the screen says worse than the station
    lo, hi = np.concatenate([s.low for s in said]), np.concatenate([s.high for s in said])
    holds = (d.pm[idx] >= lo) & (d.pm[idx] <= hi)
    cl = np.concatenate([s.clusters for s in said])
    cl_err = np.where(cl < 0, np.nan, cl - truth)
    prob = np.concatenate([s.probability for s in said])[named]
    print(f"  {name} ({len(idx)} frames judged)")

    def score(v: float | None) -> str:
        return "unfit" if v is None else f"{v:.2f}"

    print(
        "    method chosen on the other days (category error: regression, clusters): "
        + "; ".join(
            f"{p.chosen} ({score(p.scores['regression'])}, {score(p.scores['clusters'])})"
            for p in chosen
        )
    )
    sure = prob >= public.SURE
    print(
        f"    public reading named on {named.mean():.1%} of frames; within one of the station's "
        f"category {np.mean(np.abs(err) <= 1):.1%}, exact {np.mean(err == 0):.1%}, mean signed "
        f"error {-err.mean():+.2f} categories (positive: cleaner than the station)"
    )
    print(
        f"    said plainly (probability ≥ {public.SURE}) on {sure.mean():.1%} of them, right in "
        f"{np.mean(err[sure] == 0):.1%}; median probability {np.median(prob):.2f}"
    )
    print(
        f"    80 % range holds the station's PM2.5 in {holds[named].mean():.1%} of frames; "
        f"median width {np.median((hi - lo)[named]):.1f} µg/m³"
    )
    graded = np.isfinite(cl_err)
    print(
        f"    clusters (the dissertation), frame by frame: graded {graded.mean():.1%}; within one "
        f"{np.mean(np.abs(cl_err[graded]) <= 1):.1%}, exact {np.mean(cl_err[graded] == 0):.1%}, "
        f"mean signed error {-np.nanmean(cl_err):+.2f}"
    )
    poor = np.concatenate([s.poor for s in said])
    bad, clean = bad_and_clean(d, idx)
    for label, ts in (
        ("thresholds chosen on the other days", thresholds),
        ("the service's ALERT_RAISE", [public.ALERT_RAISE] * len(judged)),
    ):
        days: set[str] = set()
        at = 0
        for te, t in zip(judged, ts, strict=True):
            days |= alert_days(d, te, poor[at : at + len(te)], t, t / 2)
            at += len(te)
        print(
            f"    alerts, {label} ({', '.join(f'{t:.2f}' for t in ts)}): on "
            f"{len(days & bad)} of {len(bad)} days with ≥ 2 station hours above 25 µg/m³, "
            f"on {len(days & clean)} of {len(clean)} days whose maximum is ≤ 20"
        )


def ridge() -> object:
    return make_pipeline(StandardScaler(), RidgeCV(alphas=np.logspace(-2, 3, 30)))


def within_place(
    model: object,
    f_tr: np.ndarray,
    lv_tr: np.ndarray,
    place_tr: np.ndarray,
    f_te: np.ndarray,
    place_te: np.ndarray,
) -> np.ndarray:
    """``model`` fitted to the variation within places: each training photo's features and
    level less the mean of its place's training photos; the test photos' predicted deviations
    from their place's level (NaN for a place the training folds lack)."""
    f_tr, lv_tr, f_te = f_tr.copy(), lv_tr.astype(np.float64), f_te.copy()
    for place in set(place_tr):
        here_tr, here_te = place_tr == place, place_te == place
        centre = f_tr[here_tr].mean(axis=0)
        f_tr[here_tr] -= centre
        f_te[here_te] -= centre
        lv_tr[here_tr] -= lv_tr[here_tr].mean()
    model.fit(f_tr, lv_tr)  # type: ignore[attr-defined]
    known = np.isin(place_te, place_tr)
    return np.where(known, model.predict(f_te), np.nan)  # type: ignore[attr-defined]


def deviations(values: np.ndarray, place: np.ndarray) -> np.ndarray:
    """Each value less the mean of its place's."""
    out = values.astype(np.float64)
    for p in set(place):
        out[place == p] -= out[place == p].mean()
    return out


def t2_predict(modes_tr: np.ndarray, lv_tr: np.ndarray, modes_te: np.ndarray) -> np.ndarray:
    try:
        cal = airquality.level_clusters(
            modes_tr, lv_tr, significance=0.05, shrinkage=hotelling.QUANTISATION_VARIANCE
        )
    except hotelling.BaselineError:
        return np.full(len(modes_te), np.nan)
    out = []
    for m in modes_te:
        g = airquality.grade(cal, m)
        out.append(np.nan if g.level is None else g.level)
    return np.array(out, dtype=np.float64)


def location_mean(place_tr: np.ndarray, lv_tr: np.ndarray, place_te: np.ndarray) -> np.ndarray:
    """Each test photo's level as the mean level of the training photos of its place (the
    mean of all training photos for a place the training folds lack)."""
    means = {p: float(lv_tr[place_tr == p].mean()) for p in set(place_tr)}
    overall = float(lv_tr.mean())
    return np.array([means.get(p, overall) for p in place_te], dtype=np.float64)


def report(
    name: str, pred: np.ndarray, truth_level: np.ndarray, measured: np.ndarray, label: str
) -> None:
    ok = np.isfinite(pred)
    rho = spearmanr(pred[ok], measured[ok])[0] if ok.sum() > 2 else float("nan")
    acc = within_one(pred[ok], truth_level[ok]) if ok.any() else float("nan")
    print(
        f"  {name:22s} ρ(level, {label}) = {rho:+.3f}   within one category {acc:.2f}   "
        f"coverage {ok.mean():.2f}"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=ROOT.parent / "shared" / "data" / "sky")
    parser.add_argument(
        "--folds", type=int, default=4, help="outer folds grouped by day (Milan): judged days"
    )
    parser.add_argument("--milan-only", action="store_true")
    args = parser.parse_args()
    if args.milan_only:
        milan(args.data / "milan_series", args.folds)
        return

    root = args.data / "india_nepal"
    with open(root / "labels.csv") as f:
        rows = list(csv.DictReader(f))
    modes, feats = zip(
        *(
            features(
                decode_rgb((root / r["file"]).read_bytes(), max_pixels=10**8)[1],
                (0.0, 0.4),
                (0.4, 0.6),
            )
            for r in rows
        ),
        strict=True,
    )
    modes_a, feats_a = np.array(modes), np.array(feats)
    level = np.array([LEVELS[r["AQI_Class"]] for r in rows])
    aqi = np.array([float(r["AQI"]) for r in rows])
    groups = np.array([r["capture_session_from_filename"] for r in rows])
    location = np.array([r["location_code_from_filename"] for r in rows])
    t2 = np.full(len(rows), np.nan)
    reg = np.full(len(rows), np.nan)
    place_only = np.full(len(rows), np.nan)
    inside = {"ridge": np.full(len(rows), np.nan), "random forest": np.full(len(rows), np.nan)}
    held: list[bool] = []
    for tr, te in GroupKFold(5).split(feats_a, level, groups):
        t2[te] = t2_predict(modes_a[tr], level[tr], modes_a[te])
        reg[te] = service_regression(feats_a[tr], level[tr], feats_a[te])
        place_only[te] = location_mean(location[tr], level[tr], location[te])
        # the interval of a regression fitted in the AQI with sessions as its days: a check,
        # on photos no choice of the public reading used, of its 80 % range
        model_aqi, _ = airquality.fit_regression(
            feats_a[tr], aqi[tr], unit="aqi", groups=groups[tr].tolist()
        )
        for i in te:
            e = model_aqi.estimate(feats_a[i])
            if e.low is not None and e.high is not None and not e.outside:
                held.append(e.low <= aqi[i] <= e.high)
        for name, model in (
            ("ridge", ridge()),
            ("random forest", RandomForestRegressor(300, min_samples_leaf=3, random_state=0)),
        ):
            inside[name][te] = within_place(
                model, feats_a[tr], level[tr], location[tr], feats_a[te], location[te]
            )
    print(
        f"India–Nepal: {len(rows)} photos, {len(set(groups))} sessions, 5 folds grouped by session"
    )
    report("modes, T² clusters", t2, level, aqi, "AQI")
    report("features, ridge", reg, level, aqi, "AQI")
    # a reference that sees no pixel: the mean level of the training photos taken in the same
    # place. What it reaches, the pooled ρ rewards without any reading of the air
    report("place only, no pixels", place_only, level, aqi, "AQI")
    print(
        f"  the regression in AQI, sessions as days: its {airquality.INTERVAL:.0%} interval "
        f"holds the measured AQI for {np.mean(held):.1%} of {len(held)} photos inside it"
    )
    # the same out-of-fold predictions, ranked within each location with ≥ 10 photos: how much
    # of the pooled ρ is the ordering of places (class is confounded with location)
    for place in sorted(set(location)):
        here = location == place
        if here.sum() >= 10:
            rho = spearmanr(reg[here], aqi[here])[0]
            print(
                f"    within {place:6s} ({here.sum()} photos, "
                f"{len(set(groups[here]))} sessions): ρ(level, AQI) = {rho:+.3f}"
            )
    # fitted to the variation within places alone: does anything in the pixels follow the air
    # once the place is known? (negative is right, as above)
    aqi_dev = deviations(aqi, location)
    for name, pred in inside.items():
        ok = np.isfinite(pred)
        # the frames of one session are near-duplicates: the p-value is that of the sessions'
        # means, the independent units
        sessions = sorted(set(groups[ok]))
        by_session = spearmanr(
            [pred[ok & (groups == g)].mean() for g in sessions],
            [aqi_dev[ok & (groups == g)].mean() for g in sessions],
        )
        print(
            f"  within places, {name:13s} ρ(level − place's, AQI − place's) = "
            f"{spearmanr(pred[ok], aqi_dev[ok])[0]:+.3f} ({ok.sum()} photos); "
            f"{by_session[0]:+.3f} over {len(sessions)} sessions, p = {by_session[1]:.2f}"
        )

    milan(args.data / "milan_series", args.folds)


if __name__ == "__main__":
    main()
