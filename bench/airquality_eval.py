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

from app.air.core import airquality, breakpoints
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


def smoothed(levels: np.ndarray, times: list[datetime]) -> np.ndarray:
    """The camera's public level at each frame (``airquality.nowcasts``), from the graded
    (finite) levels only, as the service smooths them."""
    ok = np.isfinite(levels)
    graded_times = [t for t, k in zip(times, ok, strict=True) if k]
    out = airquality.nowcasts(graded_times, levels[ok].tolist(), times)
    return np.array([np.nan if v is None else v for v in out])


def milan(root: Path, folds: int) -> None:
    """The fixed Milan webcam (``milan_series``) with levels by each breakpoint table."""
    for table in breakpoints.TABLES:
        milan_table(root, folds, table)


def milan_table(root: Path, folds: int, table: str) -> None:
    """The fixed Milan webcam (``milan_series``): regression fitted in PM2.5 against the
    dissertation's clusters, on folds grouped by day and on later days from earlier ones, the
    levels made from PM2.5 by the breakpoint ``table``."""
    with open(root / "labels.csv") as f:
        rows = list(csv.DictReader(f))
    modes, feats = (
        np.array(a) for a in zip(*(milan_features(root / r["file"]) for r in rows), strict=True)
    )
    pm = np.array([float(r["pm25_ugm3"]) for r in rows])
    day = np.array([r["date"] for r in rows])
    times = milan_times(rows)
    level = np.array([breakpoints.level_of_pm25(v, table) for v in pm])
    days = sorted(set(day))
    k = earlier_days(days)
    cut = days[k]
    splits = {
        f"{folds} folds grouped by day": list(GroupKFold(folds).split(feats, pm, day)),
        f"earlier {k} days → later {len(days) - k}": [
            (np.flatnonzero(day < cut), np.flatnonzero(day >= cut))
        ],
    }
    print(
        f"Milan series: {len(rows)} frames over {len(days)} days; levels from PM2.5 by the "
        f"{breakpoints.TABLES[table]} ({table}), {np.unique(level).size} levels among them, "
        f"which rank the PM2.5 itself at ρ = {spearman(level, -pm):+.3f}; ρ against −PM2.5 "
        "(a high level is clean air)"
    )
    for name, split in splits.items():
        t2 = np.full(len(rows), np.nan)
        est = np.full(len(rows), np.nan)
        lv = np.full(len(rows), np.nan)
        low = np.full(len(rows), np.nan)
        high = np.full(len(rows), np.nan)
        doubt = np.zeros(len(rows), dtype=bool)
        tested = np.zeros(len(rows), dtype=bool)
        why = [""] * len(rows)
        span: list[tuple[str, str] | None] = [None] * len(rows)
        for tr, te in split:
            tested[te] = True
            t2[te] = t2_predict(modes[tr], level[tr], modes[te])
            model, _ = airquality.fit_regression(
                feats[tr], pm[tr], unit="pm25", groups=day[tr], table=table
            )
            for i in te:
                e = model.estimate(feats[i])
                # the level a verdict gives: none outside the calibration
                lv[i] = np.nan if e.outside else e.level
                est[i], low[i], high[i] = e.value, e.low, e.high
                doubt[i] = e.uncertain is not None
                why[i] = e.uncertain or ""
                span[i] = e.span
        sel = tested
        tt = [t for t, k in zip(times, sel, strict=True) if k]
        print(f"  {name} ({sel.sum()} frames tested)")
        print(
            f"    {'clusters (modes, T²)':34s} ρ = {spearman(t2[sel], -pm[sel]):+.3f}"
            f"   graded {np.isfinite(t2[sel]).mean():.2f}"
        )
        print(
            f"    {'regression: level':34s} ρ = {spearman(lv[sel], -pm[sel]):+.3f}"
            f"   (as verdicts give it: {np.isfinite(lv[sel]).mean():.2f} of frames levelled)"
        )
        print(
            f"    {'regression: PM2.5 estimate':34s} ρ = {spearman(-est[sel], -pm[sel]):+.3f}"
            f"   (ρ of the estimate against PM2.5)"
        )
        cat = np.array([airquality.category(v) for v in level])  # the table's own categories
        said = np.array([airquality.category(v) if np.isfinite(v) else "" for v in lv])
        sure = sel & ~doubt
        outside = np.array([w.startswith("outside") for w in why])
        print(
            f"    {'regression: certain frames':34s} {sure.sum() / sel.sum():.2f} of frames; "
            f"their category right in {np.mean(said[sure] == cat[sure]):.2f} "
            f"(all frames' {np.mean(said[sel] == cat[sel]):.2f}); doubted as outside the "
            f"calibration {outside[sel].mean():.2f}, as an interval across categories "
            f"{(doubt & ~outside)[sel].mean():.2f}"
        )
        names = [name for _, name in airquality.CATEGORIES]
        spans = [(i, span[i]) for i in np.flatnonzero(sel) if span[i] is not None]
        apart = [names.index(s[1]) - names.index(s[0]) for _, s in spans]
        holds = [names.index(s[0]) <= names.index(cat[i]) <= names.index(s[1]) for i, s in spans]
        print(
            f"    {'regression: doubted, with a span':34s} {len(spans) / sel.sum():.2f} of frames;"
            f" two neighbouring categories in {np.mean(np.array(apart) == 1):.2f} of them; the"
            f" span holds the measured category in {np.mean(holds):.2f}"
        )
        print(
            f"    {'regression: smoothed level':34s} ρ = "
            f"{spearman(smoothed(lv[sel], tt), -pm[sel]):+.3f}   (NowCast of every level)"
        )
        public = smoothed(np.where(doubt, np.nan, lv)[sel], tt)
        print(
            f"    {'regression: public level':34s} ρ = {spearman(public, -pm[sel]):+.3f}"
            f"   (NowCast of the sure levels, as /latest gives it: "
            f"{np.isfinite(public).mean():.2f} of frames have one, "
            f"distinct levels: {np.unique(np.rint(public[np.isfinite(public)])).size})"
        )
        print(
            f"    {'clusters: smoothed level':34s} ρ = "
            f"{spearman(smoothed(t2[sel], tt), -pm[sel]):+.3f}"
        )
        inside = (pm[sel] >= low[sel]) & (pm[sel] <= high[sel])
        print(
            f"    {airquality.INTERVAL:.0%} prediction interval holds the measured PM2.5 "
            f"in {inside.mean():.2f} of frames; median width "
            f"{np.median(high[sel] - low[sel]):.1f} µg/m³"
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
    parser.add_argument("--folds", type=int, default=7, help="folds grouped by day (Milan)")
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
    for tr, te in GroupKFold(5).split(feats_a, level, groups):
        t2[te] = t2_predict(modes_a[tr], level[tr], modes_a[te])
        reg[te] = service_regression(feats_a[tr], level[tr], feats_a[te])
        place_only[te] = location_mean(location[tr], level[tr], location[te])
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
