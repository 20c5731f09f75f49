"""Fleet-model evaluation on the labelled solar photos in ../shared/data/solar.

Clean (30), dust (30), bird droppings (10) and snow (7), five stratified folds that never put one
panel in both training and test (near-duplicate photos are grouped first), repeated over seeds.
For each fold: the fleet model as the service trains it (``fleet_training.fit_fleet`` with the
photos' groups: C and γ, Platt's sigmoid, the not-sure band, the panel test and the snow floor
all chosen on the training fold only) and, on the same folds, the dissertation's mode-only T²
test used as a fleet baseline (clean modes of the training panels → F-test on each test photo).
Balanced accuracy of needs cleaning (dust, droppings) against clean on the photos that are not
snow, with the interval over the folds; the same on the answers the model is sure of; the
confusion of the four labels; snow sent to brushing.

Photos that show no panel (the sky photos of ../shared/data/sky, the parts of
../shared/data/parts, the calibration checkerboards), judged by each fold's model as a panel
camera's frames would be: how many it calls unlike its panel photos, how many it is not sure
of, how many it gives a condition; and how many held-out panel photos it calls unlike (at most
5 % by the panel test's design).

``--groups``: the feature set was settled on these photos; the study fits the service's SVM
on each candidate set, and once with the set chosen by 4 grouped folds inside each training
fold: what choosing the features on photos like these earns on panels it never saw.
``--scales``: the same for the coarse LBP scale (P neighbours, radius R px).

``--copies``: an operator's photos are often several of one panel. Each photo, mirrored and
cropped, makes three of one panel; the model trained without and with ``groups``.

    python bench/fleet_eval.py [--data ../shared/data/solar] [--seeds 5] [--groups] [--scales]
                               [--copies]
"""

from __future__ import annotations

import argparse
import csv
import json
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from sklearn.metrics import balanced_accuracy_score
from sklearn.model_selection import StratifiedGroupKFold

from app.main import register_kinds
from app.platform.db.models import CameraKind
from app.platform.frames.camera_info import CameraInfo
from app.platform.frames.ingest import analyse
from app.platform.frames.jpeg import decode_rgb
from app.solar.core import fleet
from app.solar.services.fleet_training import fit_fleet, fleet_search, fold_interval
from app.solar.services.panels import as_core_model
from app.stats import hotelling

ROOT = Path(__file__).resolve().parents[1]
CAMERA = CameraInfo(id="eval", kind=CameraKind.panel, panel_id=None, roi=None)


def near_duplicate_groups(images: list[np.ndarray], threshold: float = 0.95) -> np.ndarray:
    """Group photos whose 32×32 grey thumbnails correlate above ``threshold`` (union-find)."""
    thumbs = []
    for im in images:
        t = cv2.resize(cv2.cvtColor(im, cv2.COLOR_RGB2GRAY), (32, 32), interpolation=cv2.INTER_AREA)
        v = t.astype(np.float64).ravel()
        v -= v.mean()
        thumbs.append(v / (np.linalg.norm(v) + 1e-9))
    corr = np.array(thumbs) @ np.array(thumbs).T
    parent = list(range(len(images)))

    def find(i: int) -> int:
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    for i, j in zip(*np.nonzero(np.triu(corr, 1) > threshold), strict=True):
        parent[find(int(i))] = find(int(j))
    return np.array([find(i) for i in range(len(images))])


def rates(y_true: np.ndarray, y_pred: np.ndarray) -> dict[str, float]:
    dirty, clean = y_true == 1, y_true == 0
    return {
        "balanced_accuracy": float(balanced_accuracy_score(y_true, y_pred)),
        "dirty_called_clean": float((y_pred[dirty] == 0).mean()),
        "clean_called_dirty": float((y_pred[clean] == 1).mean()),
    }


RATE_NAMES = ("balanced_accuracy", "dirty_called_clean", "clean_called_dirty")


def fmt(name: str, r: dict[str, float]) -> str:
    return (
        f"{name} BA {r['balanced_accuracy']:.3f} (dirty→clean {r['dirty_called_clean']:.2f}, "
        f"clean→dirty {r['clean_called_dirty']:.2f})"
    )


LABELS = ("clean", "dust", "bird_drop", "snow")
SCALES = ((8, 2), (8, 3), (16, 2), (16, 3), (24, 3), (16, 4))
"""(P, R) of the uniform LBP scales the study compares."""


def chosen_inside(
    candidates: dict[str, np.ndarray],
    label: np.ndarray,
    groups: np.ndarray,
    seeds: int,
    title: tuple[str, str],
    grouped_search: bool,
) -> None:
    """Balanced accuracy of the service's SVM (decision at 0) on each candidate feature
    matrix, and with the candidate chosen by 4 grouped folds inside each training fold
    (nested), on the service's folds; printed as a table headed ``title`` (caption, column).
    ``grouped_search``: C and γ by 3 grouped inner folds, else by 5 ungrouped ones."""
    y = np.isin(label, ("dust", "bird_drop")).astype(int)
    judged = label != "snow"

    def fit_predict(x: np.ndarray, tr: np.ndarray, te: np.ndarray) -> np.ndarray:
        tr = tr[judged[tr]]
        if not grouped_search:
            return np.asarray(fleet_search(x.shape[1]).fit(x[tr], y[tr]).predict(x[te]))
        search = fleet_search(x.shape[1], grouped=True, folds=3)
        return np.asarray(search.fit(x[tr], y[tr], groups=groups[tr]).predict(x[te]))

    def inner_score(x: np.ndarray, splits: list[tuple[np.ndarray, np.ndarray]]) -> float:
        """Mean balanced accuracy over the inner folds (indices into the whole set)."""
        return float(
            np.mean(
                [
                    balanced_accuracy_score(y[b][judged[b]], fit_predict(x, a, b[judged[b]]))
                    for a, b in splits
                ]
            )
        )

    first = next(iter(candidates.values()))
    scores: dict[str, list[float]] = {name: [] for name in [*candidates, "chosen inside"]}
    picks: dict[str, int] = dict.fromkeys(candidates, 0)
    for seed in range(seeds):
        folds = StratifiedGroupKFold(5, shuffle=True, random_state=seed)
        pred = {name: np.zeros(len(y), int) for name in scores}
        for tr, te in folds.split(first, label, groups):
            for name, x in candidates.items():
                pred[name][te] = fit_predict(x, tr, te)
            inner = StratifiedGroupKFold(4, shuffle=True, random_state=seed)
            splits = [(tr[a], tr[b]) for a, b in inner.split(first[tr], label[tr], groups[tr])]
            inner_ba = {name: inner_score(x, splits) for name, x in candidates.items()}
            best = max(inner_ba, key=lambda name: inner_ba[name])
            picks[best] += 1
            pred["chosen inside"][te] = fit_predict(candidates[best], tr, te)
        for name in scores:
            scores[name].append(balanced_accuracy_score(y[judged], pred[name][judged]))
    print(f"\n{title[0]} (SVM decision at 0, the same folds)")
    print(f"| {title[1]} | balanced accuracy | chosen inside |")
    print("|---|---|---|")
    for name, ba in scores.items():
        chosen = "" if name == "chosen inside" else str(picks[name])
        print(f"| {name} | {np.mean(ba):.3f} ± {np.std(ba):.3f} | {chosen} |")


def scale_study(
    images: list[np.ndarray], feats: np.ndarray, label: np.ndarray, groups: np.ndarray, seeds: int
) -> None:
    """Each candidate coarse LBP scale in place of the service's, and the scale chosen inside
    each training fold (``chosen_inside``; C and γ by 5 ungrouped folds, as before groups)."""
    base = feats[:, [fleet.ALL_FEATURES.index(n) for n in fleet.ALL_FEATURES if "lbp24r3" not in n]]
    greys = [fleet.texture_grey(im) for im in images]
    candidates = {"none": base} | {
        f"P={p}, R={r}": np.hstack([base, [fleet.lbp_histogram(g, p, r) for g in greys]])
        for p, r in SCALES
    }
    chosen_inside(candidates, label, groups, seeds, ("coarse LBP scale", "scale"), False)


GROUPS = {
    "all features": (),
    "without the coarse LBP": ("lbp24r3_",),
    "without the structure": fleet.STRUCTURE_FEATURES,
    "without either": ("lbp24r3_", *fleet.STRUCTURE_FEATURES),
}
"""Feature sets the study compares: all, or without the groups named (name prefixes)."""


def groups_study(feats: np.ndarray, label: np.ndarray, groups: np.ndarray, seeds: int) -> None:
    """Each feature set of ``GROUPS``, and the set chosen inside each training fold
    (``chosen_inside``; C and γ by 3 grouped folds): what choosing the features on photos
    like these earns on panels the model never saw."""
    candidates = {
        name: feats[:, [i for i, n in enumerate(fleet.ALL_FEATURES) if not n.startswith(drop)]]
        if drop
        else feats
        for name, drop in GROUPS.items()
    }
    chosen_inside(candidates, label, groups, seeds, ("feature sets", "features"), True)


def copies_study(images: list[np.ndarray], label: np.ndarray, seeds: int) -> None:
    """Several photos of one panel: each photo that is not snow, mirrored and cropped to its
    middle 80 %, three photos of one panel. The model trained with and without ``groups``
    (the panels), judged on 5 folds grouped by panel: the accuracy it reports of itself, and
    how it does and how sure it is on panels it never saw."""
    now = datetime.now(UTC)
    feats, names, panels = [], [], []
    for i, (image, name) in enumerate(zip(images, label, strict=True)):
        if name == "snow":
            continue
        h, w = image.shape[:2]
        middle = image[h // 10 : h - h // 10, w // 10 : w - w // 10]
        for copy in (image, image[:, ::-1], middle):
            bgr = np.ascontiguousarray(copy[:, :, ::-1])
            ok, buf = cv2.imencode(".jpg", bgr, [cv2.IMWRITE_JPEG_QUALITY, 92])
            assert ok
            feats.append(analyse(buf.tobytes(), camera=CAMERA, max_pixels=10**9).features)
            names.append(name)
            panels.append(f"p{i}")
    x, y_names, g = np.array(feats), np.array(names), np.array(panels)
    y = np.isin(y_names, ("dust", "bird_drop"))
    print(f"\n{len(x)} photos of {len(set(panels))} panels (each photo, mirrored, middle 80 %)")
    print("| trained | reported cv BA | BA on unseen panels | Brier | mean confidence | accuracy |")
    print("|---|---|---|---|---|---|")
    for grouped in (False, True):
        groups = list(g) if grouped else None
        reported = fit_fleet(x, list(y_names), now=now, groups=groups).cv_balanced_accuracy
        ba, brier, sure, right = [], [], [], []
        for seed in range(seeds):
            p, said = np.zeros(len(y)), np.zeros(len(y), bool)
            folds = StratifiedGroupKFold(5, shuffle=True, random_state=seed)
            for tr, te in folds.split(x, y_names, g):
                fit = fit_fleet(
                    x[tr], list(y_names[tr]), now=now, groups=list(g[tr]) if grouped else None
                )
                model = as_core_model(fit)
                p[te] = model.probability(x[te])
                said[te] = p[te] >= model.threshold
            ba.append(balanced_accuracy_score(y, said))
            brier.append(np.mean((p - y) ** 2))
            sure.append(np.mean(np.maximum(p, 1 - p)))
            right.append(np.mean(said == y))
        print(
            f"| {'with groups' if grouped else 'without'} | {reported:.3f} | "
            f"{np.mean(ba):.3f} ± {np.std(ba):.3f} | {np.mean(brier):.3f} | "
            f"{np.mean(sure):.3f} | {np.mean(right):.3f} |"
        )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=ROOT.parent / "shared" / "data" / "solar")
    parser.add_argument("--seeds", type=int, default=5, help="repeats of the grouped folds")
    parser.add_argument("--folds", type=int, default=5)
    parser.add_argument("--scales", action="store_true", help="the coarse LBP scale study")
    parser.add_argument("--groups", action="store_true", help="feature sets chosen inside")
    parser.add_argument(
        "--copies", action="store_true", help="three photos a panel, with and without groups"
    )
    args = parser.parse_args()
    register_kinds()

    with open(args.data / "labels.csv") as f:
        rows = list(csv.DictReader(f))
    label = np.array(["dust" if r["label"] == "dirty" else r["label"] for r in rows])
    data = [(args.data / r["file"]).read_bytes() for r in rows]
    decoded = [analyse(d, camera=CAMERA, max_pixels=10**9) for d in data]
    feats = np.array([d.features for d in decoded])
    modes = np.array([d.stats.modes for d in decoded], dtype=np.float64)
    images = [decode_rgb(d, max_pixels=10**9)[1] for d in data]
    groups = near_duplicate_groups(images)
    judged = label != "snow"
    shared = args.data.parent
    no_panel_paths = {
        "sky and street": sorted(
            p for p in (shared / "sky").rglob("*.jpg") if p.parent.name != "milan_webcam"
        ),  # milan_webcam's frames are also in milan_series
        "objects": sorted((shared / "parts").glob("*.jpg")),
        "checkerboards": sorted((shared / "calibration").rglob("*.jpg")),
    }
    sources = np.array([name for name, ps in no_panel_paths.items() for _ in ps])
    sky = [p for ps in no_panel_paths.values() for p in ps]
    no_panel = np.array(
        [analyse(p.read_bytes(), camera=CAMERA, max_pixels=10**9).features for p in sky]
    ).reshape(len(sky), -1)
    y = np.isin(label, ("dust", "bird_drop")).astype(int)
    counts = ", ".join(f"{(label == c).sum()} {c}" for c in LABELS)
    print(f"{len(rows)} photos ({counts}), {len(set(groups))} groups after near-duplicate grouping")

    now = datetime.now(UTC)
    table: list[dict[str, Any]] = []
    # + "dirty" (linear models) and "not sure" (KernelModel.doubt)
    confusion = np.zeros((len(LABELS), len(LABELS) + 2), int)
    outcome = {name: np.zeros(3, int) for name in no_panel_paths}  # unlike, not sure, judged
    panels_unlike = [0, 0]
    intervals, reported = [], []
    for seed in range(args.seeds):
        folds = StratifiedGroupKFold(args.folds, shuffle=True, random_state=seed)
        pred, t2_pred = np.zeros(len(rows), int), np.zeros(len(rows), int)
        condition = np.empty(len(rows), object)
        doubted = np.zeros(len(rows), bool)
        fold_ba = []
        for tr, te in folds.split(feats, label, groups):
            assert not set(groups[tr]) & set(groups[te])
            fit = fit_fleet(feats[tr], list(label[tr]), now=now, groups=list(groups[tr]))
            reported.append(fit.cv_balanced_accuracy)
            model = as_core_model(fit)
            pred[te] = (model.probability(feats[te]) >= model.threshold).astype(int)
            fold_ba.append(balanced_accuracy_score(y[te][judged[te]], pred[te][judged[te]]))
            condition[te] = [model.condition(f) for f in feats[te]]
            why = [model.doubt(vec) or "" for vec in feats[te]]
            doubted[te] = [bool(reason) for reason in why]
            panels_unlike[0] += sum(reason.startswith("unlike") for reason in why)
            panels_unlike[1] += len(te)
            for source, vec in zip(sources, no_panel, strict=True):
                reason = model.doubt(vec) or ""
                outcome[source][0 if reason.startswith("unlike") else 1 if reason else 2] += 1
            clean_train = tr[label[tr] == "clean"]
            baseline = hotelling.fit_baseline(modes[clean_train], significance=0.05)
            t2_pred[te] = [0 if hotelling.classify(baseline, m).clean else 1 for m in modes[te]]
        intervals.append(fold_interval(np.array(fold_ba)))
        fr = rates(y[judged], pred[judged])
        tr2 = rates(y[judged], t2_pred[judged])
        sure = judged & ~doubted
        fs = rates(y[sure], pred[sure]) | {"answered": float(sure.sum() / judged.sum())}
        table.append({"seed": seed, "fleet": fr, "t2_modes": tr2, "fleet_sure": fs})
        print(f"seed {seed}: {fmt('fleet', fr)}   {fmt('T² modes', tr2)}")
        print(f"        {fmt('fleet, sure answers', fs)} on {fs['answered']:.0%} of photos")
        for truth, seen, unsure in zip(label, condition, doubted, strict=True):
            column = "not sure" if unsure and seen != "snow" else seen
            confusion[LABELS.index(truth), [*LABELS, "dirty", "not sure"].index(column)] += 1
    summary = {
        name: {m: float(np.mean([r[name][m] for r in table])) for m in RATE_NAMES}
        for name in ("fleet", "t2_modes")
    }
    sure_mean = {
        m: float(np.mean([r["fleet_sure"][m] for r in table])) for m in (*RATE_NAMES, "answered")
    }
    spread = float(np.std([r["fleet"]["balanced_accuracy"] for r in table]))
    sure_spread = float(np.std([r["fleet_sure"]["balanced_accuracy"] for r in table]))
    low, high = np.mean(intervals, axis=0)
    print(f"mean:   {fmt('fleet', summary['fleet'])} (± {spread:.3f} over seeds)")
    print(f"        95 % interval over a seed's {args.folds} folds (mean): {low:.3f}–{high:.3f}")
    print(
        f"        {fmt('fleet, sure answers', sure_mean)} (± {sure_spread:.3f}) on "
        f"{sure_mean['answered']:.0%} of photos"
    )
    print(f"        T² modes BA {summary['t2_modes']['balanced_accuracy']:.3f}")
    print(
        f"        what each fold's model reported of itself (its own nested "
        f"cv_balanced_accuracy): {np.mean(reported):.3f} ± {np.std(reported):.3f}"
    )
    print("\nconfusion over all seeds (rows: label; columns: what the fleet model said)")
    print("| label | " + " | ".join([*LABELS, "dirty", "not sure"]) + " |")
    print("|---" * (len(LABELS) + 3) + "|")
    for i, name in enumerate(LABELS):
        print(f"| {name} | " + " | ".join(str(v) for v in confusion[i]) + " |")
    brushed = int(confusion[LABELS.index("snow"), [1, 2, 4]].sum())
    print(f"snow photos sent to brushing (dust, bird_drop or dirty, not doubted): {brushed}")
    print("\nphotos that show no panel, judged by each fold's model")
    print("| photos | n | unlike its panels | not sure | doubted | given a condition |")
    print("|---|---|---|---|---|---|")
    for name, (u, unsure, cond) in outcome.items():
        n = u + unsure + cond
        print(
            f"| {name} | {n // (args.seeds * args.folds)} | {u / n:.1%} | {unsure / n:.1%} | "
            f"{(u + unsure) / n:.1%} | {cond / n:.1%} |"
        )
    total = sum(outcome.values())
    print(
        f"| all | {int(total.sum()) // (args.seeds * args.folds)} | {total[0] / total.sum():.1%} "
        f"| {total[1] / total.sum():.1%} | {(total[0] + total[1]) / total.sum():.1%} "
        f"| {total[2] / total.sum():.1%} |"
    )
    print(f"held-out panel photos called unlike: {panels_unlike[0] / panels_unlike[1]:.1%}")
    print(json.dumps({"seeds": table, "mean": summary, "confusion": confusion.tolist()}))
    if args.scales:
        scale_study(images, feats, label, groups, args.seeds)
    if args.groups:
        groups_study(feats, label, groups, args.seeds)
    if args.copies:
        copies_study(images, label, args.seeds)


if __name__ == "__main__":
    main()
