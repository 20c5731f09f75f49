"""Requests that wait for something other than the database (a slow upload, images decoding)
give its connection back meanwhile. With SQLite the pool is the one connection every request
shares, the uploads' writer too: a robot uploading its laser images slowly, or a calibration
decoding its photos, held every other request of the service for as long. (On PostgreSQL each
request has a connection of its own, and these pass either way.)"""

from __future__ import annotations

import asyncio
import inspect
import threading
from collections.abc import Callable, Iterator
from concurrent.futures import Future, ThreadPoolExecutor
from contextlib import contextmanager
from typing import Any

import pytest
from fastapi.testclient import TestClient

from app.cells.routers import rigs
from app.platform.frames import ingest
from tests.factories import make_jpeg
from tests.factories.air import calibrate
from tests.factories.solar import clean_set

WAIT = 20.0
"""How long a request that needs only the database may take here (it takes milliseconds)."""


@contextmanager
def paused(monkeypatch: pytest.MonkeyPatch, owner: Any, name: str) -> Iterator[threading.Event]:
    """``owner.name`` made to wait, once called, until the test has checked that the service
    answers meanwhile; yields the event set when the call is under way."""
    entered, go = threading.Event(), threading.Event()
    original: Callable[..., Any] = getattr(owner, name)

    def wait_then(*args: Any, **kwargs: Any) -> Any:
        entered.set()
        go.wait(WAIT * 2)
        return original(*args, **kwargs)

    async def await_then(*args: Any, **kwargs: Any) -> Any:
        entered.set()
        await asyncio.to_thread(go.wait, WAIT * 2)
        return await original(*args, **kwargs)

    slowed = await_then if inspect.iscoroutinefunction(original) else wait_then
    monkeypatch.setattr(owner, name, slowed)
    try:
        yield entered
    finally:
        go.set()


def answers_meanwhile(client: TestClient, admin: dict[str, str], slow: Future[Any]) -> None:
    """The registry answers while ``slow`` is under way."""
    with ThreadPoolExecutor(1) as pool:
        cameras = pool.submit(client.get, "/cameras", headers=admin).result(timeout=WAIT)
    assert cameras.status_code == 200
    assert not slow.done()


def test_a_slow_upload_to_a_rig_holds_no_other_request(
    client: TestClient, admin: dict[str, str], monkeypatch: pytest.MonkeyPatch
) -> None:
    body = {"id": "cell-1", "kind": "cross", "f_px": 800, "ax": 0.3, "ay": 0.2}
    assert client.post("/rigs", json=body, headers=admin).status_code == 201
    files = [
        ("files", (f"{i}.jpg", make_jpeg(rgb=(90 + i, 140, 200)), "image/jpeg")) for i in range(4)
    ]
    with ThreadPoolExecutor(1) as pool, paused(monkeypatch, rigs, "read_form") as reading:
        slow = pool.submit(client.post, "/rigs/cell-1/laser/dot", files=files, headers=admin)
        assert reading.wait(WAIT)
        answers_meanwhile(client, admin, slow)
    r = slow.result(timeout=WAIT)
    assert r.status_code == 422  # no laser dot in these images
    assert "dot" in r.json()["detail"]


def test_a_baseline_decoding_its_photos_holds_no_other_request(
    client: TestClient, admin: dict[str, str], monkeypatch: pytest.MonkeyPatch
) -> None:
    assert client.post("/panels", json={"id": "p1"}, headers=admin).status_code == 201
    files = [("files", (f"{i}.jpg", jpeg, "image/jpeg")) for i, jpeg in enumerate(clean_set(5))]
    with ThreadPoolExecutor(1) as pool, paused(monkeypatch, ingest, "decode_all") as decoding:
        slow = pool.submit(client.post, "/panels/p1/baseline", files=files, headers=admin)
        assert decoding.wait(WAIT)
        answers_meanwhile(client, admin, slow)
    r = slow.result(timeout=WAIT)
    assert r.status_code == 201, r.text
    assert client.get("/panels/p1/baseline", headers=admin).json()["id"] == r.json()["id"]


def test_an_air_calibration_decoding_its_photos_holds_no_other_request(
    client: TestClient, admin: dict[str, str], monkeypatch: pytest.MonkeyPatch
) -> None:
    with ThreadPoolExecutor(1) as pool, paused(monkeypatch, ingest, "decode_all") as decoding:
        slow = pool.submit(calibrate, client, admin, None)
        assert decoding.wait(WAIT)
        answers_meanwhile(client, admin, slow)
    r = slow.result(timeout=WAIT)
    assert r.status_code == 201, r.text
    assert client.get("/air/calibration", headers=admin).status_code == 200
