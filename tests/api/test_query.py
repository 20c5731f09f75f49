"""A query parameter that takes one value, given twice: 422 ``repeated_parameter``, not the
last value taken without a word (``app/query.py``)."""

from __future__ import annotations

from fastapi.testclient import TestClient
from sqlalchemy import Engine

from app.query import repeated, rules
from tests.conftest import make_jpeg, table_counts


def test_an_upload_with_two_capture_times_is_refused_and_stores_nothing(
    client: TestClient, admin: dict[str, str], engine: Engine
) -> None:
    token = client.post("/cameras", json={"id": "c", "kind": "rig"}, headers=admin).json()["token"]
    before = table_counts(engine)
    r = client.post(
        "/cameras/c/frames?captured_at=2026-05-01T10:00:00Z&captured_at=2026-05-01T11:00:00Z",
        content=make_jpeg(),
        headers={"Authorization": f"Bearer {token}", "Content-Type": "image/jpeg"},
    )
    assert r.status_code == 422, r.text
    assert r.headers["content-type"] == "application/problem+json"
    body = r.json()
    assert (body["code"], body["parameters"]) == ("repeated_parameter", ["captured_at"])
    assert body["detail"] == (
        "captured_at is given 2 times; POST /cameras/c/frames takes one value of it"
    )
    assert table_counts(engine) == before


def test_paths_with_parameters_lists_and_other_names(
    client: TestClient, admin: dict[str, str]
) -> None:
    assert (
        client.post("/cameras", json={"id": "c", "kind": "sky"}, headers=admin).status_code == 201
    )
    r = client.get("/cameras/c/frames?limit=1&limit=2", headers=admin)
    assert (r.status_code, r.json()["parameters"]) == (422, ["limit"])
    # a list takes many; a name the endpoint does not know is not its business here
    assert client.get("/air/readings?camera_id=c&camera_id=c").status_code == 200
    assert client.get("/air/readings?utm=a&utm=b").status_code == 200
    assert client.get("/health?x=1&x=2").status_code == 200


def test_the_rules_come_from_the_openapi_document() -> None:
    document = {
        "paths": {
            "/a/{id}/b": {
                "get": {
                    "parameters": [
                        {"name": "id", "in": "path", "schema": {"type": "string"}},
                        {"name": "one", "in": "query", "schema": {"type": "integer"}},
                        {
                            "name": "many",
                            "in": "query",
                            "schema": {"anyOf": [{"type": "array"}, {"type": "null"}]},
                        },
                    ]
                }
            }
        }
    }
    [(pattern, single)] = rules(document)["GET"]
    assert single == {"one"}
    assert pattern.match("/a/x.y-1/b")
    assert not pattern.match("/a/x/y/b")
    assert not pattern.match("/a/x/b/c")
    assert repeated(b"one=1&many=2&many=3&x=&x=") == {"many": 2, "x": 2}
