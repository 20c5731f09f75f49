"""Where frames are kept: a failing disk, and an S3-compatible object store
(``VANTAGE_FRAME_STORE=s3``).

The S3 store is moto's S3 server, reached over HTTP through ``s3_endpoint_url`` exactly as a MinIO
or Ceph gateway would be: ingest, the image endpoint, retention, the orphan sweep, health, and
what a client sees when the store is down (503, nothing half-stored).
"""

from __future__ import annotations

import errno
import os
import socket
import uuid
from collections.abc import Iterator
from dataclasses import replace
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import boto3
import httpx2 as httpx
import pytest
from fastapi.testclient import TestClient
from moto.server import ThreadedMotoServer
from sqlalchemy import Engine, event

from app.main import create_app
from app.platform.frames import retention
from app.platform.frames.storage import digest
from app.platform.frames.stores import S3FrameStore
from app.platform.settings import Settings
from tests.factories import ADMIN_TOKEN, Clock, empty_tables, migrate, table_counts
from tests.factories.cells import rig_camera
from tests.factories.solar import CLEAN_RGB, panel_jpeg
from tests.servers import free_port, server_env, start_server

ADMIN = {"Authorization": f"Bearer {ADMIN_TOKEN}"}


CREDENTIALS = {
    "AWS_ACCESS_KEY_ID": "vantage-test",
    "AWS_SECRET_ACCESS_KEY": "vantage-test-secret",
    "AWS_SESSION_TOKEN": "",
}


@pytest.fixture(scope="module")
def s3_url() -> Iterator[str]:
    server = ThreadedMotoServer(ip_address="127.0.0.1", port=0, verbose=False)
    server.start()
    host, port = server.get_host_and_port()
    yield f"http://{host}:{port}"
    server.stop()


@pytest.fixture
def bucket(s3_url: str, monkeypatch: pytest.MonkeyPatch) -> Iterator[Any]:
    for key, value in CREDENTIALS.items():
        monkeypatch.setenv(key, value)
    s3 = boto3.resource("s3", endpoint_url=s3_url, region_name="eu-south-1")
    b = s3.Bucket(f"frames-{uuid.uuid4().hex[:12]}")
    b.create(CreateBucketConfiguration={"LocationConstraint": "eu-south-1"})
    yield b
    b.objects.all().delete()
    b.delete()


def s3_settings(settings: Settings, s3_url: str, bucket: str) -> Settings:
    return settings.model_copy(
        update={
            "frame_store": "s3",
            "s3_bucket": bucket,
            "s3_prefix": "city/",
            "s3_endpoint_url": s3_url,
            "s3_region": "eu-south-1",
        }
    )


@pytest.fixture
def s3_client(
    settings: Settings, s3_url: str, bucket: Any, engine: Engine, app: Any
) -> Iterator[tuple[TestClient, Any]]:
    # ``app`` (the disk one) only to empty the tables first
    s3_app = create_app(s3_settings(settings, s3_url, bucket.name))
    with TestClient(s3_app, raise_server_exceptions=False) as c:
        yield c, s3_app


def keys(bucket: Any) -> set[str]:
    return {o.key for o in bucket.objects.all()}


def test_frames_go_to_the_bucket_and_come_back(
    s3_client: tuple[TestClient, Any], bucket: Any, admin: dict[str, str], settings: Settings
) -> None:
    client, _ = s3_client
    headers = rig_camera(client, admin)
    body = panel_jpeg(CLEAN_RGB, seed=1)
    r = client.post("/cameras/c/frames", content=body, headers=headers)
    assert r.status_code == 201, r.text
    sha = r.json()["sha256"]
    assert sha == digest(body)
    assert keys(bucket) == {f"city/frames/{sha[:2]}/{sha}.jpg"}
    assert bucket.Object(f"city/frames/{sha[:2]}/{sha}.jpg").get()["Body"].read() == body
    assert not (settings.data_dir / "frames").exists()  # nothing on the local disk

    image = client.get(f"/frames/{r.json()['frame_id']}/image", headers=admin)
    assert image.status_code == 200
    assert image.headers["content-type"] == "image/jpeg"
    assert image.content == body
    assert image.headers["etag"] == f'"{sha}"'
    again = client.get(
        f"/frames/{r.json()['frame_id']}/image", headers={**admin, "If-None-Match": f'"{sha}"'}
    )
    assert again.status_code == 304
    assert again.content == b""
    for tags in ("*", f'"other", W/"{sha}"'):  # RFC 9110 §13.1.2
        held = client.get(
            f"/frames/{r.json()['frame_id']}/image", headers={**admin, "If-None-Match": tags}
        )
        assert held.status_code == 304, tags
    other = client.get(
        f"/frames/{r.json()['frame_id']}/image", headers={**admin, "If-None-Match": '"other"'}
    )
    assert other.status_code == 200
    assert other.content == body

    health = client.get("/health")
    assert health.status_code == 200
    assert health.json()["frame_store"] == "ok"


def test_an_object_gone_from_the_bucket_is_404(
    s3_client: tuple[TestClient, Any], bucket: Any, admin: dict[str, str]
) -> None:
    client, _ = s3_client
    r = client.post(
        "/cameras/c/frames", content=panel_jpeg(CLEAN_RGB), headers=rig_camera(client, admin)
    )
    bucket.objects.all().delete()
    image = client.get(f"/frames/{r.json()['frame_id']}/image", headers=admin)
    assert image.status_code == 404
    assert image.headers["content-type"] == "application/problem+json"


def test_retention_and_orphan_sweep_delete_objects(
    s3_client: tuple[TestClient, Any], bucket: Any, admin: dict[str, str], engine: Engine
) -> None:
    client, s3_app = s3_client
    clock = Clock()
    s3_app.state.timing = replace(s3_app.state.timing, clock=clock)
    headers = rig_camera(client, admin)
    old = [
        client.post("/cameras/c/frames", content=panel_jpeg(CLEAN_RGB, seed=s), headers=headers)
        for s in (1, 2, 3)
    ]
    clock.advance(days=40)
    new = client.post("/cameras/c/frames", content=panel_jpeg(CLEAN_RGB, seed=4), headers=headers)
    assert len(keys(bucket)) == 4

    swept = client.post("/admin/retention/sweep", headers=admin).json()
    assert swept == {"frames": 3, "files": 3, "images": 0}
    sha = new.json()["sha256"]
    assert keys(bucket) == {f"city/frames/{sha[:2]}/{sha}.jpg"}
    for r in old:
        assert client.get(f"/frames/{r.json()['frame_id']}", headers=admin).status_code == 404

    store: S3FrameStore = s3_app.state.frame_store
    orphan = panel_jpeg(CLEAN_RGB, seed=3)
    store.put(orphan, digest(orphan), datetime.now(UTC))  # as if killed before the commit
    # too young: may be an upload in flight in another process
    assert retention.sweep_orphans(s3_app.state.sessionmaker, store, min_age_s=600) == 0
    assert retention.sweep_orphans(s3_app.state.sessionmaker, store, min_age_s=0) == 1
    assert keys(bucket) == {f"city/frames/{sha[:2]}/{sha}.jpg"}
    assert table_counts(engine)["frames"] == 1


def test_history_retention_deletes_the_objects_and_keeps_the_rows(
    settings: Settings, s3_url: str, bucket: Any, admin: dict[str, str], app: Any
) -> None:
    """VANTAGE_HISTORY_RETENTION_DAYS with the S3 store: the old frames' objects go after the
    frame retention, their rows stay."""
    history = settings.model_copy(update={"history_retention_days": 365.0})
    s3_app = create_app(s3_settings(history, s3_url, bucket.name))
    clock = Clock()
    s3_app.state.timing = replace(s3_app.state.timing, clock=clock)
    with TestClient(s3_app, raise_server_exceptions=False) as client:
        headers = rig_camera(client, admin)
        old = [
            client.post("/cameras/c/frames", content=panel_jpeg(CLEAN_RGB, seed=s), headers=headers)
            for s in (1, 2, 3)
        ]
        clock.advance(days=40)
        new = client.post(
            "/cameras/c/frames", content=panel_jpeg(CLEAN_RGB, seed=4), headers=headers
        )
        swept = client.post("/admin/retention/sweep", headers=admin).json()
        assert swept == {"frames": 0, "files": 3, "images": 3}
        sha = new.json()["sha256"]
        assert keys(bucket) == {f"city/frames/{sha[:2]}/{sha}.jpg"}
        for r in old:
            frame = client.get(f"/frames/{r.json()['frame_id']}", headers=admin)
            assert frame.status_code == 200
            assert frame.json()["stored"] is False
            image = client.get(f"/frames/{r.json()['frame_id']}/image", headers=admin)
            assert image.status_code == 404


def test_store_down_is_503_and_nothing_is_stored(
    settings: Settings,
    s3_url: str,
    bucket: Any,
    engine: Engine,
    app: Any,
    admin: dict[str, str],
) -> None:
    with socket.socket() as s:  # a port nothing listens on
        s.bind(("127.0.0.1", 0))
        dead = f"http://127.0.0.1:{s.getsockname()[1]}"
    down = s3_settings(settings, dead, bucket.name)
    with TestClient(create_app(down), raise_server_exceptions=False) as client:
        health = client.get("/health")
        assert health.status_code == 503
        assert health.json()["frame_store"] == "unreachable"
        assert health.json()["database"] == "ok"
        r = client.post(
            "/cameras/c/frames", content=panel_jpeg(CLEAN_RGB), headers=rig_camera(client, admin)
        )
        assert r.status_code == 503, r.text
        assert r.headers["content-type"] == "application/problem+json"
        assert r.json()["code"] == "store_unavailable"
        assert r.headers["retry-after"] == "5"
    counts = table_counts(engine)
    assert counts["frames"] == 0
    assert counts["verdicts"] == 0


def test_s3_needs_a_bucket_and_an_admin_token() -> None:
    with pytest.raises(ValueError, match="VANTAGE_S3_BUCKET"):
        Settings(frame_store="s3", admin_token="t" * 32)  # type: ignore[arg-type]
    # machines sharing a bucket share no data directory to keep a generated token in
    with pytest.raises(ValueError, match="VANTAGE_ADMIN_TOKEN"):
        Settings(frame_store="s3", s3_bucket="frames", admin_token=None)
    assert Settings(frame_store="s3", s3_bucket="frames", admin_token="t" * 32).s3_bucket  # type: ignore[arg-type]


def test_disk_that_cannot_take_the_frame_is_503_and_nothing_is_stored(
    client: TestClient, admin: dict[str, str], settings: Settings, engine: Engine
) -> None:
    headers = rig_camera(client, admin)
    body = panel_jpeg(CLEAN_RGB, seed=5)
    packs = settings.data_dir / "packs"
    packs.write_bytes(b"")  # a file where the packs' directory should be
    r = client.post("/cameras/c/frames", content=body, headers=headers)
    assert r.status_code == 503, r.text
    assert r.headers["content-type"] == "application/problem+json"
    assert r.json()["code"] == "store_unavailable"
    assert table_counts(engine)["frames"] == 0
    assert packs.read_bytes() == b""

    packs.unlink()
    r = client.post("/cameras/c/frames", content=body, headers=headers)
    assert r.status_code == 201
    assert client.get(f"/frames/{r.json()['frame_id']}/image", headers=admin).content == body


def test_a_disk_down_to_the_space_kept_for_the_database_refuses_frames(
    client: TestClient,
    admin: dict[str, str],
    app: Any,
    engine: Engine,
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Frames stop at VANTAGE_KEEP_FREE_DISK_MB (256) free: 503 ``disk_full`` with a
    Retry-After of a minute, nothing stored, /health "full"; the rest of the service goes on
    writing (measured on a 3 MiB disk without the reserve: the frames took its last byte,
    then every write failed, registering a robot or a panel as an upload, and /health said
    "ok")."""
    headers = rig_camera(client, admin)
    body = panel_jpeg(CLEAN_RGB, seed=5)
    store = app.state.frame_store
    assert store.keep_free_bytes == 256 * 2**20
    free = [store.keep_free_bytes + 20 * 2**20]  # what the disk has left
    monkeypatch.setattr(store, "free_bytes", lambda: free[0])
    assert client.post("/cameras/c/frames", content=body, headers=headers).status_code == 201
    assert client.get("/health").json()["frame_store"] == "ok"

    # a new frame: the same bytes again would take no space, pointing at the copy stored
    other = panel_jpeg(CLEAN_RGB, seed=6)
    free[0] = store.keep_free_bytes + len(other)  # a frame's header more would cross it
    before = table_counts(engine)
    packs = sorted((app.state.settings.data_dir / "packs").rglob("*.pack"))
    assert packs  # the first frame's
    sizes = [p.stat().st_size for p in packs]
    r = client.post("/cameras/c/frames", content=other, headers=headers)
    assert r.status_code == 503, r.text
    assert r.headers["content-type"] == "application/problem+json"
    assert r.headers["retry-after"] == "60"
    assert r.json()["code"] == "disk_full"
    assert "VANTAGE_KEEP_FREE_DISK_MB" in r.json()["detail"]
    assert table_counts(engine) == before
    assert [p.stat().st_size for p in packs] == sizes
    health = client.get("/health")
    assert health.status_code == 503
    assert health.json() | {"version": None} == {
        "status": "degraded",
        "database": "ok",
        "frame_store": "full",
        "version": None,
    }
    assert client.post("/robots", json={"id": "r1"}, headers=admin).status_code == 201

    free[0] = store.keep_free_bytes + store.largest_frame_bytes + 1  # retention freed some
    assert client.get("/health").status_code == 200
    assert client.post("/cameras/c/frames", content=other, headers=headers).status_code == 201


def test_a_database_whose_disk_is_full_says_so(settings: Settings, tmp_path: Path) -> None:
    """SQLite refusing to grow (SQLITE_FULL, here its page count capped where it stands, in
    a database of its own: the tests' shared one has the free pages of every test before) is
    a 503 that names the full disk, not "cannot be reached or is busy"."""
    url = f"sqlite:///{tmp_path / 'full.db'}"
    migrate(url)
    app = create_app(settings.model_copy(update={"database_url": url}))

    @event.listens_for(app.state.engine, "begin")
    def _cap(conn: Any) -> None:
        pages = conn.exec_driver_sql("PRAGMA page_count").scalar()
        conn.exec_driver_sql(f"PRAGMA max_page_count = {pages}")

    with TestClient(app) as client:
        headers = rig_camera(client, {"Authorization": f"Bearer {ADMIN_TOKEN}"})
        statuses = []
        for k in range(200):  # until the pages' free room is used up
            r = client.post(
                "/cameras/c/frames", content=panel_jpeg(CLEAN_RGB, seed=100 + k), headers=headers
            )
            statuses.append(r.status_code)
            if r.status_code != 201:
                break
        assert r.status_code == 503, statuses
        assert r.json()["code"] == "database_unavailable"
        assert r.json()["detail"].startswith("the database's disk is full")


def test_health_sees_a_sqlite_database_that_takes_no_more_writes(
    settings: Settings, tmp_path: Path
) -> None:
    """A SQLite file answers reads, and begins its IMMEDIATE transactions, after the kernel
    has stopped its filesystem's writes (ext4's errors=remount-ro after an I/O error):
    measured so, every upload and registration got 503 "disk I/O error" while /health said
    "ok", and a load balancer kept sending it cameras. /health now commits a write. Here
    SQLite itself refuses them (``query_only``), in a database of its own."""
    url = f"sqlite:///{tmp_path / 'refusing.db'}"
    migrate(url)
    app = create_app(settings.model_copy(update={"database_url": url}))
    refusing = [False]

    @event.listens_for(app.state.engine, "begin")
    def _refuse(conn: Any) -> None:  # once BEGIN IMMEDIATE went through, as it did
        conn.exec_driver_sql(f"PRAGMA query_only = {int(refusing[0])}")

    @event.listens_for(app.state.engine, "commit")
    @event.listens_for(app.state.engine, "rollback")
    def _until_it_ends(conn: Any) -> None:
        conn.exec_driver_sql("PRAGMA query_only = 0")

    with TestClient(app) as client:
        headers = rig_camera(client, ADMIN)
        body = panel_jpeg(CLEAN_RGB, seed=7)
        assert client.get("/health").status_code == 200

        refusing[0] = True
        r = client.get("/health")
        assert r.status_code == 503
        assert r.json() | {"version": ""} == {
            "status": "degraded",
            "database": "read_only",
            "frame_store": "ok",
            "version": "",
        }
        assert client.post("/cameras/c/frames", content=body, headers=headers).status_code == 503
        assert client.get("/cameras", headers=ADMIN).status_code == 200  # reads are served

        refusing[0] = False
        assert client.get("/health").status_code == 200
        assert client.post("/cameras/c/frames", content=body, headers=headers).status_code == 201


@pytest.mark.parametrize(("error", "state"), [(errno.EROFS, "unreachable"), (errno.ENOSPC, "full")])
def test_health_sees_a_frame_directory_that_takes_no_more_files(
    client: TestClient, settings: Settings, monkeypatch: pytest.MonkeyPatch, error: int, state: str
) -> None:
    """The frame directory's filesystem stopped by the kernel (ext4's errors=remount-ro after
    an I/O error) is still listed rw and passes ``os.access``: measured so, every frame got
    503 (EROFS) while /health said "ok". Out of inodes (ENOSPC with blocks free) is the same
    to a frame. Here every file made under it fails as the kernel fails it."""
    assert client.get("/health").status_code == 200
    root = str(settings.data_dir)
    real_open = os.open

    def stopped(path: Any, flags: int, *args: Any, **kwargs: Any) -> int:
        if str(path).startswith(root) and flags & (os.O_CREAT | os.O_TMPFILE):
            raise OSError(error, os.strerror(error), str(path))
        return real_open(path, flags, *args, **kwargs)

    monkeypatch.setattr(os, "open", stopped)
    r = client.get("/health")
    assert r.status_code == 503
    assert (r.json()["database"], r.json()["frame_store"]) == ("ok", state)

    monkeypatch.setattr(os, "open", real_open)
    assert client.get("/health").status_code == 200
    assert [p.name for p in settings.data_dir.iterdir() if p.name.startswith(".probe")] == []


@pytest.mark.slow
def test_two_machines_share_one_bucket(
    database_url: str, engine: Engine, bucket: Any, s3_url: str, tmp_path: Path
) -> None:
    """Two server processes with nothing on disk in common (as on two machines): a frame posted
    to one is served by the other, each stored once."""
    empty_tables(engine)
    s3 = {
        "VANTAGE_FRAME_STORE": "s3",
        "VANTAGE_S3_BUCKET": bucket.name,
        "VANTAGE_S3_ENDPOINT_URL": s3_url,
        "VANTAGE_S3_REGION": "eu-south-1",
        **CREDENTIALS,
    }
    procs = []
    try:
        for machine in ("a", "b"):
            port = free_port()
            env = server_env(database_url, tmp_path / machine, **s3)
            procs.append((f"http://127.0.0.1:{port}", start_server(env, port)))
        (a, _), (b, _) = procs
        with httpx.Client(headers=ADMIN, timeout=30) as c:
            token = c.post(f"{a}/cameras", json={"id": "c", "kind": "rig"}).json()["token"]
            camera = {"Authorization": f"Bearer {token}", "Content-Type": "image/jpeg"}
            bodies = [panel_jpeg(CLEAN_RGB, seed=i) for i in range(10)]
            posted = []
            for i, body in enumerate(bodies):
                r = c.post(f"{(a, b)[i % 2]}/cameras/c/frames", content=body, headers=camera)
                assert r.status_code == 201, r.text
                posted.append(r.json())
            for i, frame in enumerate(posted):  # each from the other machine
                image = c.get(f"{(b, a)[i % 2]}/frames/{frame['frame_id']}/image")
                assert image.status_code == 200
                assert image.content == bodies[i]
        assert keys(bucket) == {f"frames/{f['sha256'][:2]}/{f['sha256']}.jpg" for f in posted}
        assert not any((tmp_path / m / "frames").exists() for m in ("a", "b"))
    finally:
        for _, p in procs:
            p.terminate()
            p.wait(10)


def test_frames_decode_on_about_as_many_threads_as_cores_unless_told(settings: Settings) -> None:
    # more decoding threads than cores only contend for the cores and the GIL (bench/README.md)
    cpus = len(os.sched_getaffinity(0))
    assert settings.effective_ingest_threads == max(2, cpus)
    # an S3 upload waits on the network: more of them at once
    s3 = Settings(frame_store="s3", s3_bucket="frames", admin_token="t" * 32)  # type: ignore[arg-type]
    assert s3.effective_ingest_threads == 32
    told = settings.model_copy(update={"ingest_threads": 3})
    assert told.effective_ingest_threads == 3
    app = create_app(told)
    assert app.state.writer.preparers == 3
    with pytest.raises(ValueError, match="ingest_threads"):
        Settings(ingest_threads=-1)
