"""Solar cases: synthetic panels and their photos, baselines, the fleet model, a farm's
panels and tasks."""

from __future__ import annotations

from datetime import datetime, timedelta
from typing import Any

import cv2
import numpy as np
from fastapi.testclient import TestClient

from app.solar.core.fleet import ALL_FEATURES, KernelModel
from tests.factories import bearer


def panel(seed: int = 0) -> np.ndarray:
    """A synthetic daylight panel: blue cells, grey frame lines, noise."""
    rng = np.random.default_rng(seed)
    image = np.empty((120, 160, 3), np.float64)
    image[:] = (56, 60, 84)
    image[::20, :] = (170, 170, 175)
    image[:, ::20] = (170, 170, 175)
    image += rng.normal(0, 8, image.shape)
    return np.clip(image, 0, 255).astype(np.uint8)


def panel_jpeg(
    rgb: np.ndarray,
    *,
    seed: int = 0,
    size: tuple[int, int] = (160, 120),
    gain: float = 1.0,
    pitch: int = 16,
    offset: int = 0,
) -> bytes:
    """A panel photo whose cells have colour ``rgb``: grid lines every ``pitch`` px from
    ``offset``, mild noise, JPEG q95; ``gain`` scales the whole scene (0.1: dusk)."""
    w, h = size
    rng = np.random.default_rng(seed)
    image = np.empty((h, w, 3), np.float64)
    image[:] = rgb
    image[offset::pitch, :] = (175, 175, 180)
    image[:, offset::pitch] = (175, 175, 180)
    image += rng.normal(0, 5, image.shape)
    image *= gain
    bgr = np.clip(image, 0, 255).astype(np.uint8)[:, :, ::-1]
    ok, buf = cv2.imencode(".jpg", np.ascontiguousarray(bgr), [cv2.IMWRITE_JPEG_QUALITY, 95])
    assert ok
    return buf.tobytes()


def clean_set(n: int, seed: int = 0) -> list[bytes]:
    """n clean photos whose cell colour wanders a little in every channel."""
    rng = np.random.default_rng(seed)
    return [panel_jpeg(CLEAN_RGB + rng.normal(0, 2.0, 3).round(), seed=i) for i in range(n)]


CLEAN_RGB = np.array([56.0, 60.0, 84.0])  # the dissertation's clean panel modes (Figure 5.3a)


DUST = np.array([24.0, 22.0, 21.0])  # its dusty panel is ~ (79, 82, 105)


Facts = tuple[bool, int, bool | None, bool, str]
"""A panel's stored facts: has a baseline, dirty streak, last verdict clean, last cleaning
ineffective, its open task (none, pending, claimed, lease_expired, completed)."""


TASK_FACTS = ("none", "pending", "claimed", "lease_expired", "completed")


def store_farm(engine: Any, now: datetime, facts: list[Facts], *, fleet: bool) -> list[str]:
    """Panels ``p000000``… with these facts written straight to the tables (a baseline row for
    each that has one, an open task for each that has one, held by robot ``r1`` once claimed),
    and a fleet model when ``fleet``; their ids."""
    from sqlalchemy import bindparam, insert

    from app.solar.models import Baseline, CleaningTask, FleetModel, Panel, Robot

    ids = [f"p{k:06d}" for k in range(len(facts))]
    panels, baselines, tasks = [], [], []
    for pid, (has_baseline, streak, last_clean, ineffective, task) in zip(ids, facts, strict=True):
        panels.append(
            {
                "id": pid,
                "created_at": now,
                "baseline_id": f"b-{pid}" if has_baseline else None,
                "dirty_streak": streak,
                "last_clean": last_clean,
                "ineffective": ineffective,
            }
        )
        if has_baseline:
            baselines.append(
                {
                    "id": f"b-{pid}",
                    "panel_id": pid,
                    "created_at": now,
                    "n": 8,
                    "mean_modes": [56.0, 60.0, 84.0],
                    "covariance": np.eye(3).tolist(),
                    "significance": 0.05,
                    "f_critical": 9.0,
                    "condition_number": 1.0,
                    "shrinkage": 0.0,
                }
            )
        if task != "none":
            status = "claimed" if task == "lease_expired" else task
            lease = {"claimed": 5, "lease_expired": -5}.get(task)
            tasks.append(
                {
                    "id": f"t-{pid}",
                    "panel_id": pid,
                    "open_panel_id": pid,
                    "status": status,
                    "created_at": now,
                    "robot_id": None if status == "pending" else "r1",
                    "lease_expires_at": None if lease is None else now + timedelta(minutes=lease),
                    "attempts": 0,
                }
            )
    with engine.begin() as conn:
        conn.execute(insert(Robot), [{"id": "r1", "token_hash": "x" * 64, "created_at": now}])
        # the panels first without their baselines (each refers to the other)
        conn.execute(insert(Panel), [{**p, "baseline_id": None} for p in panels])
        if baselines:
            conn.execute(insert(Baseline), baselines)
            table = Panel.__table__
            conn.execute(  # one executemany
                table.update()
                .where(table.c.id == bindparam("pid"))
                .values(baseline_id=bindparam("bid")),
                [{"pid": b["panel_id"], "bid": b["id"]} for b in baselines],
            )
        if tasks:
            conn.execute(insert(CleaningTask), tasks)
        if fleet:
            model = {
                "id": "fleet-1",
                "created_at": now,
                "feature_names": ["r"],
                "mean": [0.0],
                "scale": [1.0],
                "coef": [1.0],
                "intercept": 0.0,
                "threshold": 0.5,
                "n_clean": 10,
                "n_dirty": 10,
                "cv_balanced_accuracy": None,
            }
            conn.execute(insert(FleetModel), [model])
    return ids


def dirty_with_a_task(client: TestClient, admin: dict[str, str], farm: dict[str, Any]) -> None:
    """Train p1's baseline, then post dusty frames until the debounce opens a cleaning task."""
    train(client, admin, clean_set(10))
    for _ in range(3):
        post_frame(client, farm, CLEAN_RGB + DUST)


def post_frame(
    client: TestClient, farm: dict[str, Any], rgb: np.ndarray, seed: int = 0, gain: float = 1.0
) -> Any:
    farm["clock"].advance(minutes=10)
    r = client.post(
        "/cameras/c1/frames",
        content=panel_jpeg(rgb, seed=seed, gain=gain),
        headers={**bearer(farm["camera"]), "Content-Type": "image/jpeg"},
    )
    assert r.status_code == 201, r.text
    return r.json()["verdict"]


def train(client: TestClient, admin: dict[str, str], files: list[bytes], **params: Any) -> Any:
    return client.post(
        "/panels/p1/baseline",
        files=[("files", (f"clean{i}.jpg", f, "image/jpeg")) for i, f in enumerate(files)],
        headers=admin,
        params=params,
    )


SAND = np.array([190.0, 180.0, 160.0])


def fleet_photos() -> tuple[list[Any], list[str]]:
    """8 clean photos and 8 half covered in sand (seeded), as form parts, and their labels;
    panels of several makes and cameras: grid pitches of 13–19 px at any offset, frames of
    140–180 × 105–135 px."""
    rng = np.random.default_rng(5)
    files, labels = [], []
    for i in range(16):
        c = CLEAN_RGB + rng.normal(0, 6, 3)
        name, rgb = ("clean", c) if i % 2 == 0 else ("dust", 0.5 * c + 0.5 * SAND)
        pitch = int(rng.integers(13, 20))
        look = {"pitch": pitch, "offset": int(rng.integers(0, pitch))}
        size = (int(rng.integers(140, 181)), int(rng.integers(105, 136)))
        photo = panel_jpeg(rgb, seed=i if i % 2 == 0 else 100 + i, size=size, **look)
        files.append(("files", (f"{name[0]}{i // 2}.jpg", photo, "image/jpeg")))
        labels.append(name)
    return files, labels


def train_fleet(client: TestClient, admin: dict[str, str]) -> Any:
    """The fleet model from ``fleet_photos``."""
    files, labels = fleet_photos()
    r = client.post("/fleet/model", files=files, data={"labels": labels}, headers=admin)
    assert r.status_code == 201, r.text
    return r


def status(client: TestClient, admin: dict[str, str]) -> Any:
    """The status of the farm's panel p1 (``GET /panels/p1/status``)."""
    r = client.get("/panels/p1/status", headers=admin)
    assert r.status_code == 200, r.text
    return r.json()


def one_feature_model(**kw: object) -> KernelModel:
    """A kernel model on ALL_FEATURES whose decision is exp(−½‖z − e₀‖²) − exp(−½‖z + e₀‖²)
    (one support-vector pair, unit standardisation) through Platt's (4, 0): p = 0.5 where
    z₀ = 0, 0.915 at z = 2e₀. ``kw``: the model's other fields (heads, shape, band, …)."""
    k = len(ALL_FEATURES)
    e0 = np.eye(k)[0]
    return KernelModel(
        feature_names=ALL_FEATURES,
        mean=np.zeros(k),
        scale=np.ones(k),
        support=np.vstack([e0, -e0]),
        dual=np.array([1.0, -1.0]),
        intercept=0.0,
        gamma=0.5,
        platt=(4.0, 0.0),
        **kw,  # type: ignore[arg-type]
    )
