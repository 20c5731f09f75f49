"""``python -m app.serve``: uvicorn as the service runs it (the limits on clients are the
reverse proxy's, docs/operations.md): idle connections kept longer than a proxy's, the soft
limit on open files lifted, the shutdown grace checked, JSON log lines only."""

from __future__ import annotations

import json
import os
import resource
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import httpx2 as httpx
import pytest
from sqlalchemy import Engine

from tests.factories import ADMIN_TOKEN, ROOT, empty_tables
from tests.servers import free_port, server_env, start_server

ADMIN = {"Authorization": f"Bearer {ADMIN_TOKEN}"}


@dataclass(frozen=True)
class Server:
    port: int
    token: str
    """Camera "c"'s."""
    pid: int


@pytest.fixture
def server(database_url: str, engine: Engine, tmp_path: Path) -> Iterator[Server]:
    """A server started as ``make run`` starts it, under a soft limit of 256 open files; a rig
    camera "c" and its token."""
    empty_tables(engine)
    env = server_env(
        database_url,
        tmp_path,
    )
    port = free_port()
    proc = start_server(env, port, file_limit=256)
    try:
        r = httpx.post(
            f"http://127.0.0.1:{port}/cameras", json={"id": "c", "kind": "rig"}, headers=ADMIN
        )
        yield Server(port, r.json()["token"], proc.pid)
    finally:
        proc.terminate()
        proc.wait(timeout=30)


def _response(sock: socket.socket) -> bytes:
    """One whole response read from ``sock`` (its head, then Content-Length bytes)."""
    data = b""
    while b"\r\n\r\n" not in data:
        data += sock.recv(65536) or pytest.fail(f"closed after {data!r}")
    head, _, body = data.partition(b"\r\n\r\n")
    length = next(
        int(line.split(b":")[1])
        for line in head.lower().split(b"\r\n")
        if line.startswith(b"content-length:")
    )
    while len(body) < length:
        body += sock.recv(65536) or pytest.fail("closed mid-body")
    return head + b"\r\n\r\n" + body


@pytest.mark.slow
def test_a_connection_idle_longer_than_uvicorns_keep_alive_is_still_served(
    server: Server,
) -> None:
    """uvicorn closed a connection idle 5 s, the moment a load balancer (idle 60 s) might send
    on it: of 12 requests sent after ~5 s, 4 found it closed (a 502 from the balancer). Kept
    75 s now."""
    get = b"GET /health HTTP/1.1\r\nHost: x\r\n\r\n"
    with socket.create_connection(("127.0.0.1", server.port)) as sock:
        sock.settimeout(10)
        sock.sendall(get)
        assert _response(sock)[:12] == b"HTTP/1.1 200"
        time.sleep(6)
        sock.sendall(get)
        assert _response(sock)[:12] == b"HTTP/1.1 200"


@pytest.mark.slow  # a real server or camera process, seconds of waiting
def test_the_server_lifts_its_soft_file_limit_to_the_hard_one(server: Server) -> None:
    """Started under a soft limit of 256 (systemd's default is 1,024), the process serving
    (``python -m app.serve`` execs uvicorn: the same process) runs with its hard limit: a
    thousand connected cameras no longer take every file it may open."""
    hard = resource.getrlimit(resource.RLIMIT_NOFILE)[1]
    limits = Path(f"/proc/{server.pid}/limits").read_text().splitlines()
    files = next(x for x in limits if x.startswith("Max open files")).split()
    assert [int(files[3]), int(files[4])] == [hard, hard]
    assert hard > 256


def test_a_wrong_shutdown_grace_stops_the_start_with_its_name() -> None:
    proc = subprocess.run(
        [sys.executable, "-m", "app.serve", "--port", str(free_port())],
        cwd=ROOT,
        env={**os.environ, "VANTAGE_SHUTDOWN_GRACE_SECONDS": "-1"},
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert proc.returncode != 0
    assert "shutdown_grace_seconds" in proc.stderr


@pytest.mark.slow  # a real server process, seconds of waiting
@pytest.mark.parametrize("workers", [1, 2])
def test_the_server_logs_json_lines_only_and_one_a_request(
    database_url: str, engine: Engine, tmp_path: Path, workers: int
) -> None:
    """uvicorn's own lines (its start and stop, a request that is not HTTP; with several
    workers, those of the process supervising them) came as plain text between the JSON
    ones, and its access line doubled ``vantage.access``'s for every request, without the
    request id."""
    empty_tables(engine)
    port = free_port()
    env = server_env(database_url, tmp_path, VANTAGE_LOG_LEVEL="INFO")
    proc = subprocess.Popen(
        [sys.executable, "-m", "app.serve", "--port", str(port), "--workers", str(workers)],
        cwd=ROOT,
        env=env,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        for _ in range(100):
            try:
                if httpx.get(f"http://127.0.0.1:{port}/health").status_code == 200:
                    break
            except httpx.TransportError:
                time.sleep(0.1)
        assert httpx.get(f"http://127.0.0.1:{port}/cameras", headers=ADMIN).status_code == 200
        with socket.create_connection(("127.0.0.1", port)) as sock:
            sock.settimeout(10)
            sock.sendall(b"NOT HTTP AT ALL\r\n\r\n")
            assert sock.recv(65536).startswith(b"HTTP/1.1 400")
    finally:
        proc.terminate()
        _, err = proc.communicate(timeout=30)
    records = [json.loads(line) for line in err.splitlines()]  # each line JSON, or this fails
    logged = {(r["logger"], r["message"]) for r in records}
    assert ("uvicorn.error", "Invalid HTTP request received.") in logged
    assert any(r["logger"] == "uvicorn.error" and "Started server" in r["message"] for r in records)
    if workers > 1:
        assert any("Started parent process" in r["message"] for r in records)
    requests = [r for r in records if r["logger"] == "vantage.access"]
    assert [(r["method"], r["path"]) for r in requests if r["path"] == "/cameras"] == [
        ("GET", "/cameras")
    ]
    assert not any(r["logger"] == "uvicorn.access" for r in records)
    assert not any("color_message" in r for r in records)
