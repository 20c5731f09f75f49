"""Fixtures: a database built by the real migrations, an app per test, synthetic JPEGs.

The database is SQLite in a temporary directory, or the PostgreSQL named by
``VANTAGE_TEST_DATABASE_URL`` (``.ci/run`` sets it when one is reachable). Every test starts from
empty tables.
"""

from __future__ import annotations

import os
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
from alembic import command
from alembic.config import Config
from fastapi.testclient import TestClient
from sqlalchemy import Engine, create_engine, inspect, make_url, text

from app.main import create_app, register_kinds
from app.platform.db.base import Base
from app.platform.settings import Settings

register_kinds()  # what app.main hands the ingest path, for tests that call it directly

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


@contextmanager
def postgres_database(purpose: str) -> Iterator[str]:
    """A new database beside the PostgreSQL the tests use (``VANTAGE_TEST_DATABASE_URL``),
    dropped afterwards: for a test that must not share the tests' one (its schema walked
    down, the database set read-only). Skips without that PostgreSQL."""
    test_url = os.environ.get("VANTAGE_TEST_DATABASE_URL")
    if not test_url or not test_url.startswith("postgresql"):
        pytest.skip("needs the PostgreSQL of VANTAGE_TEST_DATABASE_URL")
    server = make_url(test_url)
    name = f"vantage_{purpose}_{os.getpid()}"
    admin = create_engine(server, isolation_level="AUTOCOMMIT")
    with admin.connect() as conn:
        conn.execute(text(f"DROP DATABASE IF EXISTS {name} WITH (FORCE)"))
        conn.execute(text(f"CREATE DATABASE {name}"))
    try:
        yield server.set(database=name).render_as_string(hide_password=False)
    finally:
        with admin.connect() as conn:
            conn.execute(text(f"DROP DATABASE IF EXISTS {name} WITH (FORCE)"))
        admin.dispose()


@pytest.fixture(scope="session")
def database_url(tmp_path_factory: pytest.TempPathFactory) -> Iterator[str]:
    url = os.environ.get("VANTAGE_TEST_DATABASE_URL")
    if url:
        engine = create_engine(url)
        with engine.begin() as conn:
            conn.execute(text("DROP SCHEMA public CASCADE"))
            conn.execute(text("CREATE SCHEMA public"))
        engine.dispose()
    else:
        url = f"sqlite:///{tmp_path_factory.mktemp('db') / 'vantage.db'}"
    migrate(url)
    return url


@pytest.fixture(scope="session")
def engine(database_url: str) -> Iterator[Engine]:
    engine = create_engine(database_url)
    yield engine
    engine.dispose()


def _empty_tables(engine: Engine) -> None:
    tables = [t.name for t in reversed(Base.metadata.sorted_tables)]
    with engine.begin() as conn:
        if engine.dialect.name == "postgresql":
            conn.execute(text(f"TRUNCATE {', '.join(tables)} CASCADE"))
        else:
            for name in tables:
                conn.execute(text(f"DELETE FROM {name}"))


@pytest.fixture
def settings(tmp_path: Path, database_url: str) -> Settings:
    return Settings(
        env="test",
        data_dir=tmp_path / "data",
        database_url=database_url,
        admin_token=ADMIN_TOKEN,  # type: ignore[arg-type]
        log_json=True,
        rate_limit_per_minute=0,  # on only where a test is about it
        isopleth_cache_seconds=0,  # likewise: maps are computed afresh for each request
    )


@pytest.fixture
def app(settings: Settings, engine: Engine) -> Any:
    _empty_tables(engine)
    return create_app(settings)


@pytest.fixture
def client(app: Any) -> Iterator[TestClient]:
    with TestClient(app, raise_server_exceptions=False) as c:
        yield c


@pytest.fixture
def admin() -> dict[str, str]:
    return {"Authorization": f"Bearer {ADMIN_TOKEN}"}


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
