"""The T² statistic of chapter 5 on the modes of the frames' own pixels (eqs. 5.12–5.22), and
baselines trained on modes of reduced images marked stale until retrained."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
from fastapi.testclient import TestClient
from scipy import stats
from sqlalchemy import Engine, create_engine, text

from tests.factories import Clock, bearer, migrate
from tests.factories.solar import train

CLEAN = np.array([56.0, 60.0, 84.0])


def textured_panel(seed: int, shift: float = 0.0) -> bytes:
    """A 640×480 panel photo with coarse cell texture (σ 18 levels): the mode of its full-size
    pixels differs from the mode of 4×4 block averages, which the texture smooths away."""
    rng = np.random.default_rng(seed)
    image = np.empty((480, 640, 3), np.float64)
    image[:] = CLEAN + shift + rng.normal(0, 2.0, 3).round()
    image += rng.normal(0, 18, image.shape)
    image[::40, :] = (175, 175, 180)
    image[:, ::40] = (175, 175, 180)
    bgr = np.clip(image, 0, 255).astype(np.uint8)[:, :, ::-1]
    return cv2.imencode(".jpg", np.ascontiguousarray(bgr), [cv2.IMWRITE_JPEG_QUALITY, 95])[
        1
    ].tobytes()


def modes_of(jpeg: bytes) -> np.ndarray:
    """Independently: the level most pixels of each channel have, ties to the lowest, on the
    full-size decode (chapter 5 §III)."""
    rgb = cv2.imdecode(np.frombuffer(jpeg, np.uint8), cv2.IMREAD_COLOR)[:, :, ::-1]
    return np.array(
        [np.argmax(np.bincount(rgb[..., c].ravel(), minlength=256)) for c in range(3)], float
    )


def reduced_modes_of(jpeg: bytes) -> np.ndarray:
    rgb = cv2.imdecode(np.frombuffer(jpeg, np.uint8), cv2.IMREAD_REDUCED_COLOR_4)[:, :, ::-1]
    return np.array(
        [np.argmax(np.bincount(rgb[..., c].ravel(), minlength=256)) for c in range(3)], float
    )


@pytest.fixture
def farm(client: TestClient, admin: dict[str, str], app: Any, clock: Clock) -> dict[str, Any]:
    assert client.post("/panels", json={"id": "p1"}, headers=admin).status_code == 201
    cam = client.post(
        "/cameras", json={"id": "c1", "kind": "panel", "panel_id": "p1"}, headers=admin
    ).json()
    return {"camera": cam["token"], "clock": clock}


def post(client: TestClient, farm: dict[str, Any], jpeg: bytes) -> Any:
    farm["clock"].advance(minutes=10)
    r = client.post(
        "/cameras/c1/frames",
        content=jpeg,
        headers={**bearer(farm["camera"]), "Content-Type": "image/jpeg"},
    )
    assert r.status_code == 201, r.text
    return r.json()


def test_the_statistic_is_of_the_full_size_modes(
    client: TestClient, admin: dict[str, str], farm: dict[str, Any]
) -> None:
    frames = [textured_panel(seed) for seed in range(7)]
    # the case at issue: block averages have another mode than the pixels
    assert any(np.abs(modes_of(f) - reduced_modes_of(f)).max() > 2 for f in frames)
    ids = [post(client, farm, f)["frame_id"] for f in frames]
    r = client.post("/panels/p1/baseline", json={"frame_ids": ids}, headers=admin)
    assert r.status_code == 201, r.text
    baseline = r.json()
    assert baseline["full_resolution"] is True
    x = np.array([modes_of(f) for f in frames])
    n = len(x)
    mean = x.mean(axis=0)  # eq. 5.12
    cov = np.cov(x, rowvar=False, ddof=1)  # eq. 5.13
    np.testing.assert_allclose(baseline["mean_modes"], mean, rtol=0, atol=1e-9)
    np.testing.assert_allclose(baseline["covariance"], cov, rtol=1e-9, atol=1e-9)
    assert baseline["f_critical"] == pytest.approx(stats.f.ppf(0.95, 3, n - 3), rel=1e-9)

    for seed, shift in ((20, 0.0), (21, 9.0)):
        new = textured_panel(seed, shift)
        verdict = post(client, farm, new)["verdict"]
        d = modes_of(new) - mean
        t2 = n / (n + 1) * d @ np.linalg.solve(cov, d)  # eq. 5.19
        f = (n - 3) / (3 * (n - 1)) * t2  # eq. 5.20
        assert verdict["modes"] == modes_of(new).tolist()
        assert verdict["t2"] == pytest.approx(t2, rel=1e-9)
        assert verdict["f_stat"] == pytest.approx(f, rel=1e-9)
        assert verdict["p_value"] == pytest.approx(stats.f.sf(f, 3, n - 3), rel=1e-9)
        assert verdict["clean"] is bool(f < stats.f.ppf(0.95, 3, n - 3))  # eqs. 5.21–5.22


def test_a_stale_baseline_judges_nothing_and_says_so(
    client: TestClient, admin: dict[str, str], farm: dict[str, Any], engine: Engine
) -> None:
    """What the migration leaves: baselines and verdicts from before full-size modes have
    full_resolution false."""
    frames = [textured_panel(seed) for seed in range(6)]
    ids = [post(client, farm, f)["frame_id"] for f in frames]
    old = client.post("/panels/p1/baseline", json={"frame_ids": ids}, headers=admin).json()
    with engine.begin() as conn:
        conn.execute(text("UPDATE baselines SET full_resolution = false"))
        conn.execute(text("UPDATE panel_verdicts SET full_resolution = false"))

    verdict = post(client, farm, textured_panel(30))["verdict"]
    assert verdict["clean"] is None
    assert "stale" in verdict["reason"]
    status = client.get("/panels/p1/status", headers=admin).json()
    assert [(w["code"], w["baseline_id"]) for w in status["warnings"]] == [
        ("baseline_stale", old["id"])
    ]
    assert client.get("/panels/p1/baseline", headers=admin).json()["full_resolution"] is False

    # the old frames' modes are of a reduced decode: no baseline from them
    r = client.post("/panels/p1/baseline", json={"frame_ids": ids}, headers=admin)
    assert r.status_code == 422
    assert r.json()["code"] == "reduced_scale_frames"
    assert r.json()["frames"] == ids

    # retrained from images: judging again, no warning
    assert train(client, admin, frames).status_code == 201
    assert client.get("/panels/p1/status", headers=admin).json()["warnings"] == []
    assert post(client, farm, textured_panel(31))["verdict"]["clean"] is not None


def test_the_migration_marks_earlier_baselines_and_verdicts_stale(tmp_path: Path) -> None:
    url = f"sqlite:///{tmp_path / 'old.db'}"
    migrate(url, "f18c5d78201c")
    engine = create_engine(url)
    t = "2026-06-01 08:00:00.000000"
    with engine.begin() as conn:
        conn.execute(
            text(
                "INSERT INTO panels (id, created_at, dirty_streak, ineffective) "
                "VALUES ('p1', :t, 0, 0)"
            ),
            {"t": t},
        )
        conn.execute(
            text(
                "INSERT INTO baselines (id, panel_id, created_at, n, mean_modes, covariance, "
                "significance, f_critical, condition_number, shrinkage) VALUES ('b1', 'p1', :t, "
                "4, '[1, 2, 3]', '[[1, 0, 0], [0, 1, 0], [0, 0, 1]]', 0.05, 9.28, 1, 0)"
            ),
            {"t": t},
        )
    migrate(url)
    with engine.connect() as conn:
        assert conn.execute(text("SELECT full_resolution FROM baselines")).scalar_one() in (
            False,
            0,
        )
    engine.dispose()
