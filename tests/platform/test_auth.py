"""Auth as the contract writes it: 401 for missing or unknown tokens, 403 for the wrong role."""

from __future__ import annotations

import base64
from typing import Any

import pytest
from fastapi.testclient import TestClient
from sqlalchemy import Engine, text

from app.main import create_app
from app.platform.auth import ADMIN_TOKEN_FILE, hash_token
from app.platform.settings import Settings
from tests.factories import ADMIN_TOKEN, make_jpeg


@pytest.fixture
def tokens(client: TestClient, admin: dict[str, str]) -> dict[str, str]:
    cam = client.post("/cameras", json={"id": "cam-a", "kind": "sky"}, headers=admin).json()
    robot = client.post("/robots", json={"id": "rob-1"}, headers=admin).json()
    return {"camera": cam["token"], "robot": robot["token"]}


def bearer(token: str) -> dict[str, str]:
    return {"Authorization": f"Bearer {token}"}


class TestRoles:
    @pytest.mark.parametrize(
        ("method", "path"),
        [("get", "/cameras"), ("get", "/panels"), ("get", "/robots"), ("get", "/cameras/cam-a")],
    )
    def test_missing_and_unknown_tokens_are_401(
        self, client: TestClient, tokens: dict[str, str], method: str, path: str
    ) -> None:
        for headers in ({}, bearer("not-a-token"), {"Authorization": "Token abc"}):
            r = client.request(method, path, headers=headers)
            assert r.status_code == 401, (headers, r.text)
            assert r.headers["content-type"] == "application/problem+json"
            assert "Bearer" in r.headers["www-authenticate"]

    @pytest.mark.parametrize("role", ["camera", "robot"])
    def test_admin_endpoints_refuse_other_roles_with_403(
        self, client: TestClient, tokens: dict[str, str], role: str
    ) -> None:
        for method, path, body in [
            ("get", "/cameras", None),
            ("post", "/cameras", {"id": "x", "kind": "sky"}),
            ("post", "/panels", {"id": "p"}),
            ("post", "/robots", {"id": "r"}),
        ]:
            r = client.request(method, path, json=body, headers=bearer(tokens[role]))
            assert r.status_code == 403, (method, path, r.text)
            assert r.headers["content-type"] == "application/problem+json"

    def test_robot_may_not_post_frames(self, client: TestClient, tokens: dict[str, str]) -> None:
        r = client.post(
            "/cameras/cam-a/frames",
            content=make_jpeg(),
            headers={**bearer(tokens["robot"]), "Content-Type": "image/jpeg"},
        )
        assert r.status_code == 403

    def test_basic_auth_needs_the_matching_camera_id(
        self, client: TestClient, tokens: dict[str, str]
    ) -> None:
        def basic(user: str, password: str) -> dict[str, str]:
            cred = base64.b64encode(f"{user}:{password}".encode()).decode()
            return {"Authorization": f"Basic {cred}", "Content-Type": "image/jpeg"}

        ok = client.post(
            "/cameras/cam-a/frames", content=make_jpeg(), headers=basic("cam-a", tokens["camera"])
        )
        assert ok.status_code == 201
        wrong_user = client.post(
            "/cameras/cam-a/frames", content=make_jpeg(), headers=basic("cam-b", tokens["camera"])
        )
        assert wrong_user.status_code == 401
        garbage = client.post(
            "/cameras/cam-a/frames",
            content=make_jpeg(),
            headers={"Authorization": "Basic !!!", "Content-Type": "image/jpeg"},
        )
        assert garbage.status_code == 401

    def test_public_endpoints_need_no_token(self, client: TestClient) -> None:
        assert client.get("/health").status_code == 200
        assert client.get("/openapi.json").status_code == 200
        assert client.get("/docs").status_code == 200


class TestTokenStorage:
    def test_only_hashes_are_stored(
        self, client: TestClient, tokens: dict[str, str], engine: Engine
    ) -> None:
        with engine.connect() as conn:
            cams = conn.execute(text("SELECT token_hash FROM cameras")).scalars().all()
            robots = conn.execute(text("SELECT token_hash FROM robots")).scalars().all()
        assert cams == [hash_token(tokens["camera"])]
        assert robots == [hash_token(tokens["robot"])]
        assert tokens["camera"] not in cams

    def test_token_is_not_shown_again(
        self, client: TestClient, tokens: dict[str, str], admin: dict[str, str]
    ) -> None:
        assert "token" not in client.get("/cameras/cam-a", headers=admin).json()
        assert all("token" not in c for c in client.get("/cameras", headers=admin).json())


class TestAdminTokenBootstrap:
    def test_generated_once_saved_and_reused(self, settings: Settings, engine: Engine) -> None:
        unset = settings.model_copy(update={"admin_token": None})
        app = create_app(unset)
        path = unset.data_dir / ADMIN_TOKEN_FILE
        token = path.read_text().strip()
        assert len(token) >= 32
        assert path.stat().st_mode & 0o777 == 0o600
        with TestClient(app) as c:
            assert c.get("/cameras", headers=bearer(token)).status_code == 200
        # a restart keeps the same token
        create_app(unset)
        assert path.read_text().strip() == token

    def test_production_refuses_a_short_admin_token(self) -> None:
        with pytest.raises(ValueError, match="at least 24"):
            Settings(env="production", admin_token="short")  # type: ignore[arg-type]


def test_tokens_are_distinct(client: TestClient, admin: dict[str, str]) -> None:
    seen: set[Any] = set()
    for i in range(5):
        seen.add(
            client.post("/cameras", json={"id": f"c{i}", "kind": "rig"}, headers=admin).json()[
                "token"
            ]
        )
    assert len(seen) == 5


VIEWER_READS = {
    ("GET", "/panels"),
    ("GET", "/panels/{panel_id}"),
    ("GET", "/panel-states"),
    ("GET", "/panels/{panel_id}/status"),
    ("GET", "/panels/{panel_id}/history"),
    ("GET", "/panels/{panel_id}/energy"),
    ("GET", "/panels/{panel_id}/soiling"),
    ("GET", "/solar/economics"),
    ("GET", "/cleaning/tasks"),
    ("GET", "/cleaning/tasks/{task_id}"),
    ("GET", "/fleet/model"),
    ("GET", "/fleet/doubts"),
    ("GET", "/fleet/labels"),
    ("GET", "/frames/{frame_id}/region.jpg"),
    ("GET", "/calibrations"),
    ("GET", "/calibrations/{calibration_id}"),
    ("GET", "/rigs"),
    ("GET", "/rigs/{rig_id}"),
}
"""What a viewer token may do: the farm and cells boards' reads."""
ROBOT_MAY = {
    ("GET", "/panels/{panel_id}/baseline"),
    ("GET", "/panels/{panel_id}/history"),
    ("GET", "/panels/{panel_id}/status"),
    ("GET", "/panels/{panel_id}/trigger"),
    ("POST", "/cleaning/claim"),
    ("POST", "/cleaning/tasks/{task_id}/claim"),
    ("POST", "/cleaning/tasks/{task_id}/complete"),
    ("POST", "/cleaning/tasks/{task_id}/fail"),
    ("GET", "/cleaning/tasks"),
    ("GET", "/cleaning/tasks/{task_id}"),
    ("POST", "/vision/outline"),
    ("POST", "/vision/outline.png"),
    ("POST", "/vision/enhance"),
    ("GET", "/rigs"),
    ("GET", "/rigs/{rig_id}"),
    ("POST", "/rigs/{rig_id}/triangulate"),
    ("POST", "/rigs/{rig_id}/laser/dot"),
    ("POST", "/rigs/{rig_id}/laser/grid"),
    ("POST", "/shapes/match"),
}
"""What a robot token may do: its cleaning tasks, its panels' state, the cells' measuring."""
ROBOTS_ONLY = {
    ("POST", "/cleaning/claim"),
    ("POST", "/cleaning/tasks/{task_id}/claim"),
    ("POST", "/cleaning/tasks/{task_id}/complete"),
    ("POST", "/cleaning/tasks/{task_id}/fail"),
}
"""What the admin may not do: a robot's own work on its tasks."""
OPEN_TO_ALL = {("GET", "/air/alerts")}
"""Public, but a token given must be valid (the admin sees more)."""


def _secured(client: TestClient) -> list[tuple[str, str]]:
    schema = client.get("/openapi.json").json()
    return [
        (m.upper(), p)
        for p, item in schema["paths"].items()
        for m, op in item.items()
        if isinstance(op, dict) and "401" in op["responses"]
    ]


class TestViewers:
    @pytest.fixture
    def viewer(self, client: TestClient, admin: dict[str, str]) -> dict[str, str]:
        r = client.post("/viewers", json={"name": "lobby"}, headers=admin)
        assert r.status_code == 201, r.text
        assert r.json()["token"].startswith("vv_")
        return dict(r.json())

    def test_the_matrix_every_operation_by_every_caller(
        self, client: TestClient, tokens: dict[str, str], viewer: dict[str, str]
    ) -> None:
        """Every operation that takes a token: 401 without one or with a wrong one; a viewer
        is refused (403) everything but the boards' reads, a robot everything but its tasks,
        panels and the cells' measuring, a camera everything here (its own frames' upload
        names its own id); each passes what it may, the admin everything but a robot's own work
        on its tasks, never with a 5xx."""
        operations = _secured(client)
        assert len(operations) > 50
        assert VIEWER_READS <= set(operations)
        for method, path in operations:
            url = path.replace("{", "").replace("}", "")  # ids that name nothing
            r = client.request(method, url, headers=bearer("vx_wrong"))
            assert r.status_code == 401, (method, path, r.status_code)
            r = client.request(method, url)
            assert r.status_code == (200 if (method, path) in OPEN_TO_ALL else 401), (method, path)
            r = client.request(method, url, headers=bearer(ADMIN_TOKEN))
            if (method, path) in ROBOTS_ONLY:
                assert r.status_code == 403, ("admin", method, path, r.text)
            else:
                assert r.status_code not in (401, 403), ("admin", method, path, r.text)
            assert r.status_code < 500, ("admin", method, path, r.text)
            for role, token, may in (
                ("viewer", viewer["token"], VIEWER_READS),
                ("robot", tokens["robot"], ROBOT_MAY),
                ("camera", tokens["camera"], set()),  # only its own frames: none named here
            ):
                r = client.request(method, url, headers=bearer(token))
                if (method, path) in may | OPEN_TO_ALL:
                    assert r.status_code not in (401, 403), (role, method, path, r.text)
                    assert r.status_code < 500, (role, method, path, r.text)
                else:
                    assert r.status_code == 403, (role, method, path, r.status_code)

    def test_listed_without_its_secret_and_revoked(
        self, client: TestClient, admin: dict[str, str], viewer: dict[str, str]
    ) -> None:
        listed = client.get("/viewers", headers=admin).json()
        assert [v["name"] for v in listed] == ["lobby"]
        assert "token" not in listed[0]
        assert client.get("/panels", headers=bearer(viewer["token"])).status_code == 200
        assert client.delete(f"/viewers/{viewer['id']}", headers=admin).status_code == 204
        assert client.get("/panels", headers=bearer(viewer["token"])).status_code == 401
        assert client.delete(f"/viewers/{viewer['id']}", headers=admin).status_code == 404

    def test_a_sign_in_code_is_good_once(self, client: TestClient, admin: dict[str, str]) -> None:
        made = client.post("/signin-codes", json={"name": "kiosk"}, headers=admin).json()
        assert made["farm"] == f"/farm#code={made['code']}"
        r = client.post("/signin-codes/redeem", json={"code": made["code"]})
        assert r.status_code == 201, r.text
        assert client.get("/panel-states", headers=bearer(r.json()["token"])).status_code == 200
        again = client.post("/signin-codes/redeem", json={"code": made["code"]})
        assert again.status_code == 422
        assert again.json()["detail"] == "the sign-in code is unknown, used or expired"
        assert [v["name"] for v in client.get("/viewers", headers=admin).json()] == ["kiosk"]

    def test_an_expired_code_is_refused(
        self, client: TestClient, admin: dict[str, str], engine: Engine
    ) -> None:
        made = client.post("/signin-codes", json={"name": "k", "minutes": 1}, headers=admin)
        with engine.begin() as conn:
            conn.execute(text("UPDATE signin_codes SET expires_at = '2000-01-01 00:00:00+00:00'"))
        r = client.post("/signin-codes/redeem", json={"code": made.json()["code"]})
        assert r.status_code == 422
        assert client.get("/viewers", headers=admin).json() == []


class TestBasic:
    def test_basic_is_for_cameras_only(self, client: TestClient, tokens: dict[str, str]) -> None:
        for user in ("admin", "anything", ""):
            cred = base64.b64encode(f"{user}:{ADMIN_TOKEN}".encode()).decode()
            r = client.get("/cameras", headers={"Authorization": f"Basic {cred}"})
            assert r.status_code == 401, user
        cred = base64.b64encode(f"rob-1:{tokens['robot']}".encode()).decode()
        assert (
            client.get("/cleaning/tasks", headers={"Authorization": f"Basic {cred}"}).status_code
            == 401
        )

    def test_no_basic_challenge_but_for_a_camera_posting(self, client: TestClient) -> None:
        for path in ("/cameras", "/panels", "/calibrations"):
            r = client.get(path)
            assert r.status_code == 401
            assert "basic" not in r.headers["www-authenticate"].lower(), path
        upload = client.post("/cameras/cam-a/frames", content=make_jpeg())
        assert "Basic" in upload.headers["www-authenticate"]
        browser = client.post(
            "/cameras/cam-a/frames", content=make_jpeg(), headers={"Sec-Fetch-Mode": "cors"}
        )
        assert "basic" not in browser.headers["www-authenticate"].lower()
