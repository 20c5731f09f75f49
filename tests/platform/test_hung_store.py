"""A frame store that stops answering (a network mount whose server went away blocks every call
into it, with no timeout): /health, the image endpoints and the start-up wait for it a bounded
time, and the rest of the service, which never touches it, goes on answering."""

from __future__ import annotations

import subprocess
import sys
import threading
from collections.abc import Iterator
from concurrent.futures import Future, ThreadPoolExecutor
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pytest
from fastapi.testclient import TestClient
from sqlalchemy import Engine

from app.main import create_app
from app.platform.frames.storage import FrameStore
from app.platform.settings import Settings
from tests.factories import ADMIN_TOKEN, empty_tables, make_jpeg
from tests.factories.cells import rig_camera

ADMIN = {"Authorization": f"Bearer {ADMIN_TOKEN}"}
WAIT = 20.0
"""How long a test waits for an answer that must come without the store (it comes in ms)."""


@dataclass
class Hung:
    """The service's store, whose checks and reads block while ``answering`` is clear."""

    store: FrameStore
    answering: threading.Event = field(default_factory=threading.Event)
    checks: int = 0
    reads: int = 0
    listings: int = 0

    def check(self) -> None:
        self.checks += 1
        self.answering.wait()
        self.store.check()

    def read(self, relative: str) -> bytes | None:
        self.reads += 1
        self.answering.wait()
        return self.store.read(relative)

    def older_than(self, seconds: float) -> list[str]:
        """The orphan sweep's first call."""
        self.listings += 1
        self.answering.wait()
        return self.store.older_than(seconds)

    def __getattr__(self, name: str) -> Any:  # the rest of the store, answering
        return getattr(self.store, name)


def hung_client(settings: Settings, seconds: float) -> Iterator[tuple[TestClient, Hung, str]]:
    """A client, its store made to hang once a frame is stored, and that frame's id."""
    app = create_app(settings.model_copy(update={"frame_store_timeout_seconds": seconds}))
    with TestClient(app, raise_server_exceptions=False) as client:
        r = client.post("/cameras/c/frames", content=make_jpeg(), headers=rig_camera(client, ADMIN))
        assert r.status_code == 201, r.text
        hung = Hung(app.state.frame_store)
        app.state.bounded_store.store = hung
        try:
            yield client, hung, r.json()["frame_id"]
        finally:
            hung.answering.set()  # the blocked calls end with the test


@contextmanager
def requests_at_once(store: Hung, workers: int) -> Iterator[ThreadPoolExecutor]:
    """Threads to send requests from while the store hangs. The store answers again before
    the threads are waited for, also when an assertion failed (else that wait never ends)."""
    with ThreadPoolExecutor(workers) as pool:
        try:
            yield pool
        finally:
            store.answering.set()


@pytest.fixture
def slow(settings: Settings, engine: Engine) -> Iterator[tuple[TestClient, Hung, str]]:
    """The store hung, and the service waiting for it longer than any test takes."""
    empty_tables(engine)
    yield from hung_client(settings, seconds=600)


@pytest.fixture
def hung(settings: Settings, engine: Engine) -> Iterator[tuple[TestClient, Hung, str]]:
    """The store hung, and the service waiting for it half a second."""
    empty_tables(engine)
    yield from hung_client(settings, seconds=0.5)


def test_health_probes_of_a_hung_store_wait_on_one_check(
    slow: tuple[TestClient, Hung, str],
) -> None:
    """Probes made while the store hangs all wait for the one check under way, not one each:
    each probe used to take a request thread for good, and within minutes of probes every
    one of them, so that requests that never touch the store hung too."""
    client, store, _ = slow
    with requests_at_once(store, 12) as pool:
        probes = [pool.submit(client.get, "/health") for _ in range(10)]
        # the rest of the service answers meanwhile
        cameras = pool.submit(client.get, "/cameras", headers=ADMIN).result(timeout=WAIT)
        assert cameras.status_code == 200
        assert [c["id"] for c in cameras.json()] == ["c"]
        assert client.get("/air/readings").status_code == 200
        assert not any(p.done() for p in probes)
        assert store.checks == 1
        store.answering.set()
        assert [p.result(timeout=WAIT).status_code for p in probes] == [200] * 10
    assert store.checks == 1


def test_an_image_read_from_a_hung_store_holds_no_other_request(
    slow: tuple[TestClient, Hung, str],
) -> None:
    """While an image read waits for the store, requests for the database are answered: the
    read used to keep the request's database connection, with SQLite the one every request
    shares, so the whole service waited with it."""
    client, store, frame_id = slow
    with requests_at_once(store, 4) as pool:
        image = pool.submit(client.get, f"/frames/{frame_id}/image", headers=ADMIN)
        region = pool.submit(client.get, f"/frames/{frame_id}/region.jpg", headers=ADMIN)
        cameras = pool.submit(client.get, "/cameras", headers=ADMIN).result(timeout=WAIT)
        assert cameras.status_code == 200
        frames = client.get("/cameras/c/frames", headers=ADMIN)
        assert [f["frame_id"] for f in frames.json()] == [frame_id]
        assert not image.done()
        assert not region.done()
        store.answering.set()
        assert image.result(timeout=WAIT).status_code == 200
        assert image.result().content[:2] == b"\xff\xd8"
        assert region.result(timeout=WAIT).status_code == 200


def test_a_hung_store_is_a_503_within_the_bound(hung: tuple[TestClient, Hung, str]) -> None:
    client, store, frame_id = hung
    for _ in range(3):
        r = client.get("/health")
        assert r.status_code == 503
        assert r.json()["frame_store"] == "unreachable"
        assert r.json()["database"] == "ok"
    assert store.checks == 1  # the first check still hangs: the next probes wait on it
    r = client.get(f"/frames/{frame_id}/image", headers=ADMIN)
    assert r.status_code == 503, r.text
    assert r.headers["content-type"] == "application/problem+json"
    assert r.json()["code"] == "store_unavailable"
    assert "did not answer within 0.5 s" in r.json()["detail"]
    assert r.headers["retry-after"] == "5"
    # a few calls at most hang in the store: beyond them the 503 comes at once
    with requests_at_once(store, 8) as pool:
        answers = list(
            pool.map(lambda _: client.get(f"/frames/{frame_id}/image", headers=ADMIN), range(8))
        )
    assert {a.status_code for a in answers} == {503}
    assert store.reads <= 4  # THREADS, one of them the hung check
    # the store is back (requests_at_once made it answer)
    for _ in range(100):  # the hung calls end
        if client.get("/health").status_code == 200:
            break
    assert client.get("/health").json()["frame_store"] == "ok"
    assert client.get(f"/frames/{frame_id}/image", headers=ADMIN).status_code == 200


def test_a_process_started_on_a_hung_store_serves(settings: Settings, engine: Engine) -> None:
    """The start-up sweep of orphan files waits for the store as /health does, then goes on in
    the background: a process started while the store hung never served, not even the
    endpoints that do not touch it. (Its shutdown still waits for the sweep.)"""
    empty_tables(engine)
    app = create_app(settings.model_copy(update={"frame_store_timeout_seconds": 0.5}))
    hung = Hung(app.state.frame_store)
    app.state.frame_store = hung
    app.state.bounded_store.store = hung
    answers: Future[tuple[int, int]] = Future()

    def serve() -> None:
        with TestClient(app) as client:  # entering it runs the start-up
            cameras = client.get("/cameras", headers=ADMIN).status_code
            answers.set_result((cameras, client.get("/health").status_code))

    with ThreadPoolExecutor(1) as pool:
        served = pool.submit(serve)
        try:
            assert answers.result(timeout=WAIT) == (200, 503)
            assert hung.listings == 1  # the sweep, still waiting for the store
        finally:
            hung.answering.set()
        served.result(timeout=WAIT)


STOP_SCRIPT = """
import sys, threading
from fastapi.testclient import TestClient
from app.main import create_app
from app.platform.settings import Settings
from tests.factories import make_jpeg

data_dir, database_url, token = sys.argv[1:]
settings = Settings(
    env="test", data_dir=data_dir, database_url=database_url, admin_token=token,
    rate_limit_per_minute=0, upload_timeout_seconds=1, frame_store_timeout_seconds=1,
)
app = create_app(settings)
with TestClient(app) as client:
    admin = {"Authorization": f"Bearer {token}"}
    camera = client.post("/cameras", json={"id": "c", "kind": "rig"}, headers=admin).json()
    never = threading.Event()
    app.state.frame_store.put = lambda *args: never.wait()  # the mount stops answering
    headers = {"Authorization": f"Bearer {camera['token']}", "Content-Type": "image/jpeg"}
    r = client.post("/cameras/c/frames", content=make_jpeg(), headers=headers)
    print(r.status_code, r.json().get("code"), flush=True)
print("stopped", flush=True)
"""


@pytest.mark.slow  # a separate interpreter, seconds of waiting
def test_a_process_with_an_upload_hung_in_the_store_stops(
    settings: Settings, engine: Engine, tmp_path: Path
) -> None:
    """A frame's write into a store that stopped answering (a hard NFS mount) never returns.
    The upload has its 503 at its deadline; then the process, told to stop, waited for that
    write forever (the preparing pool was shut down with wait=True, and its threads were
    joined again at the interpreter's exit), so only SIGKILL ended it. It now waits for
    preparations a bounded time, then exits (a separate interpreter, so that its exit is
    what is tested)."""
    empty_tables(engine)
    run = subprocess.run(
        [
            sys.executable,
            "-c",
            STOP_SCRIPT,
            str(tmp_path / "data"),
            settings.effective_database_url,
            ADMIN_TOKEN,
        ],
        capture_output=True,
        text=True,
        timeout=60,
        cwd=Path(__file__).parents[2],
    )
    assert run.returncode == 0, run.stderr[-2000:]
    assert run.stdout.split("\n")[:2] == ["503 upload_timeout", "stopped"], run.stdout
