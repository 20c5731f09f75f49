"""Real server processes for the tests that need them (several processes, kill -9)."""

from __future__ import annotations

import os
import resource
import socket
import subprocess
import sys
import time
from pathlib import Path

import httpx2 as httpx
import pytest

from tests.factories import ADMIN_TOKEN, ROOT


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
