"""What a client sends, bounded in time (``app.protocol``), and the open files a process may
hold (``app.serve.raise_file_limit``): a real server, as ``make run`` starts it, and raw
sockets that send too little, too slowly, or stop."""

from __future__ import annotations

import contextlib
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

import cv2
import httpx2 as httpx
import numpy as np
import pytest
from sqlalchemy import Engine

from app.protocol import MAX_HEADER_BYTES
from tests.conftest import ADMIN_TOKEN, ROOT, _empty_tables, make_jpeg
from tests.servers import free_port, server_env, start_server

ADMIN = {"Authorization": f"Bearer {ADMIN_TOKEN}"}
HEADERS_S = 1.0
IDLE_S = 1.5


@dataclass(frozen=True)
class Server:
    port: int
    token: str
    """Camera "c"'s."""
    pid: int


@pytest.fixture
def server(database_url: str, engine: Engine, tmp_path: Path) -> Iterator[Server]:
    """A server whose clients have 1 s for their headers and may pause 1.5 s in a body; a
    rig camera "c" and its token."""
    _empty_tables(engine)
    env = server_env(
        database_url,
        tmp_path,
        VANTAGE_REQUEST_HEADER_TIMEOUT_SECONDS=str(HEADERS_S),
        VANTAGE_REQUEST_IDLE_TIMEOUT_SECONDS=str(IDLE_S),
        VANTAGE_MAX_BODY_BYTES=str(40 * 2**20),  # for a frame larger than the sockets' buffers
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


def _closed_after(sock: socket.socket, *, within: float, trickle: bytes = b"") -> float:
    """Seconds until the server closes ``sock`` (sending ``trickle`` a byte every 0.2 s the
    while); fails past ``within``."""
    start = time.monotonic()
    sock.settimeout(0.2)
    sent = 0
    while time.monotonic() - start < within:
        try:
            data = sock.recv(4096)
        except TimeoutError:
            if sent < len(trickle):
                try:
                    sock.sendall(trickle[sent : sent + 1])
                except OSError:  # reset: closed
                    return time.monotonic() - start
                sent += 1
            continue
        except ConnectionResetError:
            return time.monotonic() - start
        if data == b"" or data.startswith(b"HTTP/1.1 4"):
            return time.monotonic() - start
    pytest.fail(f"the connection was still open after {within} s")


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


def _upload_head(token: str, length: int) -> bytes:
    """The request line and headers of a frame of ``length`` bytes from camera "c"."""
    return (
        f"POST /cameras/c/frames HTTP/1.1\r\nHost: x\r\nAuthorization: Bearer {token}\r\n"
        f"Content-Type: image/jpeg\r\nContent-Length: {length}\r\n\r\n"
    ).encode()


def _metric(port: int, phase: str) -> float:
    text = httpx.get(f"http://127.0.0.1:{port}/metrics", headers=ADMIN).text
    line = f'vantage_connections_timed_out_total{{phase="{phase}"}} '
    return next((float(x[len(line) :]) for x in text.splitlines() if x.startswith(line)), 0.0)


def test_a_connection_that_sends_nothing_is_closed(server: Server) -> None:
    """uvicorn holds such a connection for good: 1,100 of them made a process (its soft limit
    1,024 files) reset every new connection, /health included, for as long as they stayed."""
    port = server.port
    with socket.create_connection(("127.0.0.1", port)) as sock:
        took = _closed_after(sock, within=10)
    assert HEADERS_S * 0.9 <= took < HEADERS_S + 3
    assert _metric(port, "headers") == 1


def test_headers_sent_a_byte_at_a_time_are_cut_off(server: Server) -> None:
    """Each byte restarts uvicorn's keep-alive timeout; the deadline here is for the whole of
    the headers."""
    port = server.port
    headers = b"GET /health HTTP/1.1\r\nHost: x\r\n" + b"X-Slow: " + b"y" * 200
    with socket.create_connection(("127.0.0.1", port)) as sock:
        took = _closed_after(sock, within=10, trickle=headers)
    assert HEADERS_S * 0.9 <= took < HEADERS_S + 3


def test_headers_past_64_kb_get_431_and_the_rest_is_not_kept(server: Server) -> None:
    """httptools keeps every header: one connection sent 300 MB of them in 3 s and the process
    grew by 356 MB. Past 64 kB it gets 431 (problem+json) and is closed; 20 kB are served."""
    port = server.port
    padding = b"X-Pad: " + b"a" * 1000 + b"\r\n"
    with socket.create_connection(("127.0.0.1", port)) as sock:
        sock.settimeout(10)
        sock.sendall(b"GET /health HTTP/1.1\r\nHost: x\r\n")
        with contextlib.suppress(OSError):  # reset once refused
            for _ in range(1000):
                sock.sendall(padding * 100)  # 100 kB at a time, 100 MB in all
        answer = _response(sock)
    head, _, body = answer.partition(b"\r\n\r\n")
    assert head.startswith(b"HTTP/1.1 431")
    assert b"content-type: application/problem+json" in head
    assert json.loads(body)["code"] == "headers_too_large"
    assert _metric(port, "header_size") == 1

    r = httpx.get(f"http://127.0.0.1:{port}/health", headers={"X-Pad": "a" * 20_000})
    assert r.status_code == 200


def test_a_few_pipelined_requests_are_answered_and_a_flood_of_them_is_not(
    server: Server,
) -> None:
    """uvicorn parsed every pipelined request it received into one of its own, kept until
    answered: 1 MB of them made the process grow by 71 MB. Past 16 the connection is closed
    (here a thousand GETs); a few are answered in order, as HTTP/1.1 has them."""
    port = server.port
    get = b"GET /health HTTP/1.1\r\nHost: x\r\n\r\n"
    with socket.create_connection(("127.0.0.1", port)) as sock:
        sock.settimeout(10)
        sock.sendall(get * 5)
        assert [_response(sock)[:12] for _ in range(5)] == [b"HTTP/1.1 200"] * 5

    with socket.create_connection(("127.0.0.1", port)) as sock:
        sock.settimeout(10)
        with contextlib.suppress(OSError):
            sock.sendall(get * 1000)
        received = b""
        with contextlib.suppress(ConnectionResetError):
            while data := sock.recv(65536):
                received += data
    assert received.count(b"HTTP/1.1 200") <= 16
    assert _metric(port, "pipelined") == 1


def test_a_body_answered_early_is_not_taken_for_the_next_requests_headers(
    server: Server,
) -> None:
    """An upload with a wrong token is answered 401 before its body is read; the body goes on
    arriving after the answer, and the connection is kept for the next request. Counted as
    that request's headers, 700 kB of it got a 431 the client read as the answer to its next
    request."""
    port = server.port
    body = make_jpeg(640, 480, noise=40, seed=5)
    assert len(body) > 2 * MAX_HEADER_BYTES
    with socket.create_connection(("127.0.0.1", port)) as sock:
        sock.settimeout(10)
        sock.sendall(_upload_head("vc_not-a-token", len(body)))
        assert _response(sock)[:12] == b"HTTP/1.1 401"
        sock.sendall(body)
        sock.sendall(b"GET /health HTTP/1.1\r\nHost: x\r\n\r\n")
        assert _response(sock)[:12] == b"HTTP/1.1 200"
    assert _metric(port, "header_size") == 0


def test_a_body_that_stops_coming_is_dropped_and_nothing_stored(server: Server) -> None:
    """A camera that lost its link mid-upload: no FIN, no RST, nothing more. Its connection is
    closed once no byte has come for the idle timeout, and the frame is not stored."""
    port, token = server.port, server.token
    body = make_jpeg(320, 240, noise=20, seed=3)
    head = _upload_head(token, len(body))
    with socket.create_connection(("127.0.0.1", port)) as sock:
        sock.sendall(head + body[: len(body) // 2])
        took = _closed_after(sock, within=15)
    assert IDLE_S * 0.9 <= took < IDLE_S + 3
    assert _metric(port, "body") == 1
    # the endpoint saw its client go: counted as nginx counts it, not as a failure (500)
    text = httpx.get(f"http://127.0.0.1:{port}/metrics", headers=ADMIN).text
    upload = 'method="POST",route="/cameras/{camera_id}/frames"'
    assert f'vantage_http_requests_total{{{upload},status="499"}} 1.0' in text
    assert 'status="500"' not in text
    assert 'vantage_frames_rejected_total{camera_id="c",reason="client_disconnected"} 1.0' in text
    camera = httpx.get(f"http://127.0.0.1:{port}/cameras/c", headers=ADMIN).json()
    assert camera["last_captured_at"] is None


def test_an_answer_the_client_stops_reading_is_dropped(server: Server) -> None:
    """A client that stops reading (a dashboard's tab put to sleep mid-download): uvicorn held
    the rest of the answer in memory and the connection for good, its close waiting for the
    bytes to go. Measured with an 8 MB frame: closed 3 s after the client stopped (its idle
    timeout then), 2.8 MB of it sent."""
    port, token = server.port, server.token
    rng = np.random.default_rng(11)
    noise = (rng.random((2400, 3000, 3)) * 255).astype(np.uint8)
    jpeg = cv2.imencode(".jpg", noise, [cv2.IMWRITE_JPEG_QUALITY, 95])[1].tobytes()
    assert len(jpeg) > 6 * 2**20  # more than the kernel's buffers take on both sides
    r = httpx.post(
        f"http://127.0.0.1:{port}/cameras/c/frames",
        content=jpeg,
        headers={"Authorization": f"Bearer {token}", "Content-Type": "image/jpeg"},
        timeout=60,
    )
    assert r.status_code == 201, r.text
    with socket.socket() as sock:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
        sock.connect(("127.0.0.1", port))
        sock.sendall(
            f"GET /frames/{r.json()['frame_id']}/image HTTP/1.1\r\nHost: x\r\n"
            f"Authorization: Bearer {ADMIN_TOKEN}\r\n\r\n".encode()
        )
        time.sleep(IDLE_S + 2)  # reading nothing
        sock.settimeout(10)
        received = 0
        with contextlib.suppress(ConnectionResetError):
            while data := sock.recv(1 << 20):
                received += len(data)
    assert 0 < received < len(jpeg)
    assert _metric(port, "response") == 1


def test_slow_uploads_and_kept_alive_connections_are_served(server: Server) -> None:
    """A body that keeps coming may take longer than any deadline (here 4 s in 10 pieces,
    after headers sent slowly but within theirs); the same connection's next request, sent
    after a pause, is answered too."""
    port, token = server.port, server.token
    body = make_jpeg(320, 240, noise=20, seed=4)
    head = _upload_head(token, len(body))
    with socket.create_connection(("127.0.0.1", port)) as sock:
        sock.settimeout(10)
        sock.sendall(head[:20])
        time.sleep(0.5)
        sock.sendall(head[20:])
        pieces = [body[k * len(body) // 10 : (k + 1) * len(body) // 10] for k in range(10)]
        for piece in pieces:
            time.sleep(0.4)
            sock.sendall(piece)
        assert _response(sock)[:12] == b"HTTP/1.1 201"
        time.sleep(0.5)
        sock.sendall(b"GET /health HTTP/1.1\r\nHost: x\r\n\r\n")
        assert _response(sock)[:12] == b"HTTP/1.1 200"
    camera = httpx.get(f"http://127.0.0.1:{port}/cameras/c", headers=ADMIN).json()
    assert camera["last_captured_at"] is not None
    assert _metric(port, "body") == _metric(port, "headers") == 0


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


def test_the_server_lifts_its_soft_file_limit_to_the_hard_one(server: Server) -> None:
    """Started under a soft limit of 256 (systemd's default is 1,024), the process serving
    (``python -m app.serve`` execs uvicorn: the same process) runs with its hard limit: a
    thousand connected cameras no longer take every file it may open."""
    hard = resource.getrlimit(resource.RLIMIT_NOFILE)[1]
    limits = Path(f"/proc/{server.pid}/limits").read_text().splitlines()
    files = next(x for x in limits if x.startswith("Max open files")).split()
    assert [int(files[3]), int(files[4])] == [hard, hard]
    assert hard > 256


IDLE_ENV = "VANTAGE_REQUEST_IDLE_TIMEOUT_SECONDS"


@pytest.mark.parametrize(
    ("name", "value"),
    [
        *((IDLE_ENV, v) for v in ["abc", "0", "-5", "nan", "7200"]),
        ("VANTAGE_SHUTDOWN_GRACE_SECONDS", "-1"),
    ],
)
def test_a_wrong_deadline_stops_the_start_with_its_name(name: str, value: str) -> None:
    proc = subprocess.run(
        [sys.executable, "-m", "app.serve", "--port", str(free_port())],
        cwd=ROOT,
        env={**os.environ, name: value},
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert proc.returncode == 1
    assert f"{name} must be" in proc.stderr


@pytest.mark.parametrize("workers", [1, 2])
def test_the_server_logs_json_lines_only_and_one_a_request(
    database_url: str, engine: Engine, tmp_path: Path, workers: int
) -> None:
    """uvicorn's own lines (its start and stop, a request that is not HTTP; with several
    workers, those of the process supervising them) came as plain text between the JSON
    ones, and its access line doubled ``vantage.access``'s for every request, without the
    request id."""
    _empty_tables(engine)
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
