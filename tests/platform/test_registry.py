"""Registering cameras, panels and robots."""

from __future__ import annotations

import pytest
from fastapi.testclient import TestClient


class TestCreateCamera:
    def test_created_and_listed(self, client: TestClient, admin: dict[str, str]) -> None:
        body = {
            "id": "sky.north-1",
            "kind": "sky",
            "name": "North",
            "lat": 45.46,
            "lon": 9.19,
            "roi": [0, 60, 640, 300],
        }
        r = client.post("/cameras", json=body, headers=admin)
        assert r.status_code == 201, r.text
        out = r.json()
        assert out["token"].startswith("vc_")
        assert {k: out[k] for k in body} == body
        assert client.get("/cameras/sky.north-1", headers=admin).json()["roi"] == [0, 60, 640, 300]
        assert [c["id"] for c in client.get("/cameras", headers=admin).json()] == ["sky.north-1"]

    def test_duplicate_id_is_409(self, client: TestClient, admin: dict[str, str]) -> None:
        assert (
            client.post("/cameras", json={"id": "c", "kind": "rig"}, headers=admin).status_code
            == 201
        )
        r = client.post("/cameras", json={"id": "c", "kind": "sky"}, headers=admin)
        assert r.status_code == 409
        assert r.headers["content-type"] == "application/problem+json"

    @pytest.mark.parametrize(
        "body",
        [
            {"id": "a/b", "kind": "rig"},
            {"id": "x" * 65, "kind": "rig"},
            {"id": "", "kind": "rig"},
            {"id": "c", "kind": "toaster"},
            {"id": "c", "kind": "sky", "lat": 91},
            {"id": "c", "kind": "sky", "roi": [0, 0, 10]},
            {"id": "c", "kind": "sky", "roi": [0, 0, 0, 10]},
            {"id": "c", "kind": "sky", "roi": [-1, 0, 5, 10]},
            {"id": "c", "kind": "sky", "extra": 1},
            {"id": "c", "kind": "sky", "panel_id": "p"},
            {"id": "c", "kind": "panel", "panel_id": "missing"},
            {"id": "c", "kind": "sky", "lat": 45.46},  # half a place: off the map, silently
            {"id": "c", "kind": "sky", "lon": 9.19, "lat": None},
        ],
    )
    def test_invalid_bodies_are_422(
        self, client: TestClient, admin: dict[str, str], body: dict[str, object]
    ) -> None:
        r = client.post("/cameras", json=body, headers=admin)
        assert r.status_code == 422, r.text
        assert r.headers["content-type"] == "application/problem+json"
        assert r.json()["detail"]
        assert client.get("/cameras", headers=admin).json() == []

    def test_nan_coordinates_are_422(self, client: TestClient, admin: dict[str, str]) -> None:
        r = client.post(
            "/cameras",
            content=b'{"id": "c", "kind": "sky", "lat": NaN, "lon": 9.0}',
            headers={**admin, "Content-Type": "application/json"},
        )
        assert r.status_code == 422

    def test_unknown_camera_is_404(self, client: TestClient, admin: dict[str, str]) -> None:
        r = client.get("/cameras/none", headers=admin)
        assert r.status_code == 404
        assert r.headers["content-type"] == "application/problem+json"


class TestPanelsAndRobots:
    def test_panel_roundtrip(self, client: TestClient, admin: dict[str, str]) -> None:
        r = client.post(
            "/panels", json={"id": "p-1", "name": "Row 1", "lat": 1.0, "lon": 2.0}, headers=admin
        )
        assert r.status_code == 201
        assert client.get("/panels/p-1", headers=admin).json()["name"] == "Row 1"
        assert client.post("/panels", json={"id": "p-1"}, headers=admin).status_code == 409
        assert client.get("/panels/p-2", headers=admin).status_code == 404

    def test_panel_camera_attaches_to_existing_panel(
        self, client: TestClient, admin: dict[str, str]
    ) -> None:
        client.post("/panels", json={"id": "p-1"}, headers=admin)
        r = client.post(
            "/cameras", json={"id": "c", "kind": "panel", "panel_id": "p-1"}, headers=admin
        )
        assert r.status_code == 201
        assert r.json()["panel_id"] == "p-1"

    def test_robot_token_is_shown_once(self, client: TestClient, admin: dict[str, str]) -> None:
        r = client.post("/robots", json={"id": "r1"}, headers=admin)
        assert r.status_code == 201
        assert r.json()["token"].startswith("vr_")
        assert "token" not in client.get("/robots", headers=admin).json()[0]
        one = client.get("/robots/r1", headers=admin)
        assert one.status_code == 200
        assert one.json()["id"] == "r1"
        assert one.json()["retired_at"] is None
        assert "token" not in one.json()
        assert client.get("/robots/r2", headers=admin).status_code == 404
        robot = {"Authorization": f"Bearer {r.json()['token']}"}
        assert client.get("/robots/r1", headers=robot).status_code == 403
        assert client.delete("/robots/r1", headers=admin).status_code == 204
        assert client.get("/robots/r1", headers=admin).json()["retired_at"] is not None


@pytest.mark.parametrize("dots", [".", ".."])
@pytest.mark.parametrize(
    ("path", "body"),
    [
        ("/cameras", {"kind": "sky"}),
        ("/panels", {}),
        ("/robots", {}),
        ("/rigs", {"kind": "cross", "f_px": 800, "ax": 100, "ay": 100}),
    ],
)
def test_dot_segment_ids_are_refused(
    client: TestClient, admin: dict[str, str], path: str, body: dict[str, object], dots: str
) -> None:
    # every client resolves /air/cameras/../latest to /air/latest (RFC 3986 §5.2.4): such an id
    # could be registered but never reached
    r = client.post(path, json={"id": dots, **body}, headers=admin)
    assert r.status_code == 422, r.text
    assert "dot-segment" in r.text
    assert client.get(path, headers=admin).json() == []
    assert client.post(path, json={"id": f"{dots}x", **body}, headers=admin).status_code == 201


@pytest.mark.parametrize(
    ("content_type", "said"),
    [
        (None, "no Content-Type"),
        ("application/x-www-form-urlencoded", "application/x-www-form-urlencoded"),  # curl -d
        ("text/plain; charset=utf-8", "text/plain"),
    ],
)
def test_json_sent_unlabelled_is_415_naming_what_came(
    client: TestClient, admin: dict[str, str], content_type: str | None, said: str
) -> None:
    """Valid JSON labelled as a form (``curl -d`` without a Content-Type) was answered "body:
    Input should be a valid dictionary", which sent the user looking at the JSON."""
    headers = {**admin, **({"Content-Type": content_type} if content_type else {})}
    r = client.post("/cameras", content=b'{"id": "c", "kind": "rig"}', headers=headers)
    assert r.status_code == 415, r.text
    assert r.headers["content-type"] == "application/problem+json"
    assert (r.json()["code"], r.json()["detail"]) == (
        "not_json",
        f"the body must be JSON, sent with Content-Type: application/json; it came as {said}",
    )
    assert client.get("/cameras", headers=admin).json() == []
    # labelled JSON, of any JSON flavour, is read; JSON that is wrong is still 422
    for label in ("application/json; charset=utf-8", "application/merge-patch+json"):
        r = client.patch(
            "/cameras/c", content=b'{"name": "n"}', headers={**admin, "Content-Type": label}
        )
        assert r.status_code == 404  # read, and no such camera
    r = client.post(
        "/cameras", content=b'{"id": "c"}', headers={**admin, "Content-Type": "application/json"}
    )
    assert r.status_code == 422


def test_nul_characters_are_refused(client: TestClient, admin: dict[str, str]) -> None:
    # PostgreSQL cannot store NUL in text: refused as input, never a 500
    assert (
        client.post("/panels", json={"id": "p", "name": "a\u0000b"}, headers=admin).status_code
        == 422
    )
    assert (
        client.get("/cleaning/tasks", params={"panel_id": "\x00"}, headers=admin).status_code == 422
    )
    assert client.get("/frames/%00", headers=admin).status_code == 422


def test_cameras_gone_quiet(client: TestClient, admin: dict[str, str]) -> None:
    """Each camera shows when its newest frame was taken; ``silent_for`` lists those with none
    in that many seconds (or none at all): the ones an operator must go and look at."""
    from datetime import UTC, datetime, timedelta

    from tests.factories import make_jpeg

    now = datetime.now(UTC).replace(microsecond=0)
    taken = {"old": now - timedelta(hours=2), "new": now - timedelta(minutes=1)}
    for cid in ("new", "none", "old", "gone"):
        assert client.post("/cameras", json={"id": cid, "kind": "rig"}, headers=admin).is_success
    for cid, at in [("old", taken["old"] - timedelta(hours=1)), *taken.items()]:
        r = client.post(
            f"/cameras/{cid}/frames",
            params={"captured_at": at.isoformat()},
            content=make_jpeg(seed=len(cid)),
            headers={**admin, "Content-Type": "image/jpeg"},
        )
        assert r.status_code == 201, r.text
    assert client.delete("/cameras/gone", headers=admin).status_code == 204

    def seen(**params: object) -> dict[str, datetime | None]:
        r = client.get("/cameras", params=params, headers=admin)
        assert r.status_code == 200, r.text
        return {
            c["id"]: c["last_captured_at"] and datetime.fromisoformat(c["last_captured_at"])
            for c in r.json()
        }

    assert seen() == {"new": taken["new"], "none": None, "old": taken["old"]}
    assert seen(silent_for=3600) == {"none": None, "old": taken["old"]}
    assert seen(silent_for=3 * 3600) == {"none": None}
    assert seen(silent_for=3600, retired="true") == {
        "gone": None,
        "none": None,
        "old": taken["old"],
    }
    assert seen(silent_for=3600, limit=1, offset=1) == {"old": taken["old"]}
    one = client.get("/cameras/old", headers=admin).json()
    assert datetime.fromisoformat(one["last_captured_at"]) == taken["old"]
    patched = client.patch("/cameras/old", json={"name": "roof"}, headers=admin).json()
    assert patched["last_captured_at"] == one["last_captured_at"]
    assert client.get("/cameras", params={"silent_for": 0}, headers=admin).status_code == 422


def test_cameras_of_a_kind_or_a_panel(client: TestClient, admin: dict[str, str]) -> None:
    for pid in ("p1", "p2"):
        assert client.post("/panels", json={"id": pid}, headers=admin).status_code == 201
    for cid, kind, pid in [
        ("a", "panel", "p1"),
        ("b", "sky", None),
        ("c", "panel", "p2"),
        ("d", "panel", "p1"),
        ("e", "rig", None),
    ]:
        body = {"id": cid, "kind": kind, **({"panel_id": pid} if pid else {})}
        assert client.post("/cameras", json=body, headers=admin).status_code == 201
    assert client.delete("/cameras/d", headers=admin).status_code == 204

    def ids(**params: object) -> list[str]:
        r = client.get("/cameras", params=params, headers=admin)
        assert r.status_code == 200, r.text
        return [c["id"] for c in r.json()]

    assert ids(kind="panel") == ["a", "c"]
    assert ids(kind="sky") == ["b"]
    assert ids(panel_id="p1") == ["a"]
    assert ids(panel_id="p1", retired="true") == ["a", "d"]
    assert ids(panel_id="p2", kind="sky") == []
    assert client.get("/cameras", params={"panel_id": "nope"}, headers=admin).status_code == 404
    assert client.get("/cameras", params={"kind": "toaster"}, headers=admin).status_code == 422
    assert client.get("/cameras", params={"panel_id": "a/b"}, headers=admin).status_code == 422
