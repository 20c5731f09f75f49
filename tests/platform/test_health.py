"""Health, request ids, metrics, and problem+json for routing errors."""

from __future__ import annotations

import gc
import json
import shutil
import threading
import uuid
from typing import Any

import pytest
from fastapi.testclient import TestClient
from pydantic import SecretStr

from app import __version__
from app.main import create_app
from app.platform import health as health_router
from app.platform.settings import Settings
from tests.factories import make_jpeg


def test_health_reports_database_and_version(client: TestClient) -> None:
    r = client.get("/health")
    assert r.status_code == 200
    assert r.json() == {
        "status": "ok",
        "database": "ok",
        "frame_store": "ok",
        "version": __version__,
    }


def test_the_database_and_the_store_are_checked_at_once(
    client: TestClient, app: Any, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Each check waits for the other to have begun (a barrier of two): checked one after the
    other, as they were, the first waits out the barrier's timeout and fails. (With both on
    one hung mount a probe had waited for the sum of their bounds.)"""
    both = threading.Barrier(2, timeout=5)
    state = health_router._database_state

    def database(request: Any) -> Any:
        both.wait()
        return state(request)

    store = app.state.bounded_store.store
    check = store.check

    def store_check() -> None:
        both.wait()
        check()

    monkeypatch.setattr(health_router, "_database_state", database)
    monkeypatch.setattr(store, "check", store_check)
    r = client.get("/health")
    assert r.status_code == 200, r.text
    assert (r.json()["database"], r.json()["frame_store"]) == ("ok", "ok")


@pytest.mark.parametrize("path", ["/health", "/air/latest", "/openapi.json", "/cameras"])
def test_head_is_answered_wherever_get_is(
    client: TestClient, admin: dict[str, str], path: str
) -> None:
    """Load balancers and uptime checks probe with HEAD (RFC 9110 §9.3.2): GET's status and
    headers, no body."""
    got = client.get(path, headers=admin)
    head = client.head(path, headers=admin)
    assert head.status_code == got.status_code == 200
    assert head.content == b""
    assert head.headers["content-type"] == got.headers["content-type"]
    assert head.headers["content-length"] == got.headers["content-length"]  # as sent (gzip)


def test_head_keeps_the_errors_of_get(client: TestClient) -> None:
    assert client.head("/cameras").status_code == 401  # no token, as for GET
    missing = client.head("/cameras/c1/frames", headers={"Authorization": "Bearer x"})
    assert missing.status_code == 401
    assert missing.content == b""
    assert client.head("/panel-nope").status_code == 404
    # a route without GET has no HEAD either
    assert client.head("/cleaning/claim").status_code == 405


@pytest.mark.parametrize(
    ("method", "path", "allow"),
    [
        ("DELETE", "/cameras", "GET, HEAD, POST"),
        ("POST", "/rigs/r1", "DELETE, GET, HEAD, PUT"),
        ("PUT", "/health", "GET, HEAD"),
        ("GET", "/cleaning/claim", "POST"),
        ("HEAD", "/cleaning/claim", "POST"),
    ],
)
def test_405_allows_every_method_of_the_path(
    client: TestClient, method: str, path: str, allow: str
) -> None:
    """RFC 9110 §15.5.6: a 405 lists the resource's supported methods, all of them (Starlette
    named only the first route's: ``DELETE /cameras`` was told ``Allow: POST``)."""
    r = client.request(method, path)
    assert r.status_code == 405
    assert r.headers["allow"] == allow


def test_large_bodies_go_gzipped_to_clients_that_take_them(
    client: TestClient, admin: dict[str, str]
) -> None:
    """A city's map, latest levels and readings are hundreds of kB of JSON a poll."""
    zipped = client.get("/openapi.json", headers={"Accept-Encoding": "gzip"})
    plain = client.get("/openapi.json", headers={"Accept-Encoding": "identity"})
    assert zipped.headers["content-encoding"] == "gzip"
    assert zipped.headers["vary"] == "Accept-Encoding"
    assert int(zipped.headers["content-length"]) < len(plain.content) / 4
    assert "content-encoding" not in plain.headers
    assert zipped.json() == plain.json()
    head = client.head("/openapi.json", headers={"Accept-Encoding": "gzip"})
    assert head.headers["content-length"] == zipped.headers["content-length"]
    small = client.get("/health", headers={"Accept-Encoding": "gzip"})  # under 1 KiB
    assert "content-encoding" not in small.headers


def test_frames_are_neither_compressed_nor_answered_compressed(
    client: TestClient, admin: dict[str, str]
) -> None:
    """A JPEG does not compress; an upload's verdict is small and every frame would pay (only
    GET answers are compressed)."""
    token = client.post("/cameras", json={"id": "c", "kind": "rig"}, headers=admin).json()["token"]
    jpeg = make_jpeg(320, 240, noise=20.0)
    assert len(jpeg) > 4096  # over the 1 KiB below which nothing is compressed anyway
    gzip_ok = {"Accept-Encoding": "gzip"}
    r = client.post(
        "/cameras/c/frames",
        content=jpeg,
        headers={"Authorization": f"Bearer {token}", "Content-Type": "image/jpeg", **gzip_ok},
    )
    assert r.status_code == 201, r.text
    assert "content-encoding" not in r.headers
    image = client.get(f"/frames/{r.json()['frame_id']}/image", headers={**admin, **gzip_ok})
    assert (image.status_code, image.content) == (200, jpeg)
    assert "content-encoding" not in image.headers


def test_health_is_503_when_the_frame_directory_is_gone(
    client: TestClient, settings: Settings
) -> None:
    shutil.rmtree(settings.data_dir)  # an unmounted volume
    r = client.get("/health")
    assert r.status_code == 503
    assert r.json()["frame_store"] == "unreachable"
    assert r.json()["database"] == "ok"


def test_health_is_503_when_the_database_is_unreachable(settings: Settings) -> None:
    broken = settings.model_copy(
        update={"database_url": "postgresql+psycopg://nobody@127.0.0.1:1/none?connect_timeout=1"}
    )
    with TestClient(create_app(broken)) as c:
        r = c.get("/health")
    assert r.status_code == 503
    assert r.json()["database"] == "unreachable"


def test_request_id_is_echoed_and_logged(
    client: TestClient, capsys: pytest.CaptureFixture[str]
) -> None:
    r = client.get("/health", headers={"X-Request-ID": "abc-123"})
    assert r.headers["x-request-id"] == "abc-123"
    generated = client.get("/health").headers["x-request-id"]
    assert len(generated) == 32
    lines = [
        json.loads(line) for line in capsys.readouterr().err.splitlines() if line.startswith("{")
    ]
    access = [line for line in lines if line["logger"] == "vantage.access"]
    assert {"request_id": "abc-123", "path": "/health", "status": 200}.items() <= access[0].items()


def test_generated_request_ids_are_random_uuids(client: TestClient) -> None:
    ids = [client.get("/health").headers["x-request-id"] for _ in range(50)]
    assert len(set(ids)) == 50
    assert all(uuid.UUID(i).version == 4 and uuid.UUID(i).hex == i for i in ids)


def test_metrics_exposes_ingest_counters(client: TestClient, admin: dict[str, str]) -> None:
    text = client.get("/metrics", headers=admin).text
    assert "vantage_frames_received_total" in text
    assert "vantage_ingest_seconds_bucket" in text


def test_metrics_count_the_writer_s_batches_and_their_frames(
    client: TestClient, admin: dict[str, str]
) -> None:
    cam = client.post("/cameras", json={"id": "m", "kind": "rig"}, headers=admin).json()
    before = _samples(client, admin, "vantage_writer_batch_frames_")
    for seed in range(2):  # one after the other: a batch each
        r = client.post(
            "/cameras/m/frames",
            content=make_jpeg(noise=5.0, seed=seed),
            headers={"Authorization": f"Bearer {cam['token']}", "Content-Type": "image/jpeg"},
        )
        assert r.status_code == 201, r.text
    after = _samples(client, admin, "vantage_writer_batch_frames_")
    for name in ("vantage_writer_batch_frames_count", "vantage_writer_batch_frames_sum"):
        assert after[name, ()] - before.get((name, ()), 0) == 2


def _samples(
    client: TestClient, admin: dict[str, str], prefix: str = "vantage_http_"
) -> dict[tuple[str, Any], float]:
    """The /metrics samples whose names start with ``prefix``, by (name, sorted labels)."""
    from prometheus_client.parser import text_string_to_metric_families

    text = client.get("/metrics", headers=admin).text
    return {
        (s.name, tuple(sorted(s.labels.items()))): s.value
        for family in text_string_to_metric_families(text)
        for s in family.samples
        if s.name.startswith(prefix)
    }


def test_metrics_count_requests_per_route_and_status(
    client: TestClient, admin: dict[str, str]
) -> None:
    """Every answer is counted by method, route template and status, and timed: what an
    operator alerts on (the 5xx and 503 rates, a dashboard's latency). Requests answered
    before routing (a refused query), run as another method (HEAD) or refused by the route
    (405) count under their route; paths no route serves share one series."""
    before = _samples(client, admin)
    client.get("/cameras/a", headers=admin)  # 404 of a route: its template
    client.get("/cameras/b", headers=admin)
    client.head("/health")
    client.get("/air/readings", params={"camera": "x"})  # 422 before routing
    client.delete("/cameras", headers=admin)
    client.get("/no/such/path/1")
    client.get("/no/such/path/2")
    after = _samples(client, admin)

    def delta(method: str, route: str, status: int) -> float:
        key = (
            "vantage_http_requests_total",
            (("method", method), ("route", route), ("status", str(status))),
        )
        return after.get(key, 0.0) - before.get(key, 0.0)

    assert delta("GET", "/cameras/{camera_id}", 404) == 2
    assert delta("HEAD", "/health", 200) == 1
    assert delta("GET", "/air/readings", 422) == 1
    assert delta("DELETE", "/cameras", 405) == 1
    assert delta("GET", "unmatched", 404) == 2
    timed = (
        "vantage_http_request_seconds_count",
        (("method", "GET"), ("route", "/cameras/{camera_id}")),
    )
    assert after[timed] - before.get(timed, 0.0) == 2
    routes = {dict(labels)["route"] for name, labels in after if name.endswith("_total")}
    assert not any(r.startswith(("/cameras/a", "/no/")) for r in routes)  # no series per path


def test_metrics_need_the_metrics_or_the_admin_token(
    settings: Settings, engine: Any, admin: dict[str, str]
) -> None:
    """They name every camera, and the contract lists /metrics among no public endpoints: a
    scraper gets a token of its own, which opens nothing else."""
    from tests.factories import empty_tables

    empty_tables(engine)
    scraper = "m" * 32
    app = create_app(settings.model_copy(update={"metrics_token": SecretStr(scraper)}))
    with TestClient(app) as client:
        camera = client.post("/cameras", json={"id": "c", "kind": "rig"}, headers=admin).json()
        assert client.get("/metrics").status_code == 401
        assert client.get("/metrics", headers={"Authorization": "Bearer nope"}).status_code == 401
        as_camera = {"Authorization": f"Bearer {camera['token']}"}
        assert client.get("/metrics", headers=as_camera).status_code == 403
        for token in (scraper, admin["Authorization"].removeprefix("Bearer ")):
            r = client.get("/metrics", headers={"Authorization": f"Bearer {token}"})
            assert r.status_code == 200
            assert "vantage_ingest_seconds_bucket" in r.text
        as_scraper = {"Authorization": f"Bearer {scraper}"}
        assert client.get("/cameras", headers=as_scraper).status_code == 401


def test_unknown_route_is_problem_json(client: TestClient) -> None:
    r = client.get("/nowhere")
    assert r.status_code == 404
    assert r.headers["content-type"] == "application/problem+json"
    assert r.json()["status"] == 404


@pytest.mark.parametrize(
    ("body", "status", "title"),
    [
        (b"[" * 100_000, 400, "Bad request"),  # nested past the parser's depth
        ('{"id": "é"}'.encode("latin-1"), 400, "Bad request"),  # not UTF-8
        (b'{"id": "x", "kind": ', 422, "Unprocessable content"),  # cut short
    ],
)
def test_a_body_that_is_not_json_is_a_problem_with_a_title(
    client: TestClient, admin: dict[str, str], body: bytes, status: int, title: str
) -> None:
    """The 400s FastAPI raises for a body it cannot parse are titled by their reason phrase,
    as every other problem is (they had been titled "Error")."""
    r = client.post("/cameras", content=body, headers={**admin, "Content-Type": "application/json"})
    assert r.status_code == status
    assert r.headers["content-type"] == "application/problem+json"
    assert r.json()["title"] == title
    assert client.get("/cameras", headers=admin).json() == []  # nothing registered


@pytest.mark.parametrize("warm", [True, False])
def test_triangulation_warm_up_at_start_is_a_setting(
    settings: Settings, monkeypatch: pytest.MonkeyPatch, warm: bool
) -> None:
    from app.cells.core import triangulation

    calls: list[int] = []
    monkeypatch.setattr(triangulation, "warm_up", lambda: calls.append(1))
    app = create_app(settings.model_copy(update={"warm_up_triangulation": warm}))
    with TestClient(app) as c:
        assert c.get("/health").status_code == 200
    assert calls == ([1] if warm else [])


def test_start_up_objects_are_kept_out_of_the_collector_while_serving(settings: Settings) -> None:
    """A full collection then walks only what requests create, not every module and route."""
    gc.unfreeze()
    with TestClient(create_app(settings)) as c:
        assert c.get("/health").status_code == 200
        frozen = gc.get_freeze_count()
        assert frozen > 10_000
        assert frozen > len(gc.get_objects())
    assert gc.get_freeze_count() == 0
