"""A query parameter the endpoint does not take: 422 ``unknown_parameter``, not ignored; one
that takes one value, given twice: 422 ``repeated_parameter``, not the last value taken without
a word (``app/query.py``)."""

from __future__ import annotations

from datetime import UTC, datetime, timedelta, timezone

from fastapi.testclient import TestClient
from sqlalchemy import Engine

from app.platform.http.query import counted, rules
from tests.factories import make_jpeg, table_counts


def rejected(client: TestClient, admin: dict[str, str], reason: str) -> float:
    """The count of uploads refused for ``reason`` under no camera, from ``/metrics``."""
    sample = f'vantage_frames_rejected_total{{camera_id="unknown",reason="{reason}"}} '
    lines = client.get("/metrics", headers=admin).text.splitlines()
    return next((float(line.removeprefix(sample)) for line in lines if line.startswith(sample)), 0)


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
    # a list takes many; cache-busters and trackers pass, repeated or not
    assert client.get("/air/readings?camera_id=c&camera_id=c").status_code == 200
    assert client.get("/air/readings?utm_source=a&utm_source=b&_=1").status_code == 200
    assert client.get("/health?_=1700000000").status_code == 200


def test_a_parameter_the_endpoint_does_not_take_is_refused(
    client: TestClient, admin: dict[str, str]
) -> None:
    """Ignored, it answered another question: every camera's readings for ``camera=``."""
    r = client.get("/air/readings?camera=c1&limit=5")
    assert r.status_code == 422, r.text
    assert r.headers["content-type"] == "application/problem+json"
    body = r.json()
    assert (body["code"], body["parameters"]) == ("unknown_parameter", ["camera"])
    assert body["detail"].startswith(
        "camera is not a parameter of GET /air/readings; did you mean camera_id? (it takes "
    )
    assert {"camera_id", "limit"} <= set(body["accepted"])
    r = client.get("/panels?status=needs_cleaning", headers=admin)
    assert (r.status_code, r.json()["parameters"]) == (422, ["status"])
    r = client.get("/health?verbose=1")
    assert r.status_code == 422
    assert r.json()["detail"] == (
        "verbose is not a parameter of GET /health (it takes no query parameters)"
    )
    # outside the OpenAPI document nothing is checked
    assert client.get("/openapi.json?x=1").status_code == 200


def test_an_upload_with_a_misspelt_capture_time_is_refused_and_stores_nothing(
    client: TestClient, admin: dict[str, str], engine: Engine
) -> None:
    """Ignored, the frame was stored as taken when it arrived."""
    token = client.post("/cameras", json={"id": "c", "kind": "rig"}, headers=admin).json()["token"]
    before = table_counts(engine)
    refused = rejected(client, admin, "unknown_parameter")
    r = client.post(
        "/cameras/c/frames?capture_at=2026-05-01T10:00:00Z",
        content=make_jpeg(),
        headers={"Authorization": f"Bearer {token}", "Content-Type": "image/jpeg"},
    )
    assert r.status_code == 422, r.text
    body = r.json()
    assert (body["code"], body["parameters"]) == ("unknown_parameter", ["capture_at"])
    assert "did you mean captured_at?" in body["detail"]
    assert table_counts(engine) == before
    # counted with the other refused uploads, under no camera (nothing authenticated it)
    assert rejected(client, admin, "unknown_parameter") == refused + 1


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
    [rule] = rules(document)["GET"]
    assert rule.single == {"one"}
    assert rule.known == {"one", "many"}
    assert rule.pattern.match("/a/x.y-1/b")
    assert not rule.pattern.match("/a/x/y/b")
    assert not rule.pattern.match("/a/x/b/c")
    assert counted(b"one=1&many=2&many=3&x=&x=") == {"one": 1, "many": 2, "x": 2}


def test_an_offset_sent_with_its_plus_unencoded_is_read_as_the_offset(
    client: TestClient, admin: dict[str, str]
) -> None:
    """A camera whose URL template gives ``captured_at=…T10:00:00+02:00`` as it is: the "+"
    of a query is a space, the time arrived as ``…10:00:00 02:00``, and every upload got 422.
    The frame is now stored as taken at 08:00 UTC; a reading's range given so answers as with
    %2B; a "+" elsewhere in a value is still a space."""
    token = client.post("/cameras", json={"id": "c", "kind": "rig"}, headers=admin).json()["token"]
    headers = {"Authorization": f"Bearer {token}", "Content-Type": "image/jpeg"}
    taken = (datetime.now(UTC) - timedelta(days=1)).replace(microsecond=0)
    local = taken.astimezone(timezone(timedelta(hours=2)))
    r = client.post(
        f"/cameras/c/frames?captured_at={local.isoformat()}", content=make_jpeg(), headers=headers
    )
    assert "+02:00" in local.isoformat()
    assert r.status_code == 201, r.text
    assert r.json()["captured_at"] == taken.strftime("%Y-%m-%dT%H:%M:%SZ")
    india = (taken + timedelta(seconds=0.5)).astimezone(timezone(timedelta(hours=5, minutes=30)))
    as_sent = india.strftime("%Y-%m-%d+%H:%M:%S.%f+0530")  # a space for T too, and +HHMM
    r = client.post(
        f"/cameras/c/frames?captured_at={as_sent}", content=make_jpeg(seed=1), headers=headers
    )
    assert r.status_code == 201, r.text
    assert r.json()["captured_at"] == taken.strftime("%Y-%m-%dT%H:%M:%S.500000Z")
    since = local.isoformat()
    raw = client.get(f"/air/readings?since={since}")
    encoded = client.get(f"/air/readings?since={since.replace('+', '%2B')}")
    assert raw.status_code == encoded.status_code == 200, raw.text
    assert raw.json() == encoded.json()
    r = client.get(f"/air/readings?since={since[:-6]}+1")  # not an offset
    assert r.status_code == 422
    assert r.json()["errors"][0]["loc"] == ["query", "since"]
