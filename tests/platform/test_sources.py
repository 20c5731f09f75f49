"""Cameras whose frames the service pulls: snapshot URLs, MJPEG over HTTP and RTSP/H.264 from a
real RTSP server (GStreamer's), through the API with the service's own puller running."""

from __future__ import annotations

import shutil
import subprocess
import time
from collections.abc import Callable, Iterator
from datetime import datetime
from itertools import pairwise
from pathlib import Path
from typing import Any

import pytest
from fastapi.testclient import TestClient

from app.main import create_app
from app.platform.settings import Settings
from tests.factories import empty_tables
from tests.servers import CameraServer


@pytest.fixture
def camera_server() -> Iterator[CameraServer]:
    s = CameraServer()
    yield s
    s.stop()


@pytest.fixture
def puller(settings: Settings, engine: Any) -> Iterator[TestClient]:
    """The service with a short pull timeout (1.5 s), its puller running."""
    empty_tables(engine)
    fast = create_app(settings.model_copy(update={"pull_timeout_seconds": 1.5}))
    with TestClient(fast, raise_server_exceptions=False) as c:
        yield c


def until(check: Callable[[], Any], seconds: float = 15) -> Any:
    """Poll ``check`` until it returns something truthy; that value."""
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        got = check()
        if got:
            return got
        time.sleep(0.2)
    raise AssertionError(f"not within {seconds} s")


def register(client: TestClient, admin: dict[str, str], source: dict[str, Any]) -> Any:
    body = {"id": "cam", "kind": "sky", "roi": [0, 0, 160, 55], "source": source}
    r = client.post("/cameras", json=body, headers=admin)
    assert r.status_code == 201, r.text
    return r.json()


def source_of(client: TestClient, admin: dict[str, str]) -> dict[str, Any]:
    return dict(client.get("/cameras/cam", headers=admin).json()["source"])


def frames(client: TestClient, admin: dict[str, str]) -> list[dict[str, Any]]:
    r = client.get("/cameras/cam/frames", headers=admin, params={"limit": 100})
    assert r.status_code == 200, r.text
    return list(r.json())


@pytest.mark.slow  # a real server or camera process, seconds of waiting
def test_a_snapshot_camera_is_pulled_every_interval(
    puller: TestClient, admin: dict[str, str], camera_server: CameraServer
) -> None:
    """Every second a frame, stored and judged as a posted one (a sky verdict), the source
    ``ok`` with its last frame; the credentials given in the URL go to the camera as Basic
    and never come back."""
    created = register(
        puller,
        admin,
        {
            "url": camera_server.url("/snapshot.jpg").replace("//", "//op:s3cret@"),
            "every_seconds": 1,
        },
    )
    assert created["source"]["state"] == "connecting"
    assert created["source"]["url"] == camera_server.url("/snapshot.jpg")
    assert (created["source"]["username"], created["source"]["has_password"]) == ("op", True)
    got = until(lambda: len(frames(puller, admin)) >= 3 and frames(puller, admin))
    assert all(f["verdict"]["kind"] == "sky" for f in got)
    times = sorted(f["captured_at"] for f in got)
    source = source_of(puller, admin)
    assert source["state"] == "ok"
    assert puller.get("/cameras/cam", headers=admin).json()["source_state"] == "ok"
    assert source["last_frame_id"] in {f["frame_id"] for f in got}
    assert "s3cret" not in str(puller.get("/cameras", headers=admin).json())
    assert len(times) == len(set(times))


@pytest.mark.slow  # a real server or camera process, seconds of waiting
def test_pulled_frames_spend_the_cameras_rate_limit(
    settings: Settings, engine: Any, admin: dict[str, str], camera_server: CameraServer
) -> None:
    """A limit of 2 frames a minute: a source due every second stores 2 in the minute, its
    other pulls skipped (not counted as failures)."""
    empty_tables(engine)
    limited = create_app(settings.model_copy(update={"rate_limit_per_minute": 2}))
    while time.gmtime().tm_sec > 40:  # all of it within one clock minute, one budget
        time.sleep(0.5)
    with TestClient(limited, raise_server_exceptions=False) as client:
        register(client, admin, {"url": camera_server.url("/snapshot.jpg"), "every_seconds": 1})
        until(lambda: len(frames(client, admin)) >= 2)
        time.sleep(3)
        assert len(frames(client, admin)) == 2
        assert source_of(client, admin)["state"] == "ok"
        assert len(camera_server.requests) == 2  # the skipped pulls asked the camera nothing


def test_a_page_instead_of_video_is_a_bad_stream(
    puller: TestClient, admin: dict[str, str], camera_server: CameraServer
) -> None:
    register(puller, admin, {"url": camera_server.url("/page"), "every_seconds": 1})
    source = until(lambda: (s := source_of(puller, admin))["state"] != "connecting" and s)
    assert source["state"] == "bad_stream"
    assert "not a JPEG snapshot" in source["last_error"]
    assert "Camera login" not in source["last_error"]  # what it said is not repeated
    assert source["last_error_at"] is not None
    assert frames(puller, admin) == []


@pytest.mark.slow  # a real server or camera process, seconds of waiting
def test_a_stopped_camera_is_unreachable_then_recovers(
    puller: TestClient, admin: dict[str, str], camera_server: CameraServer
) -> None:
    register(puller, admin, {"url": camera_server.url("/snapshot.jpg"), "every_seconds": 1})
    until(lambda: source_of(puller, admin)["state"] == "ok")
    camera_server.stop()
    down = until(lambda: (s := source_of(puller, admin))["state"] == "unreachable" and s)
    assert "no answer" in down["last_error"]
    n = len(frames(puller, admin))
    camera_server.start()  # the same port
    until(lambda: source_of(puller, admin)["state"] == "ok", seconds=20)
    assert len(frames(puller, admin)) > n


@pytest.mark.slow  # a real server or camera process, seconds of waiting
def test_a_hung_camera_is_cut_by_the_timeout(
    puller: TestClient, admin: dict[str, str], camera_server: CameraServer
) -> None:
    """A server that accepts and never answers: cut after the pull timeout (1.5 s), the
    service answering meanwhile."""
    register(puller, admin, {"url": camera_server.url("/hang"), "every_seconds": 1})
    t = time.monotonic()
    while time.monotonic() - t < 1.0:
        assert puller.get("/health").status_code == 200
    source = until(lambda: (s := source_of(puller, admin))["state"] == "unreachable" and s)
    assert "timed out" in source["last_error"]
    assert frames(puller, admin) == []


@pytest.mark.slow  # a real server or camera process, seconds of waiting
def test_an_mjpeg_stream_is_decoded_by_ffmpeg(
    puller: TestClient, admin: dict[str, str], camera_server: CameraServer
) -> None:
    register(puller, admin, {"url": camera_server.url("/mjpeg"), "every_seconds": 2})
    got = until(lambda: frames(puller, admin))
    assert (got[0]["width"], got[0]["height"]) == (160, 100)
    assert source_of(puller, admin)["state"] == "ok"


RTSP_SERVER = Path(__file__).with_name("rtsp_server.py")


def gstreamer_rtsp() -> bool:
    python = shutil.which("python3", path="/usr/bin")
    if python is None:
        return False
    check = (
        "import gi; gi.require_version('GstRtspServer', '1.0');"
        " from gi.repository import GstRtspServer"
    )
    return subprocess.run([python, "-c", check], capture_output=True).returncode == 0


@pytest.fixture
def rtsp() -> Iterator[str]:
    """GStreamer's RTSP server with a live H.264 test pattern; its URL."""
    if not gstreamer_rtsp():
        pytest.skip(
            "needs GStreamer's RTSP server (apt install gir1.2-gst-rtsp-server-1.0 python3-gi)"
        )
    proc = subprocess.Popen(
        ["/usr/bin/python3", str(RTSP_SERVER)], stdout=subprocess.PIPE, text=True
    )
    try:
        assert proc.stdout is not None
        port = int(proc.stdout.readline())
        yield f"rtsp://127.0.0.1:{port}/test"
    finally:
        proc.terminate()
        proc.wait(10)
        if proc.stdout is not None:
            proc.stdout.close()


@pytest.mark.slow  # a real server or camera process, seconds of waiting
def test_an_rtsp_h264_stream_from_a_real_server(
    puller: TestClient, admin: dict[str, str], rtsp: str
) -> None:
    register(puller, admin, {"url": rtsp, "every_seconds": 2})
    got = until(lambda: len(frames(puller, admin)) >= 2 and frames(puller, admin), seconds=30)
    assert (got[0]["width"], got[0]["height"]) == (320, 240)
    assert source_of(puller, admin)["state"] == "ok"


def test_bad_sources_are_refused(client: TestClient, admin: dict[str, str]) -> None:
    """A scheme other than rtsp/http/https, every_seconds < 1, a URL with spaces or control
    characters, or no host: 422, and no camera made."""
    for source in (
        {"url": "ftp://10.0.0.1/cam", "every_seconds": 5},
        {"url": "rtsp://10.0.0.1/cam", "every_seconds": 0},
        {"url": "http://10.0.0.1/snap shot.jpg", "every_seconds": 5},
        {"url": "http://10.0.0.1/snap\x07.jpg", "every_seconds": 5},
        {"url": "http:///snap.jpg", "every_seconds": 5},
        {"url": "rtsp://10.0.0.1:99999/cam", "every_seconds": 5},
    ):
        r = client.post(
            "/cameras", json={"id": "bad", "kind": "sky", "source": source}, headers=admin
        )
        assert r.status_code == 422, source
        assert r.headers["content-type"] == "application/problem+json"
    assert client.get("/cameras/bad", headers=admin).status_code == 404


def test_a_source_is_patched_and_removed(client: TestClient, admin: dict[str, str]) -> None:
    r = client.post("/cameras", json={"id": "cam", "kind": "sky"}, headers=admin)
    assert r.json()["source"] is None
    patch = {"source": {"url": "rtsp://10.9.9.9/a", "every_seconds": 60, "password": "p"}}
    changed = client.patch("/cameras/cam", json=patch, headers=admin).json()
    assert changed["source"]["url"] == "rtsp://10.9.9.9/a"
    assert changed["source"]["has_password"] is True
    assert "password" not in changed["source"]
    assert client.patch("/cameras/cam", json={"name": "x"}, headers=admin).json()["source"]
    gone = client.patch("/cameras/cam", json={"source": None}, headers=admin).json()
    assert gone["source"] is None


@pytest.mark.slow
def test_two_processes_share_the_sources_and_pull_each_once_an_interval(
    database_url: str, engine: Any, tmp_path: Path, camera_server: CameraServer
) -> None:
    """Two service processes on one PostgreSQL, 20 snapshot sources every 2 s: every source is
    pulled, by one process at a time (the lease), never twice in one interval."""
    if not database_url.startswith("postgresql"):
        pytest.skip("several processes share sources on PostgreSQL (SQLite serves one)")
    import httpx2 as httpx

    from tests.factories import ADMIN_TOKEN, empty_tables
    from tests.servers import free_port, server_env, start_server

    empty_tables(engine)
    admin = {"Authorization": f"Bearer {ADMIN_TOKEN}"}
    env = server_env(database_url, tmp_path / "data")
    ports = [free_port(), free_port()]
    procs = [start_server(env, port) for port in ports]
    try:
        base = f"http://127.0.0.1:{ports[0]}"
        # the first camera's first pull is due at its creation: intervals count from there,
        # not from the last camera's, which may come a second or more later
        first = time.monotonic()
        for k in range(20):
            body = {
                "id": f"c{k:02d}",
                "kind": "sky",
                "roi": [0, 0, 160, 55],
                "source": {"url": camera_server.url(f"/snapshot.jpg?c={k}"), "every_seconds": 2},
            }
            r = httpx.post(f"{base}/cameras", json=body, headers=admin)
            assert r.status_code == 201, r.text
        time.sleep(9)
        pulls = [p for p in camera_server.requests if p.startswith("/snapshot.jpg")]
        slots = int((time.monotonic() - first) // 2) + 1  # intervals begun since
        for k in range(20):
            r = httpx.get(
                f"http://127.0.0.1:{ports[k % 2]}/cameras/c{k:02d}/frames",
                headers=admin,
                params={"limit": 100},
            )
            taken = sorted(datetime.fromisoformat(f["captured_at"]) for f in r.json())
            assert len(taken) >= 3, (k, taken)
            # two processes pulling one source would take it twice at once; a pull late
            # under load is followed by the next interval's on time, never a second at once
            gaps = [(b - a).total_seconds() for a, b in pairwise(taken)]
            assert min(gaps) > 0.25, (k, gaps)
        per_camera = {k: pulls.count(f"/snapshot.jpg?c={k}") for k in range(20)}
        # at most one pull in each interval begun: the camera asked no more often
        assert all(3 <= n <= slots for n in per_camera.values()), (slots, per_camera)
    finally:
        for proc in procs:
            proc.terminate()
            proc.wait(20)


def test_a_dead_process_leases_run_out_and_another_takes_over(
    settings: Settings, admin: dict[str, str], engine: Any
) -> None:
    """Process A takes the source and dies: B gets nothing while A's lease lasts, the source
    once it has run out; A's late record is ignored, B's kept. (The service's own puller is
    off: A and B stand for two processes.)"""
    from datetime import UTC, timedelta

    from sqlalchemy.orm import sessionmaker

    from app.platform.frames import sources

    empty_tables(engine)
    quiet = create_app(settings.model_copy(update={"pull_sources": False}))
    with TestClient(quiet, raise_server_exceptions=False) as client:
        source = {"url": "rtsp://10.9.9.9/a", "every_seconds": 60}
        body = {"id": "cam", "kind": "sky", "source": source}
        assert client.post("/cameras", json=body, headers=admin).status_code == 201
        sessions = sessionmaker(engine)
        now = datetime.now(UTC) + timedelta(seconds=1)  # due at registration
        lease = timedelta(seconds=30)
        with sessions() as s:
            [a] = sources.claim(s, "A", now, limit=10, lease=lease)
        assert a.camera.id == "cam"
        with sessions() as s:
            assert sources.claim(s, "B", now + timedelta(seconds=29), limit=10, lease=lease) == []
        later = now + timedelta(seconds=31)
        with sessions() as s:
            [b] = sources.claim(s, "B", later, limit=10, lease=lease)
        with sessions() as s:  # A wakes up and records a frame it no longer owns: ignored
            sources.finish(s, "A", a, later, frame=("fa", later), error=None)
        with sessions() as s:
            sources.finish(s, "B", b, later, frame=("fb", later), error=None)
        got = source_of(client, admin)
    assert (got["state"], got["last_frame_id"]) == ("ok", "fb")
    # the next frame is due an interval after this one was due, not after the pull ended
    assert datetime.fromisoformat(got["next_due_at"]) == b.due + timedelta(seconds=60)
