"""Anonymous crowds get nowhere: a client's requests without a token and its computations are
limited (429 with Retry-After), the public work queue is bounded (503 at once when full), and
anonymous maps are bounded and rounded so that nearby requests share the cache."""

from __future__ import annotations

import threading
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor
from typing import Any

import pytest
from fastapi.testclient import TestClient

from app.air.services import maps
from app.main import create_app
from app.platform.settings import Settings
from tests.factories import empty_tables

PATIENCE = 30.0


def limited_client(settings: Settings, engine: Any, **limits: Any) -> TestClient:
    empty_tables(engine)
    return TestClient(create_app(settings.model_copy(update=limits)), raise_server_exceptions=False)


@pytest.fixture
def five_a_minute(settings: Settings, engine: Any) -> Iterator[TestClient]:
    with limited_client(settings, engine, public_requests_per_minute=5) as c:
        yield c


def test_anonymous_requests_are_limited_per_client(
    five_a_minute: TestClient, admin: dict[str, str]
) -> None:
    got = [five_a_minute.get("/air/latest").status_code for _ in range(6)]
    assert got == [200] * 5 + [429]
    r = five_a_minute.get("/air/latest")
    assert r.headers["content-type"] == "application/problem+json"
    assert 1 <= int(r.headers["retry-after"]) <= 60
    assert r.json()["code"] == "rate_limited"
    assert five_a_minute.get("/health").status_code == 200  # probes are never limited
    # a made-up token buys nothing; a token the service accepted is not anonymous
    assert (
        five_a_minute.get("/air/latest", headers={"Authorization": "Bearer x"}).status_code == 429
    )
    assert five_a_minute.get("/cameras", headers=admin).status_code == 429  # not yet accepted
    other = TestClient(five_a_minute.app, client=("10.1.1.1", 5000))
    assert other.get("/cameras", headers=admin).status_code == 200  # another client, accepted
    assert all(other.get("/air/latest", headers=admin).status_code == 200 for _ in range(10))


def test_computations_are_limited_per_client(
    settings: Settings, engine: Any, admin: dict[str, str]
) -> None:
    with limited_client(settings, engine, public_work_per_minute=2) as c:
        got = [c.get("/air/isopleths", params={"resolution": 16}).status_code for _ in range(3)]
        assert got == [200, 200, 429]
        assert "computed maps" in c.get("/air/isopleths").json()["detail"]
        assert c.get("/cameras", headers=admin).status_code == 200  # the admin is accepted...
        assert c.get("/air/isopleths", headers=admin).status_code == 200  # ...and not limited


def test_a_full_work_queue_answers_503_at_once(
    settings: Settings, engine: Any, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Two places (one running, one waiting) taken by held maps: the third is a 503 with
    Retry-After while they are still held."""
    release, entered = threading.Event(), threading.Event()
    real = maps.stations

    def held(*args: Any, **kwargs: Any) -> Any:
        entered.set()
        assert release.wait(PATIENCE)
        return real(*args, **kwargs)

    monkeypatch.setattr(maps, "stations", held)
    with (
        limited_client(settings, engine, public_work_queue=2) as c,
        ThreadPoolExecutor(2) as pool,
    ):
        first = pool.submit(c.get, "/air/isopleths", params={"resolution": 16})
        assert entered.wait(PATIENCE)
        second = pool.submit(c.get, "/air/isopleths", params={"resolution": 32})
        while c.app.state.crowds.waiting < 2:  # the second has taken its place
            threading.Event().wait(0.01)
        try:
            third = c.get("/air/isopleths", params={"resolution": 48})
        finally:
            release.set()
        assert third.status_code == 503
        assert third.headers["retry-after"] == "2"
        assert third.json()["code"] == "busy"
        assert first.result(PATIENCE).status_code == 200
        assert second.result(PATIENCE).status_code == 200


def test_anonymous_maps_are_bounded_and_share_the_cache(
    settings: Settings, engine: Any, admin: dict[str, str]
) -> None:
    with limited_client(settings, engine, isopleth_cache_seconds=60) as c:
        r = c.get("/air/isopleths", params={"resolution": 512})
        assert r.status_code == 422
        assert "at most 256 without a token" in r.json()["detail"]
        week = c.get("/air/isopleths", params={"window": 7 * 86400})
        assert week.status_code == 422
        assert "window: at most 86400 s without a token" in week.json()["detail"]
        assert (
            c.get("/air/isopleths", params={"window": 7 * 86400}, headers=admin).status_code == 200
        )
        assert c.get("/air/isopleths", params={"resolution": 512}, headers=admin).status_code == 200
        a = c.get("/air/isopleths", params={"bbox": "9.10001,45.40002,9.29998,45.50003"})
        b = c.get("/air/isopleths", params={"bbox": "9.10004,45.40001,9.29999,45.50001"})
        assert a.status_code == b.status_code == 200
        assert a.headers["etag"] == b.headers["etag"]  # one computation for both
        assert a.json()["bbox"] == [9.1, 45.4, 9.3, 45.51]
