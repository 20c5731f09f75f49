"""Real server processes for the tests that need them (several processes, kill -9)."""

from __future__ import annotations

import os
import resource
import socket
import subprocess
import sys
import threading
import time
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from typing import Any

import httpx2 as httpx
import pytest

from tests.factories import ADMIN_TOKEN, ROOT
from tests.factories.air import sky_jpeg


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def server_env(database_url: str, data_dir: Path, **extra: str) -> dict[str, str]:
    return {
        **os.environ,
        "VANTAGE_DATABASE_URL": database_url,
        "VANTAGE_DATA_DIR": str(data_dir),
        "VANTAGE_ADMIN_TOKEN": ADMIN_TOKEN,
        "VANTAGE_LOG_LEVEL": "WARNING",
        "VANTAGE_RATE_LIMIT_PER_MINUTE": "0",
        "VANTAGE_PUBLIC_REQUESTS_PER_MINUTE": "0",  # one client (this one) asks for everything
        "VANTAGE_PUBLIC_WORK_PER_MINUTE": "0",
        "VANTAGE_SOURCE_ALLOWED_NETWORKS": "127.0.0.0/8",  # the cameras these tests serve
        **extra,
    }


def start_server(
    env: dict[str, str], port: int, *, workers: int = 0, file_limit: int | None = None
) -> subprocess.Popen[bytes]:
    """The service on ``port`` as ``make run`` and the Docker image start it (``python -m
    app.serve``, with ``workers`` processes), returned once /health answers; started under
    a soft limit of ``file_limit`` open files when given (systemd's is 1,024)."""

    def limited() -> None:
        hard = resource.getrlimit(resource.RLIMIT_NOFILE)[1]
        resource.setrlimit(resource.RLIMIT_NOFILE, (file_limit, hard))

    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "app.serve",
            "--workers",
            str(workers or 1),
            "--port",
            str(port),
            "--log-level",
            "warning",
        ],
        cwd=ROOT,
        env=env,
        preexec_fn=None if file_limit is None else limited,
    )
    for _ in range(100):
        try:
            if httpx.get(f"http://127.0.0.1:{port}/health").status_code == 200:
                return proc
        except httpx.TransportError:
            time.sleep(0.1)
    proc.kill()
    pytest.fail(f"server on port {port} did not start")


JPEG = sky_jpeg(8, seed=1)


class Camera(BaseHTTPRequestHandler):
    """A camera's web server: ``/snapshot.jpg`` one JPEG; ``/mjpeg`` an MJPEG stream (a JPEG
    every 0.1 s); ``/page`` an HTML page; ``/hang`` accepts and never answers."""

    def do_GET(self) -> None:  # noqa: N802
        self.server.requests.append(self.path)  # type: ignore[attr-defined]
        if self.path == "/hang":
            time.sleep(30)
            return
        if self.path == "/page":
            body = b"<html><body>Camera login</body></html>"
            self.send_response(200)
            self.send_header("Content-Type", "text/html")
            self.send_header("Content-Length", str(len(body)))
            self.end_headers()
            self.wfile.write(body)
            return
        if self.path.startswith("/snapshot.jpg"):
            self.send_response(200)
            self.send_header("Content-Type", "image/jpeg")
            self.send_header("Content-Length", str(len(JPEG)))
            self.end_headers()
            self.wfile.write(JPEG)
            return
        if self.path == "/mjpeg":
            self.send_response(200)
            self.send_header("Content-Type", "multipart/x-mixed-replace; boundary=frame")
            self.end_headers()
            try:
                for _ in range(100):
                    self.wfile.write(
                        b"--frame\r\nContent-Type: image/jpeg\r\n"
                        + f"Content-Length: {len(JPEG)}\r\n\r\n".encode()
                        + JPEG
                        + b"\r\n"
                    )
                    time.sleep(0.1)
            except OSError:
                pass
            return
        self.send_error(404)

    def log_message(self, *args: Any) -> None:
        pass


class CameraServer:
    """``Camera`` on a port of 127.0.0.1 that can be stopped and started again."""

    def __init__(self) -> None:
        self.port = 0
        self.requests: list[str] = []
        self.start()

    def start(self) -> None:
        self.server = ThreadingHTTPServer(("127.0.0.1", self.port), Camera)
        self.server.daemon_threads = True
        self.server.requests = self.requests  # type: ignore[attr-defined]
        self.port = self.server.server_port
        threading.Thread(target=self.server.serve_forever, daemon=True).start()

    def stop(self) -> None:
        self.server.shutdown()
        self.server.server_close()

    def url(self, path: str) -> str:
        return f"http://127.0.0.1:{self.port}{path}"
