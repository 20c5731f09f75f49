"""Bodies over their route's cap are refused (413) before the route buffers them.

FastAPI reads a JSON route's whole body before it checks the token; ``BodyLimitMiddleware``
caps it first. Caps are made small here (``max_body_bytes`` 2,000, ``max_upload_bytes``
50,000) so the bodies stay small.
"""

from __future__ import annotations

import json
from collections.abc import Iterator
from typing import Any

import pytest
from fastapi.testclient import TestClient
from sqlalchemy import Engine

from app.main import create_app
from tests.factories import ADMIN_TOKEN, empty_tables, table_counts

ADMIN = {"Authorization": f"Bearer {ADMIN_TOKEN}"}
JSON = {"Content-Type": "application/json"}


@pytest.fixture
def small(settings: Any, engine: Engine) -> Iterator[TestClient]:
    capped = settings.model_copy(update={"max_body_bytes": 2000, "max_upload_bytes": 50_000})
    empty_tables(engine)
    with TestClient(create_app(capped), raise_server_exceptions=False) as c:
        yield c


def panel(padding: int) -> bytes:
    """A valid panel, padded with whitespace (still valid JSON) to about ``padding`` bytes."""
    return (json.dumps({"id": "p", "name": "x" * 100}) + " " * padding).encode()


def chunked(data: bytes) -> Iterator[bytes]:  # no Content-Length
    for i in range(0, len(data), 500):
        yield data[i : i + 500]


@pytest.mark.parametrize("stream", [False, True], ids=["content-length", "chunked"])
def test_a_json_body_over_the_cap_is_413_even_without_a_token(
    small: TestClient, engine: Engine, stream: bool
) -> None:
    before = table_counts(engine)
    body = panel(3000)
    for headers in (JSON, {**JSON, **ADMIN}):
        content: Any = chunked(body) if stream else body
        r = small.post("/panels", content=content, headers=headers)
        assert r.status_code == 413, r.text
        assert r.headers["content-type"] == "application/problem+json"
        assert r.json()["code"] == "too_large"
    assert table_counts(engine) == before


@pytest.mark.parametrize("stream", [False, True], ids=["content-length", "chunked"])
def test_a_json_body_under_the_cap_goes_through(small: TestClient, stream: bool) -> None:
    body = panel(1000)
    content: Any = chunked(body) if stream else body
    r = small.post("/panels", content=content, headers={**JSON, **ADMIN})
    assert r.status_code == 201, r.text
    assert small.get("/panels/p", headers=ADMIN).json()["name"] == "x" * 100


def test_triangulation_takes_many_points_up_to_the_upload_cap(small: TestClient) -> None:
    rig = {"id": "x", "kind": "cross", "f_px": 800, "ax": 0.3, "ay": 0.2}
    assert small.post("/rigs", json=rig, headers=ADMIN).status_code == 201
    point = [[200, 216], [440, 216], [320, 296], [320, 136]]  # (0, 0.03, 1)
    many = json.dumps({"observations": [point] * 200}).encode()  # ~9 kB: over 2,000, under 50,000
    r = small.post("/rigs/x/triangulate", content=many, headers={**JSON, **ADMIN})
    assert r.status_code == 200, r.text
    assert len(r.json()["points"]) == 200
    too_many = json.dumps({"observations": [point] * 1200}).encode()  # ~54 kB
    r = small.post("/rigs/x/triangulate", content=too_many, headers={**JSON, **ADMIN})
    assert r.status_code == 413, r.text
