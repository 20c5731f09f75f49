"""The public maps and aggregates are worked on one at a time per process
(``VANTAGE_PUBLIC_WORK_THREADS``): anyone may ask for them, with any parameters, and each may
take seconds of CPU and database. Cheap public reads do not wait behind them."""

from __future__ import annotations

import threading
import time
from concurrent.futures import ThreadPoolExecutor
from datetime import UTC, datetime
from typing import Any

import pytest
from fastapi.testclient import TestClient
from sqlalchemy import Engine

from app.services import air
from tests.api.test_air_trends import store
from tests.conftest import make_jpeg


class Gauge:
    """Counts the calls running at once, each held for ``seconds``."""

    def __init__(self, seconds: float) -> None:
        self.seconds = seconds
        self.running = 0
        self.most = 0
        self.lock = threading.Lock()

    def wrap(self, fn: Any) -> Any:
        def held(*args: Any, **kwargs: Any) -> Any:
            with self.lock:
                self.running += 1
                self.most = max(self.most, self.running)
            try:
                time.sleep(self.seconds)
                return fn(*args, **kwargs)
            finally:
                with self.lock:
                    self.running -= 1

        return held


@pytest.mark.parametrize(
    ("target", "path", "params"),
    [
        (air, "aggregate", [{"aggregate": "daily", "tz": z} for z in ("UTC", "Asia/Kolkata")] * 2),
        (  # every map begins with the cameras' readings in its window
            air,
            "stations",
            [{"resolution": r} for r in (16, 24)] + [{"method": "rbf"}, {"window": 7200}],
        ),
    ],
    ids=["aggregates", "maps"],
)
def test_one_at_a_time_and_cheap_reads_do_not_wait(
    client: TestClient,
    admin: dict[str, str],
    monkeypatch: pytest.MonkeyPatch,
    target: Any,
    path: str,
    params: list[dict[str, Any]],
) -> None:
    gauge = Gauge(0.3)
    monkeypatch.setattr(target, path, gauge.wrap(getattr(target, path)))
    url = "/air/readings" if path == "aggregate" else "/air/isopleths"
    assert client.get("/air/isopleths").headers["cache-control"] == "public, max-age=0"
    with ThreadPoolExecutor(len(params)) as pool:
        heavy = [pool.submit(client.get, url, params=p) for p in params]
        time.sleep(0.1)  # the first holds the work slot now
        t = time.perf_counter()
        cheap = client.get("/air/readings", params={"limit": 10})
        waited = time.perf_counter() - t
        answers = [f.result() for f in heavy]
    assert [r.status_code for r in answers] == [200] * len(params), [r.text for r in answers]
    assert cheap.status_code == 200
    assert waited < gauge.seconds  # not behind even one of them
    assert gauge.most == 1


def test_a_long_public_read_holds_back_no_upload(
    client: TestClient, admin: dict[str, str], engine: Engine, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A city's daily means read for a second: a frame posted meanwhile is stored at once.
    Before, on SQLite, the read ran in the request's session, whose transaction takes the
    write lock: every upload's commit waited for the read to end."""
    cam = client.post("/cameras", json={"id": "c", "kind": "rig"}, headers=admin).json()
    aggregate = air.aggregate

    def slow(session: Any, **kwargs: Any) -> Any:
        out = aggregate(session, **kwargs)  # its transaction is open now
        time.sleep(1.0)
        return out

    monkeypatch.setattr(air, "aggregate", slow)

    store(
        client.app.state.sessionmaker.kw["bind"], [("sky-1", datetime(2026, 5, 1, tzinfo=UTC), 5)]
    )
    with ThreadPoolExecutor(1) as pool:
        reading = pool.submit(client.get, "/air/readings", params={"aggregate": "daily"})
        time.sleep(0.3)  # the read is under way
        t = time.perf_counter()
        r = client.post(
            "/cameras/c/frames",
            content=make_jpeg(seed=1, noise=2),
            headers={"Authorization": f"Bearer {cam['token']}", "Content-Type": "image/jpeg"},
        )
        took = time.perf_counter() - t
        assert reading.result().status_code == 200
        assert reading.result().json()[0]["n"] == 1
    assert r.status_code == 201, r.text
    assert took < 0.5
