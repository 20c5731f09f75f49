"""Hostile image files: a size the decoder reads otherwise than the limit, and OpenCV's own
pixel cap as the second line."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest
from fastapi.testclient import TestClient

from app.platform.frames import jpeg
from tests.factories import ROOT, bearer, make_jpeg, tiff_bomb


def test_repeated_tiff_size_tags_are_refused() -> None:
    with pytest.raises(jpeg.CorruptJpegError, match="repeats or reorders"):
        jpeg.tiff_size(tiff_bomb())
    with pytest.raises(jpeg.CorruptJpegError, match="repeats or reorders"):
        jpeg.decode_image(tiff_bomb(), max_pixels=10**6)


def test_opencv_cap_holds_where_a_header_check_is_missed() -> None:
    """OpenCV's cap follows VANTAGE_MAX_PIXELS: a 400×300 PNG decoded by OpenCV directly, not
    through the header checks, in a process whose limit is 100 000 and in one at 120 000."""
    script = textwrap.dedent(
        """
        from app.platform.frames import jpeg  # first: app sets the cap before cv2 loads
        import cv2, numpy as np
        ok, buf = cv2.imencode(".png", np.zeros((300, 400, 3), np.uint8))
        try:
            jpeg._imdecode(buf, cv2.IMREAD_COLOR_RGB, "PNG")
            print("decoded", jpeg.decoder_cap())
        except jpeg.TooManyPixelsError as exc:
            print("refused", exc)
        """
    )
    answers = []
    for limit in ("100000", "120000"):
        env = {**os.environ, "VANTAGE_MAX_PIXELS": limit}
        env.pop("OPENCV_IO_MAX_IMAGE_PIXELS", None)
        done = subprocess.run(
            [sys.executable, "-c", script], cwd=ROOT, env=env, capture_output=True, text=True
        )
        assert done.returncode == 0, done.stderr[-2000:]
        answers.append(done.stdout.split()[0])
    assert answers == ["refused", "decoded"]


def test_tiff_bomb_is_a_4xx(client: TestClient, admin: dict[str, str]) -> None:
    r = client.post("/vision/enhance", files={"file": ("b.tif", tiff_bomb())}, headers=admin)
    assert r.status_code == 422, r.text
    assert r.headers["content-type"] == "application/problem+json"
    assert "repeats or reorders" in r.json()["detail"]


def test_tiff_bomb_memory_stays_bounded() -> None:
    """Peak resident memory of a process that posts the bomb, against the same process's
    peak before: the 256 MP decode it replaces peaked 1.5–5 GB."""
    script = textwrap.dedent(
        """
        import json, resource, sys
        from pathlib import Path
        from fastapi.testclient import TestClient
        from app.main import create_app
        from app.platform.settings import Settings
        from tests.factories import migrate, tiff_bomb
        data = Path(sys.argv[1])
        url = f"sqlite:///{data / 'v.db'}"
        migrate(url)
        app = create_app(Settings(env="test", data_dir=data, database_url=url,
                                  admin_token="t" * 32))
        with TestClient(app) as c:
            body = tiff_bomb()
            c.post("/vision/enhance", files={"file": ("w.png", b"x")},
                   headers={"Authorization": "Bearer " + "t" * 32})
            before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
            r = c.post("/vision/enhance", files={"file": ("b.tif", body)},
                       headers={"Authorization": "Bearer " + "t" * 32})
            after = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
        print(json.dumps({"status": r.status_code, "grew_kib": after - before}))
        """
    )
    import tempfile

    with tempfile.TemporaryDirectory() as tmp:
        done = subprocess.run(
            [sys.executable, "-c", script, tmp],
            cwd=ROOT,
            capture_output=True,
            text=True,
            timeout=300,
        )
    assert done.returncode == 0, done.stderr[-2000:]
    answer = json.loads(done.stdout.splitlines()[-1])
    assert answer["status"] == 422
    assert answer["grew_kib"] < 100 * 1024, answer


def test_vision_is_for_admin_and_robots(client: TestClient, admin: dict[str, str]) -> None:
    cam = client.post("/cameras", json={"id": "c1", "kind": "sky"}, headers=admin).json()
    robot = client.post("/robots", json={"id": "r1"}, headers=admin).json()
    files = {"file": ("f.jpg", make_jpeg(noise=20.0))}
    for path in ("/vision/enhance", "/vision/outline", "/vision/outline.png"):
        r = client.post(path, files=files, headers=bearer(cam["token"]))
        assert r.status_code == 403, (path, r.text)
    r = client.post("/vision/enhance", files=files, headers=bearer(robot["token"]))
    assert r.status_code == 200, r.text


def test_huge_roi_values_are_refused(client: TestClient, admin: dict[str, str]) -> None:
    body = {"id": "c2", "kind": "sky", "roi": [0, 0, 10**20, 10]}
    r = client.post("/cameras", json=body, headers=admin)
    assert r.status_code == 422, r.text
    body["roi"] = [0, 0, 2_000_000, 10]
    assert client.post("/cameras", json=body, headers=admin).status_code == 422
    r = client.post(
        "/vision/enhance?roi=0,0,100000000000000000000,5",
        files={"file": ("f.jpg", make_jpeg())},
        headers=admin,
    )
    assert r.status_code == 422
    assert client.get("/cameras", headers=admin).json() == []


def test_the_data_directory_is_private(tmp_path: Path) -> None:
    """A first start makes the data directory 0700 and the database, token and frame files
    0600, whatever the umask."""
    data = tmp_path / "fresh"
    env = {**os.environ, "VANTAGE_DATA_DIR": str(data)}
    for name in ("VANTAGE_DATABASE_URL", "VANTAGE_ADMIN_TOKEN"):
        env.pop(name, None)
    script = textwrap.dedent(
        """
        import os
        os.umask(0o022)
        from alembic import command
        from alembic.config import Config
        command.upgrade(Config("alembic.ini"), "head")
        from fastapi.testclient import TestClient
        from app.main import create_app
        from app.platform.settings import Settings
        from tests.factories import make_jpeg
        with TestClient(create_app(Settings())) as c:
            token = open(os.environ["VANTAGE_DATA_DIR"] + "/admin_token").read().strip()
            h = {"Authorization": "Bearer " + token}
            cam = c.post("/cameras", json={"id": "c", "kind": "rig"}, headers=h).json()
            r = c.post("/cameras/c/frames", content=make_jpeg(),
                       headers={"Authorization": "Bearer " + cam["token"],
                                "Content-Type": "image/jpeg"})
            assert r.status_code == 201, r.text
        """
    )
    done = subprocess.run(
        [sys.executable, "-c", script], cwd=ROOT, env=env, capture_output=True, text=True
    )
    assert done.returncode == 0, done.stderr[-3000:]
    assert data.stat().st_mode & 0o777 == 0o700
    files = [p for p in data.rglob("*") if p.is_file()]
    assert {p.name for p in files} >= {"vantage.db", "admin_token"}
    assert any(p.suffix == ".pack" for p in files), [p.name for p in files]  # the frame
    for p in files:
        assert p.stat().st_mode & 0o077 == 0, (p, oct(p.stat().st_mode))
    for p in data.rglob("*"):
        if p.is_dir():
            assert p.stat().st_mode & 0o077 == 0, (p, oct(p.stat().st_mode))


def test_an_upload_that_is_not_multipart_is_a_415(
    client: TestClient, admin: dict[str, str]
) -> None:
    for headers in ({}, {"Content-Type": "application/json"}):
        r = client.post("/vision/outline", content=b"{}", headers={**admin, **headers})
        assert r.status_code == 415, (headers, r.text)
        assert r.json()["code"] == "not_multipart"
