"""Fixtures: a database built by the real migrations, an app per test, synthetic JPEGs.

The database is SQLite in a temporary directory, or the PostgreSQL named by
``VANTAGE_TEST_DATABASE_URL`` (``.ci/run`` sets it when one is reachable). Every test starts from
empty tables.
"""

from __future__ import annotations

import os
import threading
import time
from collections.abc import Iterator
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import uvicorn
from fastapi.testclient import TestClient
from sqlalchemy import Engine, create_engine, make_url, text

from app.main import create_app, register_kinds
from app.platform.settings import Settings
from tests.factories import ADMIN_TOKEN, Clock, empty_tables, migrate, recreate_database

register_kinds()  # what app.main hands the ingest path, for tests that call it directly


@pytest.fixture(scope="session")
def database_url(tmp_path_factory: pytest.TempPathFactory) -> Iterator[str]:
    url = os.environ.get("VANTAGE_TEST_DATABASE_URL")
    worker = os.environ.get("PYTEST_XDIST_WORKER")
    if url and worker:  # each of pytest-xdist's workers empties tables of a database its own
        url = recreate_database(url, f"{make_url(url).database}_{worker}")
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
        public_requests_per_minute=0,  # the anonymous limits too
        public_work_per_minute=0,
        source_allowed_networks=["127.0.0.0/8"],  # the cameras these tests serve are local
    )


@pytest.fixture
def app(settings: Settings, engine: Engine) -> Any:
    empty_tables(engine)
    return create_app(settings)


@pytest.fixture
def client(app: Any) -> Iterator[TestClient]:
    with TestClient(app, raise_server_exceptions=False) as c:
        yield c


@pytest.fixture
def admin() -> dict[str, str]:
    return {"Authorization": f"Bearer {ADMIN_TOKEN}"}


@pytest.fixture
def clock(app: Any) -> Clock:
    """The app's clock, moved by the test (``Clock.advance``)."""
    c = Clock()
    app.state.timing = replace(app.state.timing, clock=c)
    return c


@pytest.fixture
def city(client: TestClient, admin: dict[str, str], clock: Clock) -> dict[str, Any]:
    tokens = {}
    rng = np.random.default_rng(1)
    for i in range(12):
        body = {
            "id": f"sky{i}",
            "kind": "sky",
            "lat": 45.40 + 0.1 * rng.random(),
            "lon": 9.10 + 0.2 * rng.random(),
            "roi": [0, 0, 160, 55],
        }
        r = client.post("/cameras", json=body, headers=admin)
        assert r.status_code == 201, r.text
        tokens[body["id"]] = (r.json()["token"], body["lon"])
    return {"tokens": tokens, "clock": clock}


@pytest.fixture
def live(app: Any) -> Iterator[str]:
    """The app served by uvicorn on a free port of 127.0.0.1 (its lifespan run); its URL."""
    server = uvicorn.Server(
        uvicorn.Config(app, host="127.0.0.1", port=0, log_level="warning", lifespan="on")
    )
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    deadline = time.monotonic() + 30
    while not server.started:
        assert time.monotonic() < deadline, "uvicorn did not start"
        time.sleep(0.05)
    port = server.servers[0].sockets[0].getsockname()[1]
    yield f"http://127.0.0.1:{port}"
    server.should_exit = True
    thread.join(timeout=10)
