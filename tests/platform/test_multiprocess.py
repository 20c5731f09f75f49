"""Several server processes against one PostgreSQL: each cleaning task goes to exactly one robot.

Runs only when ``VANTAGE_TEST_DATABASE_URL`` names a PostgreSQL database (``.ci/run`` sets it).
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor
from datetime import UTC, datetime, timedelta
from pathlib import Path

import httpx2 as httpx
import pytest
from sqlalchemy import Engine

from app.air.core import airquality
from tests.factories import ADMIN_TOKEN, LEFT, RIGHT, empty_tables, halves, near
from tests.factories.air import calibrate, sky_jpeg
from tests.factories.solar import CLEAN_RGB, DUST, clean_set, panel_jpeg
from tests.servers import free_port, server_env, start_server

URL = os.environ.get("VANTAGE_TEST_DATABASE_URL", "")
pytestmark = [
    pytest.mark.postgres,
    pytest.mark.skipif(not URL.startswith("postgresql"), reason="needs PostgreSQL"),
]
ADMIN = {"Authorization": f"Bearer {ADMIN_TOKEN}"}
CACHE_SECONDS = 600.0
"""How long each server keeps a camera it has seen (VANTAGE_CAMERA_CACHE_SECONDS): longer than
any test, so what reaches the other process does so without the cache running out."""


@pytest.fixture
def servers(engine: Engine, database_url: str, tmp_path: Path) -> Iterator[list[str]]:
    empty_tables(engine)
    env = server_env(database_url, tmp_path, VANTAGE_CAMERA_CACHE_SECONDS=str(CACHE_SECONDS))
    procs = []
    try:
        for _ in range(2):
            procs.append((port := free_port(), start_server(env, port)))
        yield [f"http://127.0.0.1:{port}" for port, _ in procs]
    finally:
        for _, p in procs:
            p.terminate()
            p.wait(10)


def test_twenty_robots_across_two_processes_get_twenty_distinct_tasks(servers: list[str]) -> None:
    a, b = servers
    with httpx.Client(base_url=a, headers=ADMIN, timeout=30) as c:
        for i in range(20):
            assert c.post("/panels", json={"id": f"p{i}"}).status_code == 201
            cam = c.post("/cameras", json={"id": f"c{i}", "kind": "panel", "panel_id": f"p{i}"})
            files = [
                ("files", (f"{j}.jpg", f, "image/jpeg")) for j, f in enumerate(clean_set(5, i))
            ]
            assert c.post(f"/panels/p{i}/baseline", files=files).status_code == 201
            for k in range(3):  # alternate processes: the debounce state lives in the database
                r = httpx.post(
                    f"{(a, b)[k % 2]}/cameras/c{i}/frames",
                    content=panel_jpeg(CLEAN_RGB + DUST, seed=k),
                    headers={
                        "Authorization": f"Bearer {cam.json()['token']}",
                        "Content-Type": "image/jpeg",
                    },
                )
                assert r.status_code == 201, r.text
        tokens = [c.post("/robots", json={"id": f"r{i}"}).json()["token"] for i in range(20)]
        assert len(c.get("/cleaning/tasks").json()) == 20

    def claim(i: int) -> httpx.Response:
        return httpx.post(
            f"{servers[i % 2]}/cleaning/claim",
            headers={"Authorization": f"Bearer {tokens[i]}"},
            timeout=30,
        )

    with ThreadPoolExecutor(20) as pool:
        results = list(pool.map(claim, range(20)))
    assert [r.status_code for r in results] == [200] * 20
    assert len({r.json()["task_id"] for r in results}) == 20
    # and nothing is left to claim, on either process
    for url in servers:
        r = httpx.post(f"{url}/cleaning/claim", headers={"Authorization": f"Bearer {tokens[0]}"})
        assert r.status_code == 204


def test_frames_alternately_and_a_baseline_shared_at_once(servers: list[str]) -> None:
    a, b = servers
    with httpx.Client(headers=ADMIN, timeout=30) as c:
        assert c.post(f"{a}/panels", json={"id": "p"}).status_code == 201
        cam = c.post(f"{a}/cameras", json={"id": "c", "kind": "panel", "panel_id": "p"}).json()
        token = {"Authorization": f"Bearer {cam['token']}", "Content-Type": "image/jpeg"}
        ids = []
        for i in range(200):
            r = httpx.post(
                f"{servers[i % 2]}/cameras/c/frames",
                headers=token,
                content=panel_jpeg(CLEAN_RGB, seed=i),
            )
            assert r.status_code == 201, r.text
            ids.append(r.json()["frame_id"])
        stored = c.get(f"{b}/cameras/c/frames", params={"limit": 1000}).json()
        assert {f["frame_id"] for f in stored} == set(ids)
        assert all(f["verdict"]["modes"] for f in stored)
        # a baseline trained through one process judges the other's very next frame
        files = [("files", (f"{j}.jpg", f, "image/jpeg")) for j, f in enumerate(clean_set(6))]
        assert c.post(f"{a}/panels/p/baseline", files=files).status_code == 201
        v = httpx.post(
            f"{b}/cameras/c/frames", headers=token, content=panel_jpeg(CLEAN_RGB + DUST, seed=999)
        ).json()["verdict"]
        assert v["method"] == "baseline"
        assert v["clean"] is False


def test_a_new_token_a_new_region_and_retirement_reach_the_other_process_at_once(
    servers: list[str],
) -> None:
    a, b = servers
    stored: list[str] = []
    with httpx.Client(headers=ADMIN, timeout=30) as c:
        body = {"id": "r", "kind": "rig", "roi": [0, 0, 24, 48]}  # the left half
        old = c.post(f"{a}/cameras", json=body).json()["token"]

        def post(server: str, token: str) -> httpx.Response:
            r = httpx.post(
                f"{server}/cameras/r/frames",
                headers={"Authorization": f"Bearer {token}", "Content-Type": "image/jpeg"},
                content=halves(),
            )
            if r.status_code == 201:
                stored.append(r.json()["frame_id"])
            return r

        first = post(b, old)  # b now keeps the camera and its token
        assert first.status_code == 201, first.text
        assert near(first.json()["verdict"]["modes"], LEFT)

        # a new token through a: the old one stops on both processes with the next frame
        new = c.post(f"{a}/cameras/r/token").json()["token"]
        assert post(a, old).status_code == 401
        assert post(b, old).status_code == 401
        assert post(b, new).status_code == 201

        # a new region through a: b measures its next frame in it, though it kept the camera
        r = c.patch(f"{a}/cameras/r", json={"roi": [40, 0, 24, 48]})  # the right half
        assert r.status_code == 200, r.text
        assert near(post(a, new).json()["verdict"]["modes"], RIGHT)
        frame = post(b, new)
        assert frame.status_code == 201, frame.text
        assert near(frame.json()["verdict"]["modes"], RIGHT)
        assert frame.json()["verdict"]["roi"] == [40, 0, 24, 48]

        # retired through a: b refuses the camera's next frame
        assert c.delete(f"{a}/cameras/r").status_code == 204
        assert post(a, new).status_code == 401
        refused = post(b, new)
        assert refused.status_code == 401, refused.text
        # every 201 is a stored frame, and nothing else was stored
        kept = c.get(f"{a}/cameras/r/frames", params={"limit": 1000}).json()
        assert sorted(f["frame_id"] for f in kept) == sorted(stored)


def test_backlogs_sent_at_once_to_both_processes_are_smoothed_as_if_sent_in_order(
    servers: list[str],
) -> None:
    """Three cameras empty their buffers after an outage, each with many requests at once,
    spread over both processes. Each reading's smoothed level is the NowCast of every reading
    of its camera taken up to it, as when the frames come one by one: the two processes'
    transactions do not each smooth without the other's frame (a process alone writes its
    frames one after another, on one thread), and none of them fails, though each process's
    batches take the cameras in their own order."""
    a, b = servers
    cameras = ["s0", "s1", "s2"]
    tokens = {}
    with httpx.Client(headers=ADMIN, timeout=60) as c:
        for i, camera in enumerate(cameras):
            body = {"id": camera, "kind": "sky", "lat": 45.46, "lon": 9.19 + 0.01 * i}
            body["roi"] = [0, 0, 160, 55]
            tokens[camera] = c.post(f"{a}/cameras", json=body).json()["token"]
        with httpx.Client(base_url=b, headers=ADMIN, timeout=60) as at_b:
            assert calibrate(at_b, ADMIN, None).status_code == 201  # type: ignore[arg-type]
    start = datetime(2026, 11, 2, 6, 0, tzinfo=UTC)
    levels = [10, 10, 7, 5, 3, 1, 1, 3, 5, 7, 10, 10] * 3  # changing air: smoothing matters
    frames = [
        (camera, start + timedelta(minutes=10 * k), sky_jpeg(level, seed=k))
        for camera in cameras  # one camera after another: many of its frames at once
        for k, level in enumerate(levels)
    ]

    def post(i: int) -> httpx.Response:
        camera, taken, jpeg = frames[i]
        return httpx.post(
            f"{servers[i % 2]}/cameras/{camera}/frames",
            content=jpeg,
            params={"captured_at": taken.isoformat()},
            headers={"Authorization": f"Bearer {tokens[camera]}", "Content-Type": "image/jpeg"},
            timeout=60,
        )

    with ThreadPoolExecutor(16) as pool:
        results = list(pool.map(post, range(len(frames))))
    assert [r.status_code for r in results] == [201] * len(frames), [
        r.text for r in results if r.status_code != 201
    ][:3]
    for camera in cameras:
        stored = httpx.get(
            f"{a}/air/readings", params={"camera_id": camera, "limit": 1000}, timeout=30
        ).json()
        assert len(stored) == len(levels)
        taken = [datetime.fromisoformat(r["captured_at"]) for r in stored]
        graded = [(t, r["level"]) for t, r in zip(taken, stored, strict=True) if r["level"]]
        assert len(graded) >= 30  # a sky may fall outside the calibration: ungraded, smoothed
        expected = airquality.nowcasts(
            [t for t, _ in graded], [float(level) for _, level in graded], taken
        )
        assert [r["smoothed_level"] for r in stored] == pytest.approx(expected, rel=1e-9)
