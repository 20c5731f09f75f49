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
from tests.factories import make_jpeg


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
