"""What several test modules build their cases from: the database and its migrations,
synthetic JPEGs, panels, skies, rigs and stored rows. Tests import from here, never from
another test module."""

from __future__ import annotations

import os
import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from datetime import UTC, datetime, timedelta
from http.server import BaseHTTPRequestHandler, HTTPServer
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
from alembic import command
from alembic.config import Config
from fastapi.testclient import TestClient
from sqlalchemy import Engine, create_engine, insert, inspect, make_url, select, text
from sqlalchemy.orm import Session

from app.air.models import AirAlert, SkyVerdict
from app.cells.core.triangulation import CrossRig, View
from app.platform.db.base import Base
from app.platform.db.models import Camera, CameraKind, Frame, Verdict
from tests.cells.scenes import checkerboard_photo

Reading = tuple[str, datetime, int | None]
"""A sky reading: camera, capture time, level (None: ungraded)."""

K_RENDER = np.array([[800.0, 0.0, 320.0], [0.0, 800.0, 240.0], [0.0, 0.0, 1.0]])

LEFT, RIGHT = (200, 40, 40), (40, 40, 200)

ROOT = Path(__file__).resolve().parents[1]


SHARED_DATA = ROOT.parent / "shared" / "data"


ADMIN_TOKEN = "test-admin-token-0123456789abcdef"


def alembic_config(url: str) -> Config:
    cfg = Config(str(ROOT / "alembic.ini"))
    cfg.attributes["database_url"] = url
    cfg.attributes["configure_logger"] = False
    return cfg


def migrate(url: str, revision: str = "head") -> None:
    command.upgrade(alembic_config(url), revision)


def recreate_database(url: str, name: str) -> str:
    """The URL of database ``name`` on ``url``'s PostgreSQL server, dropped if it was there and
    made anew (empty)."""
    server = make_url(url)
    _drop_database(url, name, create=True)
    return server.set(database=name).render_as_string(hide_password=False)


def _drop_database(url: str, name: str, *, create: bool = False) -> None:
    admin = create_engine(make_url(url), isolation_level="AUTOCOMMIT")
    try:
        with admin.connect() as conn:
            conn.execute(text(f"DROP DATABASE IF EXISTS {name} WITH (FORCE)"))
            if create:
                conn.execute(text(f"CREATE DATABASE {name}"))
    finally:
        admin.dispose()


@contextmanager
def postgres_database(purpose: str) -> Iterator[str]:
    """A new database beside the PostgreSQL the tests use (``VANTAGE_TEST_DATABASE_URL``),
    dropped afterwards: for a test that must not share the tests' one (its schema walked
    down, the database set read-only). Skips without that PostgreSQL."""
    test_url = os.environ.get("VANTAGE_TEST_DATABASE_URL")
    if not test_url or not test_url.startswith("postgresql"):
        pytest.skip("needs the PostgreSQL of VANTAGE_TEST_DATABASE_URL")
    name = f"vantage_{purpose}_{os.getpid()}"
    try:
        yield recreate_database(test_url, name)
    finally:
        _drop_database(test_url, name)


def empty_tables(engine: Engine) -> None:
    tables = [t.name for t in reversed(Base.metadata.sorted_tables)]
    with engine.begin() as conn:
        if engine.dialect.name == "postgresql":
            conn.execute(text(f"TRUNCATE {', '.join(tables)} CASCADE"))
        else:
            for name in tables:
                conn.execute(text(f"DELETE FROM {name}"))


def make_jpeg(
    width: int = 64,
    height: int = 48,
    rgb: tuple[int, int, int] = (90, 140, 200),
    *,
    noise: float = 0.0,
    seed: int = 0,
    quality: int = 95,
) -> bytes:
    """A JPEG of a flat colour (RGB), optionally with Gaussian noise of std ``noise``."""
    image = np.empty((height, width, 3), np.float64)
    image[:] = rgb
    if noise:
        image += np.random.default_rng(seed).normal(0.0, noise, image.shape)
    bgr = np.clip(image, 0, 255).astype(np.uint8)[:, :, ::-1]
    ok, buf = cv2.imencode(".jpg", np.ascontiguousarray(bgr), [cv2.IMWRITE_JPEG_QUALITY, quality])
    assert ok
    return buf.tobytes()


def table_counts(engine: Engine) -> dict[str, int]:
    names = inspect(engine).get_table_names()
    with engine.connect() as conn:
        return {n: conn.execute(text(f"SELECT count(*) FROM {n}")).scalar_one() for n in names}


@dataclass
class Stall:
    stuck: threading.Event = field(default_factory=threading.Event)
    """Set once the first batch is held."""
    release: threading.Event = field(default_factory=threading.Event)
    batches: list[int] = field(default_factory=list)
    """The size of every batch written meanwhile, the held one first."""


@contextmanager
def stalled_writer(writer: Any) -> Iterator[Stall]:
    """The frame writer's next batch waits, as on a database that does not commit, until
    ``release`` is set (30 s at most: never hang the suite); released and restored on exit."""
    write = writer._write

    def stalling(batch: Any, **kw: Any) -> Any:
        stall.batches.append(len(batch))
        if not stall.stuck.is_set():
            stall.stuck.set()
            stall.release.wait(30)
        return write(batch, **kw)

    stall = Stall()
    writer._write = stalling
    try:
        yield stall
    finally:
        stall.release.set()
        writer._write = write


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


def pages(
    client: TestClient, path: str, params: dict[str, Any], headers: dict[str, str] | None = None
) -> list[list[dict[str, Any]]]:
    """Every page of a listing, following its ``Link: rel=next`` headers."""
    out = []
    r = client.get(path, params=params, headers=headers)
    while True:
        assert r.status_code == 200, r.text
        out.append(r.json())
        if "link" not in r.headers:
            return out
        url, rel = r.headers["link"].split(";")
        assert rel.strip() == 'rel="next"'
        r = client.get(url.strip().strip("<>"), headers=headers)


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


T0 = datetime(2026, 6, 1, 12, tzinfo=UTC)


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


RIG = CrossRig(f=800.0, ax=0.30, ay=0.20, cx=320.0, cy=240.0)


def points(n: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return np.column_stack(
        [rng.uniform(-0.5, 0.5, n), rng.uniform(-0.4, 0.4, n), rng.uniform(1.0, 5.0, n)]
    )


def calibrated_views() -> list[View]:
    k = np.array([[800.0, 0, 320], [0, 800, 240], [0, 0, 1]])
    dist = np.array([-0.1, 0.01, 0.0, 0.0, 0.0])
    views = []
    for i in range(4):
        r = cv2.Rodrigues(np.radians([0.0, (i - 1.5) * 8, 0.0]))[0]
        centre = np.array([(i - 1.5) * 0.3, 0.05 * i, 0.0])
        views.append(View(k, dist, r, -r @ centre))
    return views


def panel(seed: int = 0) -> np.ndarray:
    """A synthetic daylight panel: blue cells, grey frame lines, noise."""
    rng = np.random.default_rng(seed)
    image = np.empty((120, 160, 3), np.float64)
    image[:] = (56, 60, 84)
    image[::20, :] = (170, 170, 175)
    image[:, ::20] = (170, 170, 175)
    image += rng.normal(0, 8, image.shape)
    return np.clip(image, 0, 255).astype(np.uint8)


def corner_error(found: np.ndarray, truth: np.ndarray) -> float:
    """Largest distance between matched corners, over the rotations of the found cycle."""
    if found.shape != truth.shape:
        return float("inf")
    return min(
        float(np.linalg.norm(np.roll(found, -k, axis=0) - truth, axis=1).max())
        for k in range(len(found))
    )


def rendered_board(width: int, height: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """A 9×6-corner board (40 px squares, a white margin) warped in perspective onto a grey
    width × height image, rendered at 4× and area-averaged down; and its 54 inner corners in
    the image [px, pixel centres at integers], exact by construction."""
    sq = 40
    board = np.kron((np.indices((7, 10)).sum(0) % 2) * 255, np.ones((sq, sq))).astype(np.uint8)
    board = cv2.copyMakeBorder(board, sq, sq, sq, sq, cv2.BORDER_CONSTANT, value=255)
    h, w = board.shape
    src = np.float32([[0, 0], [w, 0], [w, h], [0, h]])
    dst = np.float32(
        [[0.2, 0.15], [0.8, 0.2], [0.75, 0.85], [0.25, 0.8]] * np.array([width, height])
    )
    m = cv2.getPerspectiveTransform(src, dst)
    big = cv2.warpPerspective(
        board, np.diag([4.0, 4.0, 1.0]) @ m, (4 * width, 4 * height), borderValue=128
    )
    image = cv2.resize(big, (width, height), interpolation=cv2.INTER_AREA)
    image = cv2.add(image, np.random.default_rng(seed).integers(0, 6, image.shape, np.uint8))
    # an inner corner lies between board pixels: at sq·k − 0.5 in pixel-centre coordinates; a
    # 4× render area-averaged down moves pixel centres by −3/8
    corners = np.array(
        [[sq * (2 + i) - 0.5, sq * (2 + j) - 0.5] for j in range(6) for i in range(9)],
        np.float32,
    )
    truth = cv2.perspectiveTransform(corners.reshape(-1, 1, 2), m).reshape(-1, 2) - 0.375
    return image, truth


# very clean sky: R 30, G 78, B 180 (Figure 6.3a); haze moves it towards grey
CLEAN = np.array([30.0, 78.0, 180.0])


HAZE = np.array([165.0, 165.0, 170.0])


CLEAN_RGB = np.array([56.0, 60.0, 84.0])  # the dissertation's clean panel modes (Figure 5.3a)


DUST = np.array([24.0, 22.0, 21.0])  # its dusty panel is ~ (79, 82, 105)


def panel_jpeg(
    rgb: np.ndarray, *, seed: int = 0, size: tuple[int, int] = (160, 120), gain: float = 1.0
) -> bytes:
    """A panel photo whose cells have colour ``rgb``: grid lines, mild noise, JPEG q95;
    ``gain`` scales the whole scene (0.1: dusk)."""
    w, h = size
    rng = np.random.default_rng(seed)
    image = np.empty((h, w, 3), np.float64)
    image[:] = rgb
    image[::16, :] = (175, 175, 180)
    image[:, ::16] = (175, 175, 180)
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


class Clock:
    def __init__(self) -> None:
        self.now = datetime(2026, 6, 1, 8, 0, tzinfo=UTC)

    def __call__(self) -> datetime:
        return self.now

    def advance(self, **kw: float) -> None:
        self.now += timedelta(**kw)


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


def rig_camera(client: TestClient, admin: dict[str, str]) -> dict[str, str]:
    cam = client.post("/cameras", json={"id": "c", "kind": "rig"}, headers=admin).json()
    return {"Authorization": f"Bearer {cam['token']}", "Content-Type": "image/jpeg"}


def halves() -> bytes:
    """A 64×48 JPEG: the left half LEFT, the right half RIGHT (RGB)."""
    image = np.empty((48, 64, 3), np.uint8)
    image[:, :32] = LEFT
    image[:, 32:] = RIGHT
    ok, buf = cv2.imencode(".jpg", image[:, :, ::-1].copy(), [cv2.IMWRITE_JPEG_QUALITY, 95])
    assert ok
    return buf.tobytes()


def near(rgb: list[int], expected: tuple[int, int, int]) -> bool:
    return all(abs(a - b) <= 6 for a, b in zip(rgb, expected, strict=True))  # JPEG: ±6 levels


def bearer(token: str) -> dict[str, str]:
    return {"Authorization": f"Bearer {token}"}


def dirty_with_a_task(client: TestClient, admin: dict[str, str], farm: dict[str, Any]) -> None:
    """Train p1's baseline, then post dusty frames until the debounce opens a cleaning task."""
    train(client, admin, clean_set(10))
    for _ in range(3):
        post_frame(client, farm, CLEAN_RGB + DUST)


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


def rendered_views(
    n: int,
    *,
    size: tuple[int, int] = (640, 480),
    k: np.ndarray = K_RENDER,
    seed: int = 0,
    noise_seed: int | None = None,
    quality: int = 95,
) -> list[bytes]:
    """JPEGs of the 9 × 6 board at n poses drawn from ``seed`` through a known camera
    (tests/core/scenes), with sensor noise drawn from ``noise_seed`` (default: ``seed``)."""
    rng = np.random.default_rng(seed)
    noise = seed if noise_seed is None else noise_seed
    out = []
    centre = np.array([100.0, 62.5, 0.0])  # of the 9 × 6 board of 25 mm squares
    for i in range(n):
        rvec = rng.normal(0, 0.3, 3)
        r = cv2.Rodrigues(rvec)[0]
        # turned about its centre, 60 cm ahead, ±3 cm aside: the whole board in the frame
        tvec = -r @ centre + np.array([0.0, 0.0, 600.0]) + rng.normal(0, [30, 30, 60])
        image = checkerboard_photo(k, rvec, tvec, size, seed=noise + i)
        out.append(cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, quality])[1].tobytes())
    return out


def upload(
    client: TestClient, admin: dict[str, str], images: list[tuple[str, bytes]]
) -> tuple[int, dict[str, Any]]:
    r = client.post(
        "/calibrations",
        files=[("files", (name, data, "image/jpeg")) for name, data in images],
        data={"pattern_cols": "9", "pattern_rows": "6", "square_size": "25"},
        headers=admin,
    )
    return r.status_code, r.json()


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


def recorder(
    *answers: int,
) -> tuple[type[BaseHTTPRequestHandler], list[tuple[bytes, dict[str, str]]]]:
    """A receiver keeping each POST's body and headers (names lower-cased), answering them
    ``answers`` in turn (then 204), and the list it keeps them in."""
    got: list[tuple[bytes, dict[str, str]]] = []

    class Receiver(BaseHTTPRequestHandler):
        def do_POST(self) -> None:  # noqa: N802
            body = self.rfile.read(int(self.headers["Content-Length"]))
            got.append((body, {k.lower(): v for k, v in self.headers.items()}))
            self.send_response(answers[len(got) - 1] if len(got) <= len(answers) else 204)
            self.end_headers()

        def log_message(self, *args: Any) -> None:
            pass

    return Receiver, got


@contextmanager
def served(handler: type[BaseHTTPRequestHandler]) -> Iterator[str]:
    """``handler`` serving on a local port for the block: its base URL."""
    server = HTTPServer(("127.0.0.1", 0), handler)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    try:
        yield f"http://127.0.0.1:{server.server_port}"
    finally:
        server.shutdown()
        server.server_close()


def tiff_bomb(first: tuple[int, int] = (16000, 16000), last: tuple[int, int] = (10, 10)) -> bytes:
    """A small deflate TIFF whose directory gives ImageWidth/ImageLength twice: ``first``
    (what libtiff decodes by) and ``last`` (what a reader taking the last copy sees). Every
    row's strip points at the same few compressed bytes, so 16000×16000 takes ~128 KB."""
    import struct
    import zlib

    w, h = first
    strip = zlib.compress(bytes(w), 9)
    entries = [
        (256, 4, 1, w),
        (257, 4, 1, h),
        (258, 3, 1, 8),  # BitsPerSample
        (259, 3, 1, 8),  # Compression: Adobe deflate
        (262, 3, 1, 1),  # PhotometricInterpretation: black is zero
        (273, 4, h, 0),  # StripOffsets, one per row
        (277, 3, 1, 1),  # SamplesPerPixel
        (278, 4, 1, 1),  # RowsPerStrip
        (279, 4, h, 0),  # StripByteCounts
        (256, 4, 1, last[0]),
        (257, 4, 1, last[1]),
    ]
    offsets_at = 8 + 2 + 12 * len(entries) + 4
    counts_at = offsets_at + 4 * h
    strip_at = counts_at + 4 * h
    out = bytearray(b"II*\x00" + struct.pack("<IH", 8, len(entries)))
    for tag, kind, count, value in entries:
        value = {273: offsets_at, 279: counts_at}.get(tag, value)
        fmt = "<HHIHH" if kind == 3 else "<HHII"
        out += struct.pack(fmt, tag, kind, count, value, *([0] if kind == 3 else []))
    out += struct.pack("<I", 0)
    out += struct.pack(f"<{h}I", *([strip_at] * h))
    out += struct.pack(f"<{h}I", *([len(strip)] * h))
    return bytes(out + strip)


SAND = np.array([190.0, 180.0, 160.0])


def fleet_photos() -> tuple[list[Any], list[str]]:
    """8 clean photos and 8 half covered in sand (seeded), as form parts, and their labels."""
    rng = np.random.default_rng(5)
    files, labels = [], []
    for i in range(8):
        c = CLEAN_RGB + rng.normal(0, 6, 3)
        d = 0.5 * c + 0.5 * SAND
        files.append(("files", (f"c{i}.jpg", panel_jpeg(c, seed=i), "image/jpeg")))
        files.append(("files", (f"d{i}.jpg", panel_jpeg(d, seed=100 + i), "image/jpeg")))
        labels += ["clean", "dust"]
    return files, labels


def train_fleet(client: TestClient, admin: dict[str, str]) -> Any:
    """The fleet model from ``fleet_photos``."""
    files, labels = fleet_photos()
    r = client.post("/fleet/model", files=files, data={"labels": labels}, headers=admin)
    assert r.status_code == 201, r.text
    return r
