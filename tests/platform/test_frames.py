"""Frame ingest over HTTP: storage, verdicts, and every kind of bad input."""

from __future__ import annotations

import base64
import json
from datetime import UTC, datetime, timedelta
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
from fastapi.testclient import TestClient
from sqlalchemy import Engine

from app.platform.frames.storage import PACK_HEADER
from tests.factories import make_jpeg, stalled_writer, table_counts

DAY = (datetime.now(UTC) - timedelta(days=2)).date().isoformat()
"""A recent day: frames taken before the history the service keeps are refused."""


def bomb_jpeg(width: int = 60000, height: int = 60000) -> bytes:
    """A genuine 1×1 JPEG whose start-of-frame header is patched to claim ``width``×``height``."""
    data = bytearray(make_jpeg(1, 1))
    sof = data.index(b"\xff\xc0")
    data[sof + 5 : sof + 7] = height.to_bytes(2, "big")
    data[sof + 7 : sof + 9] = width.to_bytes(2, "big")
    return bytes(data)


def png_bytes() -> bytes:
    ok, buf = cv2.imencode(".png", np.zeros((8, 8, 3), np.uint8))
    assert ok
    return buf.tobytes()


@pytest.fixture
def camera(client: TestClient, admin: dict[str, str]) -> dict[str, Any]:
    r = client.post("/cameras", json={"id": "cam-1", "kind": "rig"}, headers=admin)
    assert r.status_code == 201, r.text
    return r.json()


def cam_headers(camera: dict[str, Any]) -> dict[str, str]:
    return {"Authorization": f"Bearer {camera['token']}", "Content-Type": "image/jpeg"}


def stored_files(data_dir: Path) -> list[tuple[str, int]]:
    """Every file of the frame store (packs, and frames stored as files of their own), with
    its size: a pack that grew shows."""
    return sorted(
        (str(p.relative_to(data_dir)), p.stat().st_size)
        for sub in ("packs", "frames")
        for p in (data_dir / sub).rglob("*")
        if p.is_file()
    )


@pytest.fixture
def snapshot(engine: Engine, settings: Any, camera: dict[str, Any]) -> Any:
    """What the database and the frame store hold: a refused upload leaves both as they were."""

    def take() -> tuple[dict[str, int], list[tuple[str, int]]]:
        return table_counts(engine), stored_files(settings.data_dir)

    return take


class TestPostFrame:
    def test_raw_jpeg_is_stored_with_its_verdict(
        self, client: TestClient, camera: dict[str, Any], admin: dict[str, str], settings: Any
    ) -> None:
        body = make_jpeg(64, 48, (90, 140, 200))
        r = client.post(
            "/cameras/cam-1/frames",
            content=body,
            headers=cam_headers(camera),
            params={"captured_at": f"{DAY}T12:00:00Z"},
        )
        assert r.status_code == 201, r.text
        out = r.json()
        assert out["camera_id"] == "cam-1"
        assert out["captured_at"].startswith(f"{DAY}T12:00:00")
        assert (out["width"], out["height"]) == (64, 48)
        # a flat colour survives JPEG to within a level or two
        np.testing.assert_allclose(out["verdict"]["modes"], [90, 140, 200], atol=2)
        np.testing.assert_allclose(out["verdict"]["means"], [90, 140, 200], atol=2)
        files = stored_files(settings.data_dir)
        assert [size for _, size in files] == [PACK_HEADER.size + len(body)]  # one pack
        assert (settings.data_dir / files[0][0]).read_bytes()[PACK_HEADER.size :] == body
        image = client.get(f"/frames/{out['frame_id']}/image", headers=admin)
        assert image.status_code == 200
        assert image.content == body
        listed = client.get("/cameras/cam-1/frames", headers=admin).json()
        assert [f["frame_id"] for f in listed] == [out["frame_id"]]

    def test_the_frames_of_a_time_range_are_listed(
        self, client: TestClient, camera: dict[str, Any], admin: dict[str, str]
    ) -> None:
        """A camera's frames taken in [since, until), newest first, paged within the range."""
        ids = {}
        for hour in range(8, 14):
            r = client.post(
                "/cameras/cam-1/frames",
                content=make_jpeg(16, 16, (hour * 10, 0, 0)),
                headers=cam_headers(camera),
                params={"captured_at": f"{DAY}T{hour:02d}:00:00Z"},
            )
            ids[hour] = r.json()["frame_id"]

        def listed(**params: Any) -> list[str]:
            r = client.get("/cameras/cam-1/frames", params=params, headers=admin)
            assert r.status_code == 200, r.text
            return [f["frame_id"] for f in r.json()]

        day = {"since": f"{DAY}T09:00:00Z", "until": f"{DAY}T12:00:00Z"}
        assert listed(**day) == [ids[11], ids[10], ids[9]]
        assert listed(**day, limit=2, offset=2) == [ids[9]]
        assert listed(since=f"{DAY}T14:00:00+01:00") == [ids[13]]  # 13:00 UTC
        assert listed(until=f"{DAY}T09:00:00") == [ids[8]]  # no offset: UTC
        r = client.get(
            "/cameras/cam-1/frames", params={**day, "until": day["since"]}, headers=admin
        )
        assert r.status_code == 422
        r = client.get("/cameras/nope/frames", params=day, headers=admin)
        assert r.status_code == 404

    def test_captured_at_outside_the_history_kept_is_refused(
        self, client: TestClient, camera: dict[str, Any], engine: Engine, settings: Any
    ) -> None:
        """Not more than 10 minutes ahead, and not before the history kept (30 days here): a
        camera whose clock was reset to 1970 had every frame stored and graded, then shown
        nowhere (neither as a sky camera's latest reading nor on the map, and a panel took
        each for a late upload)."""
        assert settings.frame_retention_days == 30
        assert settings.history_retention_days is None
        now = datetime.now(UTC)
        refused = [
            now + timedelta(minutes=20),
            datetime(1970, 1, 1, tzinfo=UTC),
            datetime(2000, 1, 1, tzinfo=UTC),
            now - timedelta(days=30, minutes=5),
        ]
        before = table_counts(engine), stored_files(settings.data_dir)
        for when in refused:
            r = client.post(
                "/cameras/cam-1/frames",
                content=make_jpeg(seed=1, noise=3),
                headers=cam_headers(camera),
                params={"captured_at": when.isoformat()},
            )
            assert (r.status_code, r.json()["code"]) == (422, "bad_time"), r.text
            assert r.headers["content-type"] == "application/problem+json"
        assert (table_counts(engine), stored_files(settings.data_dir)) == before
        assert "is the camera's clock set" in r.json()["detail"]
        for i, when in enumerate([now + timedelta(minutes=5), now - timedelta(days=29)]):
            r = client.post(
                "/cameras/cam-1/frames",
                content=make_jpeg(seed=2 + i, noise=3),
                headers=cam_headers(camera),
                params={"captured_at": when.isoformat()},
            )
            assert r.status_code == 201, r.text

    def test_an_archive_within_the_history_kept_is_a_backfill(
        self, app: Any, settings: Any, admin: dict[str, str]
    ) -> None:
        """Rows kept for a year (history_retention_days): a camera's frames are taken within
        the upload window (frame_retention_days, 30 here); an admin imports an archive of the
        last year with backfill=true; a camera may not backfill (403), and nothing older than
        the history kept is taken. (``app`` empties the tables; this test runs an app of its
        own settings.)"""
        from app.main import create_app

        year = create_app(settings.model_copy(update={"history_retention_days": 365.0}))
        with TestClient(year, raise_server_exceptions=False) as client:
            r = client.post("/cameras", json={"id": "cam-1", "kind": "rig"}, headers=admin)
            camera = cam_headers(r.json())

            def post(days: int, headers: dict[str, str], **extra: str) -> Any:
                taken = (datetime.now(UTC) - timedelta(days=days)).isoformat()
                return client.post(
                    "/cameras/cam-1/frames",
                    content=make_jpeg(seed=days, noise=3),
                    headers={**headers, "Content-Type": "image/jpeg"},
                    params={"captured_at": taken, **extra},
                )

            assert post(29, camera).status_code == 201
            old = post(200, camera)
            assert (old.status_code, old.json()["code"]) == (422, "bad_time")
            assert "backfill=true" in old.json()["detail"]
            assert post(200, camera, backfill="true").status_code == 403
            assert post(200, admin, backfill="true").status_code == 201
            too_old = post(366, admin, backfill="true")
            assert (too_old.status_code, too_old.json()["code"]) == (422, "bad_time")
            assert "before the history this service keeps" in too_old.json()["detail"]

    @pytest.mark.parametrize("sent", [f"{DAY}T13:00:00", f"{DAY}T15:00:00+02:00"])
    def test_captured_at_without_an_offset_is_utc_and_one_with_is_converted(
        self, client: TestClient, camera: dict[str, Any], sent: str
    ) -> None:
        r = client.post(
            "/cameras/cam-1/frames",
            content=make_jpeg(),
            headers=cam_headers(camera),
            params={"captured_at": sent},
        )
        assert r.status_code == 201, r.text
        assert r.json()["captured_at"] == f"{DAY}T13:00:00Z"

    def test_multipart_upload(self, client: TestClient, camera: dict[str, Any]) -> None:
        r = client.post(
            "/cameras/cam-1/frames",
            files={"file": ("f.jpg", make_jpeg(), "image/jpeg")},
            headers={"Authorization": f"Bearer {camera['token']}"},
        )
        assert r.status_code == 201, r.text

    def test_multipart_captured_at_field(
        self, client: TestClient, camera: dict[str, Any], snapshot: Any
    ) -> None:
        """An IP camera posting a form sends its time as a field beside the file: it is the
        frame's time, as the query parameter is. Before, it was ignored (the frame took the
        time it was received)."""
        auth = {"Authorization": f"Bearer {camera['token']}"}
        r = client.post(
            "/cameras/cam-1/frames",
            files={"file": ("f.jpg", make_jpeg(), "image/jpeg")},
            data={"captured_at": f"{DAY}T12:00:00+02:00"},
            headers=auth,
        )
        assert r.status_code == 201, r.text
        assert r.json()["captured_at"] == f"{DAY}T10:00:00Z"
        same = client.post(  # both, agreeing
            "/cameras/cam-1/frames",
            files={"file": ("f.jpg", make_jpeg(seed=1, noise=2), "image/jpeg")},
            data={"captured_at": f"{DAY}T11:00:00Z"},
            params={"captured_at": f"{DAY}T11:00:00Z"},
            headers=auth,
        )
        assert same.status_code == 201, same.text
        before = snapshot()
        for data, params in [
            ({"captured_at": "yesterday"}, {}),
            ({"captured_at": "1970-01-01T00:00:00Z"}, {}),
            ({"captured_at": f"{DAY}T11:00:00Z"}, {"captured_at": f"{DAY}T11:30:00Z"}),
            ({"captured_at": [f"{DAY}T11:00:00Z", f"{DAY}T11:30:00Z"]}, {}),
        ]:
            bad = client.post(
                "/cameras/cam-1/frames",
                files={"file": ("f.jpg", make_jpeg(seed=2, noise=2), "image/jpeg")},
                data=data,
                params=params,
                headers=auth,
            )
            assert bad.status_code == 422, (data, params)
            assert bad.json()["code"] == "bad_time"
        assert snapshot() == before

    def test_a_compressed_body_is_refused_with_its_reason(
        self, client: TestClient, camera: dict[str, Any], snapshot: Any
    ) -> None:
        import gzip

        before = snapshot()
        r = client.post(
            "/cameras/cam-1/frames",
            content=gzip.compress(make_jpeg()),
            headers={**cam_headers(camera), "Content-Encoding": "gzip"},
        )
        assert r.status_code == 415
        assert r.json()["code"] == "content_encoding"
        assert r.headers["accept-encoding"] == "identity"
        assert snapshot() == before

    def test_basic_auth_with_camera_id_and_token(
        self, client: TestClient, camera: dict[str, Any]
    ) -> None:
        cred = base64.b64encode(f"cam-1:{camera['token']}".encode()).decode()
        headers = {"Authorization": f"Basic {cred}", "Content-Type": "image/jpeg"}
        r = client.post("/cameras/cam-1/frames", content=make_jpeg(), headers=headers)
        assert r.status_code == 201, r.text

    def test_admin_may_post(
        self, client: TestClient, camera: dict[str, Any], admin: dict[str, str]
    ) -> None:
        r = client.post(
            "/cameras/cam-1/frames",
            content=make_jpeg(),
            headers={**admin, "Content-Type": "image/jpeg"},
        )
        assert r.status_code == 201

    def test_roi_restricts_the_statistics(self, client: TestClient, admin: dict[str, str]) -> None:
        cam = client.post(
            "/cameras", json={"id": "c", "kind": "rig", "roi": [0, 0, 32, 48]}, headers=admin
        ).json()
        image = np.zeros((48, 64, 3), np.uint8)
        image[:, :32] = (200, 30, 30)  # left half red (RGB) inside the ROI
        image[:, 32:] = (10, 10, 250)
        ok, buf = cv2.imencode(".jpg", image[:, :, ::-1].copy(), [cv2.IMWRITE_JPEG_QUALITY, 100])
        r = client.post("/cameras/c/frames", content=buf.tobytes(), headers=cam_headers(cam))
        assert r.status_code == 201, r.text
        np.testing.assert_allclose(r.json()["verdict"]["modes"], [200, 30, 30], atol=3)

    def test_polygon_roi_restricts_the_statistics(
        self, client: TestClient, admin: dict[str, str]
    ) -> None:
        """Sky above a sloping skyline: a triangle of blue over a dark building. The polygon's
        statistics are the sky's alone; its bounding rectangle would mix in the building."""
        triangle = [[0, 0], [63, 0], [0, 47]]
        cam = client.post(
            "/cameras", json={"id": "s", "kind": "rig", "roi": triangle}, headers=admin
        ).json()
        assert cam["roi"] == triangle
        image = np.full((48, 64, 3), (40, 40, 40), np.uint8)
        yy, xx = np.mgrid[0:48, 0:64]
        image[xx / 63 + yy / 47 <= 1.02] = (120, 160, 230)  # the sky, up to the diagonal
        jpeg = cv2.imencode(".jpg", image[:, :, ::-1].copy(), [cv2.IMWRITE_JPEG_QUALITY, 100])[1]
        r = client.post("/cameras/s/frames", content=jpeg.tobytes(), headers=cam_headers(cam))
        assert r.status_code == 201, r.text
        verdict = r.json()["verdict"]
        np.testing.assert_allclose(verdict["modes"], [120, 160, 230], atol=3)
        np.testing.assert_allclose(verdict["means"], [120, 160, 230], atol=8)

    @pytest.mark.parametrize(
        ("roi", "why"),
        [
            ([[0, 0], [10, 10]], "3 to 64"),
            ([[0, 0], [10, 10], [10, 0], [0, 10]], "not simple"),  # a bow tie
            ([[0, 0], [5, 5], [10, 10]], "no area"),
            ([[0, 0], [-1, 5], [10, 10]], "x, y ≥ 0"),
            ([[0, 0, 1], [5, 5], [10, 0]], "[x, y]"),
        ],
    )
    def test_bad_polygon_roi(
        self, client: TestClient, admin: dict[str, str], roi: list, why: str
    ) -> None:
        r = client.post("/cameras", json={"id": "s", "kind": "sky", "roi": roi}, headers=admin)
        assert r.status_code == 422
        assert why in r.text
        assert client.get("/cameras/s", headers=admin).status_code == 404

    def test_polygon_roi_outside_frame(self, client: TestClient, admin: dict[str, str]) -> None:
        cam = client.post(
            "/cameras",
            json={"id": "s", "kind": "sky", "roi": [[0, 0], [700, 0], [0, 40]]},
            headers=admin,
        ).json()
        r = client.post("/cameras/s/frames", content=make_jpeg(), headers=cam_headers(cam))
        assert r.status_code == 422
        assert "does not lie inside" in r.json()["detail"]

    def test_identical_bytes_are_two_frames_each_served(
        self, client: TestClient, camera: dict[str, Any], admin: dict[str, str], settings: Any
    ) -> None:
        body = make_jpeg()
        posted = [
            client.post("/cameras/cam-1/frames", content=body, headers=cam_headers(camera))
            for _ in range(2)
        ]
        assert [r.status_code for r in posted] == [201, 201]
        assert len({r.json()["frame_id"] for r in posted}) == 2
        for r in posted:
            image = client.get(f"/frames/{r.json()['frame_id']}/image", headers=admin)
            assert image.content == body
        # both rows point at one copy in the pack (``DiskFrameStore.put``)
        assert [size for _, size in stored_files(settings.data_dir)] == [
            PACK_HEADER.size + len(body)
        ]

    def test_verdict_kind_follows_camera_kind(
        self, client: TestClient, admin: dict[str, str]
    ) -> None:
        client.post("/panels", json={"id": "p1"}, headers=admin)
        panel_cam = client.post(
            "/cameras", json={"id": "pc", "kind": "panel", "panel_id": "p1"}, headers=admin
        ).json()
        sky_cam = client.post("/cameras", json={"id": "sc", "kind": "sky"}, headers=admin).json()
        pv = client.post(
            "/cameras/pc/frames", content=make_jpeg(), headers=cam_headers(panel_cam)
        ).json()
        sv = client.post(
            "/cameras/sc/frames", content=make_jpeg(), headers=cam_headers(sky_cam)
        ).json()
        assert pv["verdict"]["panel_id"] == "p1"
        assert "clean" in pv["verdict"]
        assert "level" in sv["verdict"]
        assert "category" in sv["verdict"]


class TestBadInput:
    """Each bad upload gets the contract's 4xx as problem+json and leaves nothing behind."""

    @pytest.mark.parametrize(
        ("body", "content_type", "status"),
        [
            pytest.param(b"", "image/jpeg", 422, id="empty"),
            pytest.param(make_jpeg(320, 240, noise=30)[:2000], "image/jpeg", 422, id="truncated"),
            pytest.param(
                b"\xff\xd8\xff\xe0garbage" * 10 + b"\xff\xd9", "image/jpeg", 422, id="garbage"
            ),
            pytest.param(png_bytes(), "image/jpeg", 415, id="png-as-jpeg"),
            pytest.param(bomb_jpeg(), "image/jpeg", 422, id="bomb-60000x60000"),
            pytest.param(make_jpeg(), "text/plain", 415, id="wrong-content-type"),
        ],
    )
    def test_refused_and_nothing_stored(
        self,
        client: TestClient,
        camera: dict[str, Any],
        snapshot: Any,
        body: bytes,
        content_type: str,
        status: int,
    ) -> None:
        before = snapshot()
        headers = {**cam_headers(camera), "Content-Type": content_type}
        r = client.post("/cameras/cam-1/frames", content=body, headers=headers)
        assert r.status_code == status, r.text
        assert r.headers["content-type"] == "application/problem+json"
        problem = r.json()
        assert problem["status"] == status
        assert problem["title"]
        assert problem["detail"]
        assert snapshot() == before

    def test_bomb_is_refused_from_the_header(
        self, client: TestClient, camera: dict[str, Any]
    ) -> None:
        r = client.post("/cameras/cam-1/frames", content=bomb_jpeg(), headers=cam_headers(camera))
        assert r.status_code == 422
        assert "3600000000 pixels" in r.json()["detail"]

    def test_body_over_limit(
        self, client: TestClient, camera: dict[str, Any], snapshot: Any, settings: Any
    ) -> None:
        before = snapshot()
        big = b"\xff\xd8" + b"\0" * settings.max_body_bytes
        r = client.post("/cameras/cam-1/frames", content=big, headers=cam_headers(camera))
        assert r.status_code == 413
        assert r.headers["content-type"] == "application/problem+json"

        def chunks() -> Any:  # no Content-Length: the cap must hold while streaming
            for _ in range(settings.max_body_bytes // 65536 + 2):
                yield b"\0" * 65536

        r = client.post("/cameras/cam-1/frames", content=chunks(), headers=cam_headers(camera))
        assert r.status_code == 413
        assert snapshot() == before

    def test_unknown_camera(self, client: TestClient, admin: dict[str, str], snapshot: Any) -> None:
        before = snapshot()
        r = client.post(
            "/cameras/nope/frames",
            content=make_jpeg(),
            headers={**admin, "Content-Type": "image/jpeg"},
        )
        assert r.status_code == 404
        assert r.headers["content-type"] == "application/problem+json"
        assert snapshot() == before

    def test_another_cameras_token(
        self, client: TestClient, admin: dict[str, str], camera: dict[str, Any], snapshot: Any
    ) -> None:
        client.post("/cameras", json={"id": "cam-2", "kind": "rig"}, headers=admin)
        before = snapshot()
        r = client.post("/cameras/cam-2/frames", content=make_jpeg(), headers=cam_headers(camera))
        assert r.status_code == 403
        assert r.headers["content-type"] == "application/problem+json"
        assert snapshot() == before

    @pytest.mark.parametrize(
        "value",
        [
            "yesterday",
            "2026-13-01T00:00:00Z",
            "2999-01-01T00:00:00Z",
            "0001-01-01T00:00:00+14:00",  # before year 1 in UTC
            "9999-12-31T23:59:59-14:00",  # after 9999 in UTC
        ],
    )
    def test_malformed_captured_at(
        self, client: TestClient, camera: dict[str, Any], snapshot: Any, value: str
    ) -> None:
        before = snapshot()
        r = client.post(
            "/cameras/cam-1/frames",
            content=make_jpeg(),
            headers=cam_headers(camera),
            params={"captured_at": value},
        )
        assert r.status_code == 422
        assert r.headers["content-type"] == "application/problem+json"
        assert snapshot() == before

    @pytest.mark.parametrize(
        ("path", "status"),
        [("/cameras/a/b/frames", 404), (f"/cameras/{'x' * 200}/frames", 422)],
        ids=["slash", "200-chars"],
    )
    def test_bad_camera_id(
        self, client: TestClient, admin: dict[str, str], snapshot: Any, path: str, status: int
    ) -> None:
        before = snapshot()
        r = client.post(path, content=make_jpeg(), headers={**admin, "Content-Type": "image/jpeg"})
        assert r.status_code == status
        assert r.headers["content-type"] == "application/problem+json"
        assert snapshot() == before

    def test_roi_outside_frame(
        self, client: TestClient, admin: dict[str, str], engine: Engine
    ) -> None:
        cam = client.post(
            "/cameras", json={"id": "c2", "kind": "rig", "roi": [600, 400, 100, 100]}, headers=admin
        ).json()
        before = table_counts(engine)
        r = client.post("/cameras/c2/frames", content=make_jpeg(64, 48), headers=cam_headers(cam))
        assert r.status_code == 422
        assert "does not lie inside" in r.json()["detail"]
        assert table_counts(engine) == before

    def test_multipart_without_file_field(
        self, client: TestClient, camera: dict[str, Any], snapshot: Any
    ) -> None:
        before = snapshot()
        r = client.post(
            "/cameras/cam-1/frames",
            files={"other": ("f.jpg", make_jpeg(), "image/jpeg")},
            headers={"Authorization": f"Bearer {camera['token']}"},
        )
        assert r.status_code == 422
        assert r.json()["detail"] == (
            "multipart body has no file in field 'file' (its file is in 'other': name that"
            " field 'file')"
        )
        assert snapshot() == before

    def test_a_jpeg_labelled_octet_stream_is_taken(
        self, client: TestClient, camera: dict[str, Any], snapshot: Any
    ) -> None:
        """Cameras and scripts label a raw upload application/octet-stream: the bytes are a
        JPEG or are refused as any other upload (415 for a PNG, nothing stored)."""
        auth = {"Authorization": f"Bearer {camera['token']}"}
        octets = {**auth, "Content-Type": "application/octet-stream"}
        r = client.post("/cameras/cam-1/frames", content=make_jpeg(), headers=octets)
        assert r.status_code == 201, r.text
        # older camera firmware labels its JPEGs image/pjpeg: taken alike (it was 415)
        pjpeg = {**auth, "Content-Type": "image/pjpeg"}
        r = client.post("/cameras/cam-1/frames", content=make_jpeg(seed=3), headers=pjpeg)
        assert r.status_code == 201, r.text
        before = snapshot()
        png = client.post("/cameras/cam-1/frames", content=png_bytes(), headers=octets)
        assert png.status_code == 415
        assert snapshot() == before

    def test_rejections_are_counted(
        self, client: TestClient, camera: dict[str, Any], admin: dict[str, str]
    ) -> None:
        client.post("/cameras/cam-1/frames", content=png_bytes(), headers=cam_headers(camera))
        metrics = client.get("/metrics", headers=admin).text
        assert 'vantage_frames_rejected_total{camera_id="cam-1",reason="not_jpeg"}' in metrics


class TestIdempotency:
    def test_same_key_gets_the_original(
        self, client: TestClient, camera: dict[str, Any], engine: Engine
    ) -> None:
        headers = {**cam_headers(camera), "Idempotency-Key": "upload-42"}
        first = client.post(
            "/cameras/cam-1/frames", content=make_jpeg(seed=1, noise=5), headers=headers
        )
        again = client.post(
            "/cameras/cam-1/frames", content=make_jpeg(seed=1, noise=5), headers=headers
        )
        assert (first.status_code, again.status_code) == (201, 201)
        assert again.json() == first.json()
        assert again.headers["idempotent-replay"] == "true"
        assert "idempotent-replay" not in first.headers
        assert table_counts(engine)["frames"] == 1

    def test_a_key_used_again_for_another_frame_is_refused(
        self, client: TestClient, camera: dict[str, Any], engine: Engine
    ) -> None:
        """A camera whose key counter restarted (a reboot) sent a new frame under an old key:
        it got the old frame's 201 (a replay), and the new frame was lost without a word."""
        headers = {**cam_headers(camera), "Idempotency-Key": "1"}
        first = client.post(
            "/cameras/cam-1/frames", content=make_jpeg(seed=1, noise=5), headers=headers
        )
        assert first.status_code == 201, first.text
        counts = table_counts(engine)
        other = client.post(
            "/cameras/cam-1/frames", content=make_jpeg(seed=9, noise=5), headers=headers
        )
        assert other.status_code == 422, other.text
        assert other.headers["content-type"] == "application/problem+json"
        assert other.json()["code"] == "idempotency_key_reused"
        assert first.json()["frame_id"] in other.json()["detail"]
        assert table_counts(engine) == counts
        fresh = {**headers, "Idempotency-Key": "1-after-reboot"}
        r = client.post("/cameras/cam-1/frames", content=make_jpeg(seed=9, noise=5), headers=fresh)
        assert r.status_code == 201, r.text
        assert r.json()["frame_id"] != first.json()["frame_id"]

    def test_same_bytes_and_capture_time(
        self, client: TestClient, camera: dict[str, Any], engine: Engine
    ) -> None:
        body = make_jpeg(seed=2, noise=5)
        params = {"captured_at": f"{DAY}T12:00:00Z"}
        r1 = client.post(
            "/cameras/cam-1/frames", content=body, headers=cam_headers(camera), params=params
        )
        r2 = client.post(
            "/cameras/cam-1/frames", content=body, headers=cam_headers(camera), params=params
        )
        assert r2.json()["frame_id"] == r1.json()["frame_id"]
        # a new capture time is a new frame, though the bytes are the same
        r3 = client.post(
            "/cameras/cam-1/frames",
            content=body,
            headers=cam_headers(camera),
            params={"captured_at": f"{DAY}T12:01:00Z"},
        )
        assert r3.json()["frame_id"] != r1.json()["frame_id"]
        assert table_counts(engine)["frames"] == 2

    def test_a_retry_stores_no_second_copy_of_the_bytes(
        self, client: TestClient, camera: dict[str, Any], app: Any, admin: dict[str, str]
    ) -> None:
        """A retried 550 kB frame was written into the pack again and kept for the whole
        retention; the replay now points at the copy already there."""
        store = app.state.frame_store
        body = make_jpeg(seed=4, noise=5)
        headers = {**cam_headers(camera), "Idempotency-Key": "once"}
        first = client.post("/cameras/cam-1/frames", content=body, headers=headers)
        again = client.post("/cameras/cam-1/frames", content=body, headers=headers)
        assert again.headers["idempotent-replay"] == "true"
        (pack,) = store.packs()
        assert (store.root / pack).stat().st_size == PACK_HEADER.size + len(body)
        image = client.get(f"/frames/{first.json()['frame_id']}/image", headers=admin)
        assert image.content == body

    def test_concurrent_retries_store_one_frame(
        self, client: TestClient, camera: dict[str, Any], engine: Engine
    ) -> None:
        from concurrent.futures import ThreadPoolExecutor

        headers = {**cam_headers(camera), "Idempotency-Key": "burst"}
        body = make_jpeg(seed=3, noise=5)
        with ThreadPoolExecutor(8) as pool:
            results = list(
                pool.map(
                    lambda _: client.post("/cameras/cam-1/frames", content=body, headers=headers),
                    range(8),
                )
            )
        assert {r.status_code for r in results} == {201}
        assert len({r.json()["frame_id"] for r in results}) == 1
        assert table_counts(engine)["frames"] == 1


class TestRateLimit:
    def test_a_flooding_camera_gets_429_and_the_others_do_not(
        self, client: TestClient, admin: dict[str, str], app: Any
    ) -> None:
        from dataclasses import replace

        from tests.factories import Clock

        clock = Clock()
        app.state.timing = replace(app.state.timing, clock=clock)
        app.state.settings = app.state.settings.model_copy(update={"rate_limit_per_minute": 5})
        tokens = {
            cid: client.post("/cameras", json={"id": cid, "kind": "rig"}, headers=admin).json()[
                "token"
            ]
            for cid in ("loud", "quiet")
        }

        def post(cid: str, seed: int) -> Any:
            clock.advance(seconds=1)
            return client.post(
                f"/cameras/{cid}/frames",
                content=make_jpeg(seed=seed, noise=3),
                headers={"Authorization": f"Bearer {tokens[cid]}", "Content-Type": "image/jpeg"},
            )

        assert [post("loud", i).status_code for i in range(5)] == [201] * 5
        refused = post("loud", 99)
        assert refused.status_code == 429
        assert refused.headers["content-type"] == "application/problem+json"
        assert 50 <= int(refused.headers["retry-after"]) <= 60
        assert post("quiet", 1).status_code == 201  # the other camera is unaffected
        clock.advance(seconds=60)
        assert post("loud", 100).status_code == 201  # the minute has rolled on

    def test_the_limit_holds_across_processes(
        self, settings: Any, engine: Engine, admin: dict[str, str]
    ) -> None:
        """Two instances of the service on one database (each with its own reservations),
        posting alternately: exactly the limit gets through in a minute, the rest is 429."""
        from dataclasses import replace

        from app.main import create_app
        from tests.factories import Clock

        clock = Clock()
        limited = settings.model_copy(update={"rate_limit_per_minute": 40})  # blocks of 2
        apps = [create_app(limited), create_app(limited)]
        for a in apps:
            a.state.timing = replace(a.state.timing, clock=clock)
        before = table_counts(engine)["frames"]
        with TestClient(apps[0]) as one, TestClient(apps[1]) as two:
            token = one.post(
                "/cameras", json={"id": "across", "kind": "rig"}, headers=admin
            ).json()["token"]
            headers = {"Authorization": f"Bearer {token}", "Content-Type": "image/jpeg"}
            codes = []
            for i in range(50):
                clock.advance(seconds=0.5)
                c = (one, two)[i % 2]
                codes.append(
                    c.post("/cameras/across/frames", content=make_jpeg(seed=i), headers=headers)
                )
            statuses = [r.status_code for r in codes]
            assert statuses.count(201) == 40
            assert set(statuses[40:]) == {429}
            assert table_counts(engine)["frames"] - before == 40
            clock.advance(seconds=60)
            r = two.post("/cameras/across/frames", content=make_jpeg(seed=99), headers=headers)
            assert r.status_code == 201


def test_a_stalled_database_does_not_starve_the_other_endpoints(
    client: TestClient, app: Any, camera: dict[str, Any], admin: dict[str, str]
) -> None:
    """50 uploads wait for a commit that does not come (the writer's batch does not return, as
    in a database failover): they hold no thread while they wait, so the shared thread pool
    (40 threads) still serves the other endpoints, and every upload completes afterwards."""
    import threading
    from concurrent.futures import ThreadPoolExecutor

    writer = app.state.writer
    body = make_jpeg(seed=4, noise=5)
    with stalled_writer(writer) as stall, ThreadPoolExecutor(50) as pool:
        uploads = [
            pool.submit(
                client.post,
                "/cameras/cam-1/frames",
                content=body,
                headers=cam_headers(camera),
                params={"captured_at": f"{DAY}T00:00:{i:02d}Z"},
            )
            for i in range(50)
        ]
        try:
            # the first batch stalls; the other uploads are decoded and queued behind it
            assert stall.stuck.wait(10)
            for _ in range(100):
                if stall.batches[0] + writer._queue.qsize() == 50:
                    break
                threading.Event().wait(0.1)
            assert stall.batches[0] + writer._queue.qsize() == 50
            assert not any(u.done() for u in uploads)
            r = client.get("/cameras/cam-1", headers=admin)  # a sync endpoint: a pool thread
            assert r.status_code == 200
            assert not stall.release.is_set(), "answered only after the stall ended"
        finally:
            stall.release.set()
        assert [u.result().status_code for u in uploads] == [201] * 50


def test_an_upload_the_database_does_not_take_in_time_is_a_503_and_left_out(
    settings: Any, engine: Engine, admin: dict[str, str]
) -> None:
    """A database that hangs (its disk stalled) held every upload for as long as it hung, and
    the frames were stored whenever it came back, long after the cameras had given up and sent
    them again. Now an upload gets 503 ``upload_timeout`` after ``upload_timeout_seconds``;
    those not yet being written are dropped, and the cameras' retries store each frame once."""
    from concurrent.futures import ThreadPoolExecutor

    from app.main import create_app
    from tests.factories import empty_tables

    empty_tables(engine)
    app = create_app(settings.model_copy(update={"upload_timeout_seconds": 1.0}))
    with TestClient(app, raise_server_exceptions=False) as client:
        r = client.post("/cameras", json={"id": "cam-1", "kind": "rig"}, headers=admin)
        headers = cam_headers(r.json())
        # the camera looked up (and cached) first: here only its frames' batches hang
        warm = client.post("/cameras/cam-1/frames", content=make_jpeg(seed=98), headers=headers)
        assert warm.status_code == 201

        def upload(i: int) -> Any:
            return client.post(
                "/cameras/cam-1/frames",
                content=make_jpeg(seed=i, noise=5),
                headers=headers,
                params={"captured_at": f"{DAY}T00:00:{i:02d}Z"},
            )

        with stalled_writer(app.state.writer) as stall, ThreadPoolExecutor(8) as pool:
            first = pool.submit(upload, 0)
            assert stall.stuck.wait(10)  # the first upload's batch hangs in the database
            rest = [pool.submit(upload, i) for i in range(1, 8)]
            answers = [first.result(), *(u.result() for u in rest)]
        assert [a.status_code for a in answers] == [503] * 8
        assert {a.json()["code"] for a in answers} == {"upload_timeout"}
        assert {a.headers["retry-after"] for a in answers} == {"5"}
        # the batch under way when the deadline came is stored; the 7 queued behind it are not
        again = client.post(
            "/cameras/cam-1/frames", content=make_jpeg(seed=99, noise=5), headers=headers
        )
        assert again.status_code == 201  # written after everything queued before it
        assert table_counts(engine)["frames"] == 1 + stall.batches[0] + 1
        # the cameras send them again: each frame stored once, the first answered as a replay
        retried = [upload(i) for i in range(8)]
        assert [r.status_code for r in retried] == [201] * 8
        assert retried[0].headers.get("idempotent-replay") == "true"
        assert table_counts(engine)["frames"] == 1 + 8 + 1


def test_a_cameras_frames_page_by_cursor(
    client: TestClient, camera: dict[str, Any], admin: dict[str, str]
) -> None:
    from tests.factories import pages

    sent = []
    for k, minute in enumerate((0, 10, 10, 20, 30)):
        r = client.post(
            "/cameras/cam-1/frames",
            content=make_jpeg(seed=k, noise=2),
            headers=cam_headers(camera),
            params={"captured_at": f"{DAY}T08:{minute:02d}:00Z"},
        )
        assert r.status_code == 201, r.text
        sent.append((r.json()["captured_at"], r.json()["frame_id"]))
    got = pages(client, "/cameras/cam-1/frames", {"limit": 2}, headers=admin)
    assert [len(p) for p in got] == [2, 2, 1]
    assert [(f["captured_at"], f["frame_id"]) for p in got for f in p] == sorted(sent, reverse=True)


class TestRegionPreview:
    """``GET /frames/{id}/region.jpg``: the frame with its region outlined and the rest
    darkened, to check a camera's region on a real frame (or preview another)."""

    @staticmethod
    def grey(client: TestClient, admin: dict[str, str], roi: list[int] | None) -> str:
        body = {"id": "sky-1", "kind": "sky", **({"roi": roi} if roi else {})}
        token = client.post("/cameras", json=body, headers=admin).json()["token"]
        image = np.full((120, 160, 3), 180, np.uint8)  # flat grey: darkened is 60
        ok, buf = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, 98])
        assert ok
        r = client.post(
            "/cameras/sky-1/frames",
            content=buf.tobytes(),
            headers={"Authorization": f"Bearer {token}", "Content-Type": "image/jpeg"},
        )
        assert r.status_code == 201, r.text
        return str(r.json()["frame_id"])

    @staticmethod
    def shown(r: Any) -> np.ndarray:
        assert r.status_code == 200, r.text
        assert r.headers["content-type"] == "image/jpeg"
        return cv2.cvtColor(
            cv2.imdecode(np.frombuffer(r.content, np.uint8), cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB
        )

    def test_the_region_of_the_verdict_is_outlined(
        self, client: TestClient, admin: dict[str, str]
    ) -> None:
        fid = self.grey(client, admin, [20, 10, 100, 50])
        out = self.shown(client.get(f"/frames/{fid}/region.jpg", headers=admin)).astype(int)
        assert np.abs(out[30, 70] - 180).max() <= 6  # inside: as taken
        for y, x in ((100, 70), (30, 140), (5, 5)):  # outside: a third
            assert np.abs(out[y, x] - 60).max() <= 6, (y, x)
        edge = out[10, 70]  # the rectangle's top edge, amber
        assert edge[0] > 200, edge
        assert edge[2] < 80, edge

    def test_another_region_previewed(self, client: TestClient, admin: dict[str, str]) -> None:
        fid = self.grey(client, admin, [20, 10, 100, 50])
        triangle = [[0, 0], [159, 0], [0, 119]]
        r = client.get(
            f"/frames/{fid}/region.jpg", params={"roi": json.dumps(triangle)}, headers=admin
        )
        out = self.shown(r).astype(int)
        assert np.abs(out[20, 20] - 180).max() <= 6  # inside the triangle
        assert np.abs(out[110, 150] - 60).max() <= 6  # below its hypotenuse

    def test_refusals(self, client: TestClient, admin: dict[str, str], camera: Any) -> None:
        fid = self.grey(client, admin, None)
        path = f"/frames/{fid}/region.jpg"
        for roi, code in (("[0, 0, 200, 10]", "roi_outside_frame"), ("[1, 2]", "bad_roi"),
                          ("not json", "bad_roi"), ("[[0, 0], [5, 5]]", "bad_roi")):  # fmt: skip
            r = client.get(path, params={"roi": roi}, headers=admin)
            assert r.status_code == 422, roi
            assert r.json()["code"] == code, roi
        whole = self.shown(client.get(path, headers=admin)).astype(int)
        assert np.abs(whole[60, 80] - 180).max() <= 6  # no region: the whole frame
        assert client.get("/frames/none/region.jpg", headers=admin).status_code == 404
        as_camera = {"Authorization": f"Bearer {camera['token']}"}
        assert client.get(path, headers=as_camera).status_code == 403
