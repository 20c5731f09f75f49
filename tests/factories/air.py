"""Sky cameras' cases: synthetic skies, calibrations, readings and alerts written straight
to the tables."""

from __future__ import annotations

from collections.abc import Callable
from datetime import UTC, datetime, timedelta
from typing import Any

import cv2
import numpy as np
from fastapi.testclient import TestClient
from sqlalchemy import Engine, insert, select
from sqlalchemy.orm import Session

from app.air.models import AirAlert, SkyVerdict
from app.platform.db.models import Camera, CameraKind, Frame, Verdict
from tests.factories import empty_tables

Reading = tuple[str, datetime, int | None]
"""A sky reading: camera, capture time, level (None: ungraded)."""


def store(engine: Engine, readings: list[Reading], *, start: int = 0) -> None:
    """Sky readings written straight to the tables (the grading path has its own tests), as
    frames ``f{start:07d}`` on; cameras not there yet are registered."""
    with engine.connect() as conn:
        known = set(conn.execute(select(Camera.id)).scalars())
    cameras = sorted({cam for cam, _, _ in readings} - known)
    frames, verdicts, skies = [], [], []
    for k, (cam, at, level) in enumerate(readings, start):
        fid = f"f{k:07d}"
        frames.append(
            {
                "id": fid, "camera_id": cam, "captured_at": at, "received_at": at, "width": 1,
                "height": 1, "size_bytes": 1, "sha256": f"{k:064x}",
            }
        )  # fmt: skip
        verdicts.append(
            {
                "frame_id": fid, "kind": CameraKind.sky, "camera_id": cam, "mode_r": 0,
                "mode_g": 0, "mode_b": 0, "mean_r": 0.0, "mean_g": 0.0, "mean_b": 0.0,
            }
        )  # fmt: skip
        skies.append({"frame_id": fid, "level": level})
    with engine.begin() as conn:
        if cameras:
            conn.execute(
                insert(Camera),
                [{"id": c, "kind": CameraKind.sky, "token_hash": f"h-{c}"} for c in cameras],
            )
        for table, rows in ((Frame, frames), (Verdict, verdicts), (SkyVerdict, skies)):
            for start in range(0, len(rows), 20_000):
                conn.execute(insert(table.__table__), rows[start : start + 20_000])


T0 = datetime(2026, 6, 1, 12, tzinfo=UTC)


def sky_jpeg(level: float, seed: int = 0) -> bytes:
    """Sky of the level's colour in the top 60 %, a dark street below (outside the ROI)."""
    t = (10 - level) / 9
    rng = np.random.default_rng(seed)
    rgb = (1 - t) * CLEAN + t * HAZE + rng.normal(0, 2.0, 3)
    image = np.empty((100, 160, 3))
    image[:60] = rgb
    image[60:] = (40, 40, 45)
    image += rng.normal(0, 4, image.shape)
    bgr = np.clip(image, 0, 255).astype(np.uint8)[:, :, ::-1]
    ok, buf = cv2.imencode(".jpg", np.ascontiguousarray(bgr), [cv2.IMWRITE_JPEG_QUALITY, 95])
    assert ok
    return buf.tobytes()


def calibrate(
    client: TestClient,
    admin: dict[str, str],
    camera: str | None = "sky0",
    *,
    label: Any = None,
    applies_to: list[str] | None = None,
    method: str = "clusters",
    image: Callable[[int, int], bytes] | None = None,
) -> Any:
    """Calibrate from synthetic skies of levels 1, 3, 5, 7 and 10 (eight each, the k-th of a
    level ``image(level, k)``), each labelled ``label(level)`` (the level itself by default)."""
    files, levels = [], []
    for level in (1, 3, 5, 7, 10):
        for k in range(8):
            jpeg = image(level, k) if image else sky_jpeg(level, seed=100 * level + k)
            files.append(("files", (f"{level}-{k}.jpg", jpeg, "image/jpeg")))
            levels.append(str(label(level) if label else level))
    params: dict[str, Any] = {"significance": 0.01, "method": method}
    if camera is not None:
        params["camera_id"] = camera
    if applies_to is not None:
        params["applies_to"] = applies_to
    return client.post(
        "/air/calibration", files=files, data={"levels": levels}, headers=admin, params=params
    )


def seed_alerts(engine: Engine, n: int, taken: datetime = T0) -> None:
    """``n`` undelivered alerts of a camera's frame taken at ``taken``, a second apart."""
    empty_tables(engine)
    with Session(engine) as s:
        s.add(Camera(id="sky", kind=CameraKind.sky, token_hash="h"))
        s.add(
            Frame(
                id="f", camera_id="sky", captured_at=taken, received_at=taken, width=1, height=1,
                size_bytes=1, sha256="0" * 64,
            )
        )  # fmt: skip
        s.flush()
        for k in range(n):
            s.add(
                AirAlert(
                    id=f"a{k}", camera_id="sky", frame_id="f",
                    created_at=taken + timedelta(seconds=k), smoothed_level=2.0, category="Poor",
                )
            )  # fmt: skip
        s.commit()


# very clean sky: R 30, G 78, B 180 (Figure 6.3a); haze moves it towards grey
CLEAN = np.array([30.0, 78.0, 180.0])


HAZE = np.array([165.0, 165.0, 170.0])


def post(client: TestClient, city: dict[str, Any], camera: str, level: float, seed: int) -> Any:
    return post_bytes(client, city, camera, sky_jpeg(level, seed))


def post_bytes(client: TestClient, city: dict[str, Any], camera: str, jpeg: bytes) -> Any:
    token = city["tokens"][camera][0]
    r = client.post(
        f"/cameras/{camera}/frames",
        content=jpeg,
        headers={"Authorization": f"Bearer {token}", "Content-Type": "image/jpeg"},
    )
    assert r.status_code == 201, r.text
    return r.json()["verdict"]
