"""What several test modules build their cases from: the database and its migrations,
synthetic JPEGs, clocks, receivers; each room's cases in ``tests.factories.<room>``. Tests
import from here, never from another test module."""

from __future__ import annotations

import os
import threading
from collections.abc import Iterator
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
from sqlalchemy import Engine, create_engine, inspect, make_url, text

from app.platform.db.base import Base

LEFT, RIGHT = (200, 40, 40), (40, 40, 200)

ROOT = Path(__file__).resolve().parents[2]


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


class Clock:
    def __init__(self) -> None:
        self.now = datetime(2026, 6, 1, 8, 0, tzinfo=UTC)

    def __call__(self) -> datetime:
        return self.now

    def advance(self, **kw: float) -> None:
        self.now += timedelta(**kw)


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
