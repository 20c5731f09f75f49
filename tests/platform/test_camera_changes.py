"""Changing a registered camera: its fields (PATCH), its upload token (rotation), and retiring
it (DELETE)."""

from __future__ import annotations

from datetime import UTC, datetime
from typing import Any

import cv2
import numpy as np
import pytest
from fastapi.testclient import TestClient
from sqlalchemy import Engine, update

from app.platform.auth import hash_token
from app.platform.db.models import Camera, CameraKind
from app.platform.frames.camera_info import CameraInfo, TokenCache
from tests.factories import LEFT, RIGHT, halves, make_jpeg, near, table_counts


def register(client: TestClient, admin: dict[str, str], **fields: object) -> str:
    body = {"id": "cam", "kind": "rig", **fields}
    r = client.post("/cameras", json=body, headers=admin)
    assert r.status_code == 201, r.text
    token: str = r.json()["token"]
    return token


def post(client: TestClient, token: str, data: bytes) -> tuple[int, dict[str, object]]:
    r = client.post(
        "/cameras/cam/frames",
        content=data,
        headers={"Authorization": f"Bearer {token}", "Content-Type": "image/jpeg"},
    )
    return r.status_code, r.json()


def modes(body: dict[str, object]) -> list[int]:
    verdict = body["verdict"]
    assert isinstance(verdict, dict)
    return list(verdict["modes"])


def judged_on(client: TestClient, token: str, colour: tuple[int, int, int]) -> None:
    """Post ``halves()``: stored, and its modes are those of the half ``colour``."""
    status, body = post(client, token, halves())
    assert status == 201, body
    assert near(modes(body), colour), modes(body)


class TestUpdate:
    def test_a_new_region_applies_to_the_very_next_frame(
        self, client: TestClient, admin: dict[str, str]
    ) -> None:
        token = register(client, admin, roi=[0, 0, 24, 48])  # inside the left half
        judged_on(client, token, LEFT)  # also puts the camera in the token cache

        r = client.patch("/cameras/cam", json={"roi": [40, 0, 24, 48]}, headers=admin)
        assert r.status_code == 200, r.text
        assert r.json()["roi"] == [40, 0, 24, 48]
        judged_on(client, token, RIGHT)

    def test_fields_left_out_keep_their_value_and_null_clears(
        self, client: TestClient, admin: dict[str, str]
    ) -> None:
        register(client, admin, name="East", lat=45.0, lon=9.0, roi=[0, 0, 10, 10])
        r = client.patch("/cameras/cam", json={"name": "East gate", "roi": None}, headers=admin)
        assert r.status_code == 200, r.text
        out = client.get("/cameras/cam", headers=admin).json()
        assert (out["name"], out["lat"], out["lon"], out["roi"]) == ("East gate", 45.0, 9.0, None)
        assert out["kind"] == "rig"

    def test_a_polygon_region(self, client: TestClient, admin: dict[str, str]) -> None:
        token = register(client, admin)
        polygon = [[40, 0], [63, 0], [63, 47], [40, 47]]
        r = client.patch("/cameras/cam", json={"roi": polygon}, headers=admin)
        assert r.status_code == 200, r.text
        judged_on(client, token, RIGHT)

    def test_a_panel_camera_moves_to_another_panel(
        self, client: TestClient, admin: dict[str, str]
    ) -> None:
        for panel in ("p1", "p2"):
            assert client.post("/panels", json={"id": panel}, headers=admin).status_code == 201
        register(client, admin, kind="panel", panel_id="p1")
        r = client.patch("/cameras/cam", json={"panel_id": "p2"}, headers=admin)
        assert r.status_code == 200, r.text
        assert client.get("/cameras/cam", headers=admin).json()["panel_id"] == "p2"

    @pytest.mark.parametrize(
        "body",
        [
            {"kind": None},
            {"id": "other"},
            {"roi": [0, 0, 10]},
            {"roi": [[0, 0], [10, 10], [0, 10], [10, 0]]},  # self-crossing
            {"lat": 91},
            {"lon": "east"},
            {"panel_id": "p1"},  # a rig camera watches no panel
            {"lat": 45.0},  # half a place: the camera would silently stay off the air map
            {"name": "x" * 201},
        ],
    )
    def test_invalid_changes_are_422_and_change_nothing(
        self, client: TestClient, admin: dict[str, str], engine: Engine, body: dict[str, object]
    ) -> None:
        assert client.post("/panels", json={"id": "p1"}, headers=admin).status_code == 201
        register(client, admin, name="East", roi=[0, 0, 10, 10])
        before = client.get("/cameras/cam", headers=admin).json()
        r = client.patch("/cameras/cam", json=body, headers=admin)
        assert r.status_code == 422, r.text
        assert r.headers["content-type"] == "application/problem+json"
        assert client.get("/cameras/cam", headers=admin).json() == before

    @pytest.mark.parametrize(
        "roi", [[40, 0, 30, 48], [0, 40, 10, 10], [[0, 0], [64, 0], [10, 40]]], ids=str
    )
    def test_a_region_outside_the_latest_frame_is_422(
        self, client: TestClient, admin: dict[str, str], roi: list[object]
    ) -> None:
        token = register(client, admin, roi=[0, 0, 24, 48])
        assert post(client, token, halves())[0] == 201  # 64×48
        r = client.patch("/cameras/cam", json={"roi": roi}, headers=admin)
        assert r.status_code == 422, r.text
        assert "64×48" in r.json()["detail"], r.json()["detail"]
        assert client.get("/cameras/cam", headers=admin).json()["roi"] == [0, 0, 24, 48]
        # a region that fits the same frame is taken
        fits = client.patch("/cameras/cam", json={"roi": [0, 0, 64, 48]}, headers=admin)
        assert fits.status_code == 200, fits.text

    def test_a_missing_panel_is_422(self, client: TestClient, admin: dict[str, str]) -> None:
        register(client, admin, kind="panel")
        r = client.patch("/cameras/cam", json={"panel_id": "nowhere"}, headers=admin)
        assert r.status_code == 422
        assert client.get("/cameras/cam", headers=admin).json()["panel_id"] is None

    def test_unknown_camera_is_404(self, client: TestClient, admin: dict[str, str]) -> None:
        r = client.patch("/cameras/ghost", json={"name": "x"}, headers=admin)
        assert r.status_code == 404
        assert r.headers["content-type"] == "application/problem+json"

    def test_only_the_admin_may_change_a_camera(
        self, client: TestClient, admin: dict[str, str]
    ) -> None:
        token = register(client, admin, name="East")
        assert client.patch("/cameras/cam", json={"name": "x"}).status_code == 401
        own = {"Authorization": f"Bearer {token}"}
        assert client.patch("/cameras/cam", json={"name": "x"}, headers=own).status_code == 403
        assert client.get("/cameras/cam", headers=admin).json()["name"] == "East"


class TestTokenRotation:
    def test_the_old_token_stops_at_once_and_the_new_one_works(
        self, client: TestClient, admin: dict[str, str], engine: Engine
    ) -> None:
        old = register(client, admin)
        assert post(client, old, make_jpeg())[0] == 201  # the old token is now cached
        r = client.post("/cameras/cam/token", headers=admin)
        assert r.status_code == 200, r.text
        new = r.json()["token"]
        assert new.startswith("vc_")
        assert new != old
        assert r.json()["id"] == "cam"

        frames = table_counts(engine)["frames"]
        status, body = post(client, old, make_jpeg(seed=1, noise=3))
        assert status == 401, body
        assert table_counts(engine)["frames"] == frames
        assert post(client, new, make_jpeg(seed=2, noise=3))[0] == 201
        # the token is shown once: the camera's own view does not carry it
        assert "token" not in client.get("/cameras/cam", headers=admin).json()

    def test_unknown_camera_is_404_and_only_the_admin_may_rotate(
        self, client: TestClient, admin: dict[str, str]
    ) -> None:
        token = register(client, admin)
        assert client.post("/cameras/ghost/token", headers=admin).status_code == 404
        own = {"Authorization": f"Bearer {token}"}
        assert client.post("/cameras/cam/token", headers=own).status_code == 403
        assert client.post("/cameras/cam/token").status_code == 401
        assert post(client, token, make_jpeg())[0] == 201  # still the camera's token


class TestRetire:
    def test_a_retired_camera_posts_nothing_and_keeps_its_history(
        self, client: TestClient, admin: dict[str, str], engine: Engine
    ) -> None:
        token = register(client, admin, name="East")
        first = client.post(
            "/cameras/cam/frames",
            content=make_jpeg(),
            headers={"Authorization": f"Bearer {token}", "Content-Type": "image/jpeg"},
        ).json()  # the token is now cached
        r = client.delete("/cameras/cam", headers=admin)
        assert r.status_code == 204, r.text
        assert r.content == b""

        counts = table_counts(engine)
        status, body = post(client, token, make_jpeg(seed=1, noise=3))  # its own token: gone
        assert status == 401, body
        r = client.post(
            "/cameras/cam/frames",
            content=make_jpeg(seed=2, noise=3),
            headers={**admin, "Content-Type": "image/jpeg"},
        )
        assert r.status_code == 409, r.text
        assert r.headers["content-type"] == "application/problem+json"
        assert r.json()["code"] == "camera_retired"
        assert table_counts(engine) == counts

        out = client.get("/cameras/cam", headers=admin).json()
        assert out["retired_at"] is not None
        assert out["name"] == "East"
        again = client.post("/cameras", json={"id": "cam", "kind": "panel"}, headers=admin)
        assert again.status_code == 409, again.text  # its history keeps the id
        assert again.json()["code"] == "camera_retired"
        assert "ids are not reused" in again.json()["detail"]
        frames = client.get("/cameras/cam/frames", headers=admin).json()
        assert [f["frame_id"] for f in frames] == [first["frame_id"]]

    def test_retired_cameras_leave_the_list_unless_asked_for(
        self, client: TestClient, admin: dict[str, str]
    ) -> None:
        for camera in ("a", "b", "c"):
            r = client.post("/cameras", json={"id": camera, "kind": "rig"}, headers=admin)
            assert r.status_code == 201
        assert client.delete("/cameras/b", headers=admin).status_code == 204
        listed = client.get("/cameras", headers=admin).json()
        assert [c["id"] for c in listed] == ["a", "c"]
        assert all(c["retired_at"] is None for c in listed)
        every = client.get("/cameras", params={"retired": True}, headers=admin).json()
        assert [(c["id"], c["retired_at"] is None) for c in every] == [
            ("a", True),
            ("b", False),
            ("c", True),
        ]

    def test_retiring_again_changes_nothing_and_the_id_stays_taken(
        self, client: TestClient, admin: dict[str, str]
    ) -> None:
        register(client, admin)
        assert client.delete("/cameras/cam", headers=admin).status_code == 204
        when = client.get("/cameras/cam", headers=admin).json()["retired_at"]
        assert client.delete("/cameras/cam", headers=admin).status_code == 204
        assert client.get("/cameras/cam", headers=admin).json()["retired_at"] == when
        r = client.post("/cameras", json={"id": "cam", "kind": "rig"}, headers=admin)
        assert r.status_code == 409

    def test_a_retired_camera_cannot_be_changed_or_given_a_token(
        self, client: TestClient, admin: dict[str, str]
    ) -> None:
        register(client, admin, name="East")
        assert client.delete("/cameras/cam", headers=admin).status_code == 204
        before = client.get("/cameras/cam", headers=admin).json()
        for r in (
            client.patch("/cameras/cam", json={"name": "West"}, headers=admin),
            client.post("/cameras/cam/token", headers=admin),
        ):
            assert r.status_code == 409, r.text
            assert r.json()["code"] == "camera_retired"
        assert client.get("/cameras/cam", headers=admin).json() == before

    def test_unknown_camera_is_404_and_only_the_admin_may_retire(
        self, client: TestClient, admin: dict[str, str]
    ) -> None:
        token = register(client, admin)
        assert client.delete("/cameras/ghost", headers=admin).status_code == 404
        assert client.delete("/cameras/cam").status_code == 401
        own = {"Authorization": f"Bearer {token}"}
        assert client.delete("/cameras/cam", headers=own).status_code == 403
        assert client.get("/cameras/cam", headers=admin).json()["retired_at"] is None
        assert post(client, token, make_jpeg())[0] == 201


@pytest.mark.parametrize("change", ["token replaced", "camera retired"])
def test_a_change_made_by_another_process_stops_the_next_frame(
    client: TestClient, admin: dict[str, str], engine: Engine, change: str
) -> None:
    token = register(client, admin)
    assert post(client, token, halves())[0] == 201  # this process now keeps the camera
    before = table_counts(engine)
    # another process replaces the token, or retires the camera: this one is not told
    values: dict[str, object] = (
        {"token_hash": hash_token("vc_elsewhere")}
        if change == "token replaced"
        else {"retired_at": datetime(2026, 1, 1, tzinfo=UTC)}
    )
    with engine.begin() as conn:
        conn.execute(update(Camera).where(Camera.id == "cam").values(**values))
    status, body = post(client, token, halves())
    assert status == 401, body
    assert body["detail"] == "unknown token: it was replaced, or its camera retired"
    assert table_counts(engine) == before  # no frame, no verdict
    # and this process has forgotten the camera: the next upload is looked up again (and, its
    # token now unknown, refused before its body is read, not by the writer)
    status, body = post(client, token, halves())
    assert status == 401, body
    if change == "token replaced":
        assert body["detail"] == "unknown token"
        # an operator's upload with the admin token is not a camera token's: stored
        r = client.post(
            "/cameras/cam/frames", content=halves(), headers={**admin, "Content-Type": "image/jpeg"}
        )
        assert r.status_code == 201, r.text


@pytest.mark.parametrize("token", ["camera's", "admin"])
def test_a_region_changed_by_another_process_measures_the_next_frame_in_it(
    client: TestClient, admin: dict[str, str], engine: Engine, token: str
) -> None:
    own = register(client, admin, roi=[0, 0, 32, 48])
    auth = {"Authorization": f"Bearer {own}"} if token == "camera's" else admin

    def upload() -> dict[str, object]:
        r = client.post(
            "/cameras/cam/frames", content=halves(), headers={**auth, "Content-Type": "image/jpeg"}
        )
        assert r.status_code == 201, r.text
        body: dict[str, object] = r.json()
        return body

    assert near(modes(upload()), LEFT)  # this process now keeps the camera
    # another process moves the region to the right half: this one is not told
    with engine.begin() as conn:
        conn.execute(update(Camera).where(Camera.id == "cam").values(roi=[32, 0, 32, 48]))
    body = upload()
    assert near(modes(body), RIGHT), body  # measured again, in the region as it is now
    verdict = body["verdict"]
    assert isinstance(verdict, dict)
    assert verdict["roi"] == [32, 0, 32, 48]
    assert near(modes(upload()), RIGHT)
    frames = client.get("/cameras/cam/frames", headers=admin).json()
    assert len(frames) == 3  # each frame stored once


def test_a_camera_moved_to_another_panel_by_another_process_judges_that_one(
    client: TestClient, admin: dict[str, str], engine: Engine
) -> None:
    for pid in ("p1", "p2"):
        assert client.post("/panels", json={"id": pid}, headers=admin).status_code == 201
    own = register(client, admin, kind="panel", panel_id="p1")
    status, body = post(client, own, halves())
    assert status == 201, body
    assert body["verdict"]["panel_id"] == "p1"  # type: ignore[index]
    with engine.begin() as conn:  # another process re-attaches the camera
        conn.execute(update(Camera).where(Camera.id == "cam").values(panel_id="p2"))
    status, body = post(client, own, halves())
    assert status == 201, body
    assert body["verdict"]["panel_id"] == "p2"  # type: ignore[index]
    p1 = client.get("/panels/p1/status", headers=admin).json()
    assert p1["last_verdict"]["frame_id"] != body["frame_id"]


def test_a_camera_that_keeps_changing_is_told_to_send_the_frame_again(
    client: TestClient, admin: dict[str, str], engine: Engine, app: Any
) -> None:
    own = register(client, admin)
    before = table_counts(engine)
    measured: list[object] = []
    # every batch finds the camera changed again (other processes changing it meanwhile)
    app.state.writer._check = lambda session, credentials: (
        measured.append(credentials) or dict.fromkeys(credentials, "changed")
    )
    r = client.post(
        "/cameras/cam/frames",
        content=halves(),
        headers={"Authorization": f"Bearer {own}", "Content-Type": "image/jpeg"},
    )
    assert r.status_code == 503, r.text
    assert r.json()["code"] == "camera_changing"
    assert r.headers["retry-after"] == "1"
    assert len(measured) == 3  # measured three times, then given up
    assert table_counts(engine) == before


def test_the_token_cache_forgets_one_camera() -> None:
    cache = TokenCache()
    a = CameraInfo("a", CameraKind.rig, None, None)
    b = CameraInfo("b", CameraKind.rig, None, None)
    cache.put("h1", a)
    cache.put("h2", a)
    cache.put("h3", b)
    cache.forget("a")
    assert (cache.get("h1"), cache.get("h2"), cache.get("h3")) == (None, None, b)


def test_a_cache_time_of_zero_keeps_nothing(monkeypatch: pytest.MonkeyPatch) -> None:
    # the clock stands still: an entry kept for 0 s would still be in date when read
    monkeypatch.setattr("app.platform.frames.camera_info.time.monotonic", lambda: 100.0)
    cache = TokenCache(ttl=0)
    cache.put("h1", CameraInfo("a", CameraKind.rig, None, None))
    assert cache.get("h1") is None


def test_a_camera_registered_as_the_wrong_kind_is_corrected_before_its_first_frame(
    client: TestClient, admin: dict[str, str], engine: Engine
) -> None:
    """A sky camera registered as a panel camera by mistake: its kind changes while it has
    stored no frame (its id was burnt before: retired, an id is never registered again), and
    its next frame is judged as a sky. Once it has frames, a change of kind is 409 and changes
    nothing. A kind goes with the panel_id it needs or must not have; it cannot be cleared."""
    assert client.post("/panels", json={"id": "p"}, headers=admin).status_code == 201
    token = register(client, admin, kind="panel", panel_id="p", roi=[0, 0, 64, 24])
    r = client.patch("/cameras/cam", json={"kind": "sky"}, headers=admin)
    assert r.status_code == 422, r.text  # a sky camera watches no panel
    assert "panel_id is only for panel cameras" in r.json()["detail"]
    assert client.patch("/cameras/cam", json={"kind": None}, headers=admin).status_code == 422
    r = client.patch("/cameras/cam", json={"kind": "sky", "panel_id": None}, headers=admin)
    assert r.status_code == 200, r.text
    assert (r.json()["kind"], r.json()["panel_id"], r.json()["roi"]) == (
        "sky",
        None,
        [0, 0, 64, 24],
    )
    up = client.post(
        "/cameras/cam/frames",
        content=make_jpeg(noise=3),
        headers={"Authorization": f"Bearer {token}", "Content-Type": "image/jpeg"},
    )
    assert up.status_code == 201, up.text
    assert "level" in up.json()["verdict"]  # a sky verdict, not a panel's
    assert "clean" not in up.json()["verdict"]

    before = table_counts(engine)
    r = client.patch("/cameras/cam", json={"kind": "rig"}, headers=admin)
    assert r.status_code == 409, r.text
    assert r.json()["code"] == "camera_has_frames"
    assert client.get("/cameras/cam", headers=admin).json()["kind"] == "sky"
    assert table_counts(engine) == before
    # the same kind again is no change
    assert client.patch("/cameras/cam", json={"kind": "sky"}, headers=admin).status_code == 200


def test_a_kind_changed_by_another_process_judges_the_next_frame_as_that_kind(
    client: TestClient, admin: dict[str, str], engine: Engine
) -> None:
    """This process keeps the camera's snapshot (a rig); another changes its kind to sky before
    its first frame: the batch's check finds the kind changed, and the frame is measured again
    as a sky, not stored as a rig's."""
    token = register(client, admin)
    headers = {"Authorization": f"Bearer {token}", "Content-Type": "image/jpeg"}
    assert client.get("/cameras/cam/frames", headers=admin).json() == []
    # cache the snapshot here: an upload refused after authentication (a PNG)
    png = cv2.imencode(".png", np.zeros((8, 8, 3), np.uint8))[1].tobytes()
    assert client.post("/cameras/cam/frames", content=png, headers=headers).status_code == 415
    with engine.begin() as conn:
        conn.execute(update(Camera).where(Camera.id == "cam").values(kind=CameraKind.sky))
    r = client.post("/cameras/cam/frames", content=make_jpeg(noise=3), headers=headers)
    assert r.status_code == 201, r.text
    assert "level" in r.json()["verdict"], r.json()
