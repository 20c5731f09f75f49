"""Fleet-model evaluation on the labelled solar photos in ../shared/data/solar.

Clean (30) vs needs cleaning (dirty 30 + bird droppings 10), five stratified folds that never
put one panel in both training and test (near-duplicate photos are grouped first). For each
fold: the fleet model as the service trains it (``training.fit_fleet``) and, on the same folds,
the dissertation's mode-only T² test used as a fleet baseline (clean modes of the training
panels → F-test on each test photo). Also checks that decoding panel frames at reduced scale
(as the service does) leaves the fleet verdicts unchanged.

    python bench/fleet_eval.py [--data ../shared/data/solar] [--seed 0]
"""

from __future__ import annotations

import argparse
import csv
import json
from datetime import UTC, datetime
from pathlib import Path

import cv2
import numpy as np
from sklearn.metrics import balanced_accuracy_score
from sklearn.model_selection import StratifiedGroupKFold

from app.platform.db.models import CameraKind
from app.platform.frames import hotelling as soiling
from app.platform.frames.camera_info import CameraInfo
from app.platform.frames.ingest import analyse
from app.platform.frames.jpeg import decode_rgb
from app.solar.core import fleet
from app.solar.panels import as_core_model
from app.solar.training import fit_fleet

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


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=ROOT.parent / "shared" / "data" / "solar")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--folds", type=int, default=5)
    args = parser.parse_args()

    with open(args.data / "labels.csv") as f:
        rows = list(csv.DictReader(f))
    used = [r for r in rows if r["label"] in ("clean", "dirty", "bird_drop")]
    snow = [r for r in rows if r["label"] == "snow"]
    data = [(args.data / r["file"]).read_bytes() for r in used]
    decoded = [analyse(d, camera=CAMERA, max_pixels=10**9) for d in data]
    feats = np.array([d.features for d in decoded])
    modes = np.array([d.stats.modes for d in decoded], dtype=np.float64)
    y = np.array([r["label"] != "clean" for r in used], dtype=int)
    full = [decode_rgb(d, max_pixels=10**9)[1] for d in data]
    groups = near_duplicate_groups(full)
    print(
        f"{len(used)} photos ({(y == 0).sum()} clean, {(y == 1).sum()} need cleaning), "
        f"{len(set(groups))} groups after near-duplicate grouping"
    )

    now = datetime.now(UTC)
    folds = StratifiedGroupKFold(args.folds, shuffle=True, random_state=args.seed)
    table: list[dict] = []
    for k, (tr, te) in enumerate(folds.split(feats, y, groups)):
        assert not set(groups[tr]) & set(groups[te])
        model = as_core_model(fit_fleet(feats[tr], y[tr].astype(bool), now=now))
        pred = (model.probability(feats[te]) >= model.threshold).astype(int)
        baseline = soiling.fit_baseline(modes[tr][y[tr] == 0], significance=0.05)
        t2_pred = np.array([0 if soiling.classify(baseline, m).clean else 1 for m in modes[te]])
        fr, tr2 = rates(y[te], pred), rates(y[te], t2_pred)
        table.append({"fold": k, "n_test": len(te), "fleet": fr, "t2_modes": tr2})
        print(f"fold {k}: n={len(te):2d}  {fmt('fleet', fr)}   {fmt('T² modes', tr2)}")
    summary = {
        name: {m: float(np.mean([r[name][m] for r in table])) for m in RATE_NAMES}
        for name in ("fleet", "t2_modes")
    }
    print(
        f"mean:         {fmt('fleet', summary['fleet'])}   {fmt('T² modes', summary['t2_modes'])}"
    )

    # reduced-scale decoding: the same model judges the full-size and the reduced frames alike?
    model = as_core_model(fit_fleet(feats, y.astype(bool), now=now))
    full_feats = np.array([fleet.features(im) for im in full])
    same = (model.probability(full_feats) >= 0.5) == (model.probability(feats) >= 0.5)
    reductions = sorted({d.reduction for d in decoded})
    print(
        f"reduced decoding (factors {reductions}): {same.sum()}/{len(same)} fleet verdicts equal "
        "to full-size decoding"
    )
    snow_dirty = []
    for r in snow:
        d = analyse((args.data / r["file"]).read_bytes(), camera=CAMERA, max_pixels=10**9)
        snow_dirty.append(bool(model.probability(d.features) >= 0.5) if d.quality is None else None)
    print(f"snow (not a cleaning-robot job, not scored): judged dirty {snow_dirty}")
    print(
        json.dumps(
            {"folds": table, "mean": summary, "reduced_equal": int(same.sum()), "n": len(same)}
        )
    )


if __name__ == "__main__":
    main()
