"""The public maps and aggregates are worked on one at a time per process
(``VANTAGE_PUBLIC_WORK_THREADS``): anyone may ask for them, with any parameters, and each may
take seconds of CPU and database. Cheap public reads, and uploads, do not wait behind them.

The heavy calls are held on an event, not slept: what must not wait for them is shown to end
while they are still held (a timeout only guards against a hang)."""

from __future__ import annotations

import threading
from concurrent.futures import ThreadPoolExecutor
from datetime import UTC, datetime
from typing import Any

import pytest
from fastapi.testclient import TestClient
from sqlalchemy import Engine

from app.air.services import maps, readings
from tests.factories import make_jpeg
from tests.factories.air import store

PATIENCE = 30.0
"""Seconds before a wait counts as a hang."""


class Gate:
    """Holds every call of the wrapped function until ``release``; counts how many are held
    at once and tells when the first has begun."""

    def __init__(self) -> None:
        self.released = threading.Event()
        self.entered = threading.Event()
        self.running = 0
        self.most = 0
        self.lock = threading.Lock()

    def wrap(self, fn: Any) -> Any:
        def held(*args: Any, **kwargs: Any) -> Any:
            with self.lock:
                self.running += 1
                self.most = max(self.most, self.running)
            try:
                out = fn(*args, **kwargs)  # its database transaction, if any, is open now
                self.entered.set()
                assert self.released.wait(PATIENCE)
                return out
            finally:
                with self.lock:
                    self.running -= 1

        return held


@pytest.mark.parametrize(
    ("path", "params"),
    [
        ("aggregate", [{"aggregate": "daily", "tz": z} for z in ("UTC", "Asia/Kolkata")] * 2),
        (  # every map begins with the cameras' readings in its window
            "stations",
            [{"resolution": r} for r in (16, 24)] + [{"method": "rbf"}, {"window": 7200}],
        ),
    ],
    ids=["aggregates", "maps"],
)
def test_one_at_a_time_and_cheap_reads_do_not_wait(
    client: TestClient,
    monkeypatch: pytest.MonkeyPatch,
    path: str,
    params: list[dict[str, Any]],
) -> None:
    assert client.get("/air/isopleths").headers["cache-control"] == "public, max-age=0"
    gate = Gate()
    service = readings if path == "aggregate" else maps
    monkeypatch.setattr(service, path, gate.wrap(getattr(service, path)))
    url = "/air/readings" if path == "aggregate" else "/air/isopleths"
    with ThreadPoolExecutor(len(params) + 1) as pool:
        heavy = [pool.submit(client.get, url, params=p) for p in params]
        assert gate.entered.wait(PATIENCE)
        cheap = pool.submit(client.get, "/air/readings", params={"limit": 10})
        assert cheap.result(timeout=PATIENCE).status_code == 200  # while the others are held
        assert gate.most == 1
        gate.released.set()
        answers = [f.result(timeout=PATIENCE) for f in heavy]
    assert [r.status_code for r in answers] == [200] * len(params), [r.text for r in answers]
    assert gate.most == 1


def test_a_long_public_read_holds_back_no_upload(
    client: TestClient, admin: dict[str, str], engine: Engine, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A city's daily means are being read: a frame posted meanwhile is stored before the read
    ends. Before, on SQLite, the read ran in the request's session, whose transaction takes
    the write lock: every upload's commit waited for the read to end."""
    cam = client.post("/cameras", json={"id": "c", "kind": "rig"}, headers=admin).json()
    store(engine, [("sky-1", datetime(2026, 5, 1, tzinfo=UTC), 5)])
    gate = Gate()
    monkeypatch.setattr(readings, "aggregate", gate.wrap(readings.aggregate))
    with ThreadPoolExecutor(2) as pool:
        reading = pool.submit(client.get, "/air/readings", params={"aggregate": "daily"})
        assert gate.entered.wait(PATIENCE)
        upload = pool.submit(
            client.post,
            "/cameras/c/frames",
            content=make_jpeg(seed=1, noise=2),
            headers={"Authorization": f"Bearer {cam['token']}", "Content-Type": "image/jpeg"},
        )
        try:
            stored = upload.result(timeout=PATIENCE)  # while the read is held
        finally:
            gate.released.set()
        assert stored.status_code == 201, stored.text
        assert reading.result(timeout=PATIENCE).json()[0]["n"] == 1
