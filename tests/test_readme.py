"""The README's first session, run as written against the service started as ``make run``
starts it: its commands must work on a fresh data directory, with the sample frame shipped."""

from __future__ import annotations

import json
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from tests.factories import ROOT
from tests.servers import free_port, server_env, start_server


def first_session() -> str:
    """The shell block under "A first session", without its first line (``make run &``,
    which the test does itself)."""
    readme = (ROOT / "README.md").read_text()
    block = re.search(r"## A first session\n\n```sh\n(.*?)```", readme, re.S)
    assert block is not None, "README has no first session"
    lines = block.group(1).splitlines()
    assert lines[0].startswith("make run &")
    return "\n".join(lines[1:])


@pytest.mark.slow  # a real server or camera process, seconds of waiting
@pytest.mark.skipif(shutil.which("curl") is None, reason="the README's session uses curl")
def test_the_first_session_runs_as_written(tmp_path: Path) -> None:
    (tmp_path / "docs").symlink_to(ROOT / "docs")
    env = server_env(f"sqlite:///{tmp_path / 'data' / 'vantage.db'}", tmp_path / "data")
    del env["VANTAGE_ADMIN_TOKEN"]  # made at the first start, as on a fresh clone
    port = free_port()
    subprocess.run(
        [str(Path(sys.executable).with_name("alembic")), "upgrade", "head"],
        cwd=ROOT,
        env=env,
        check=True,
        capture_output=True,
    )
    proc = start_server(env, port)
    try:
        script = first_session().replace("localhost:8000", f"127.0.0.1:{port}")
        done = subprocess.run(
            ["bash", "-euo", "pipefail", "-c", script],
            cwd=tmp_path,
            env=env,
            capture_output=True,
            text=True,
            timeout=60,
        )
    finally:
        proc.terminate()
        proc.wait(10)
    assert done.returncode == 0, done.stderr
    answer = json.loads(done.stdout)
    assert answer["camera_id"] == "street-1"
    assert answer["verdict"]["kind"] == "sky"
    assert len(answer["verdict"]["modes"]) == 3
    assert answer["verdict"]["reason"] == "air-quality model not calibrated (POST /air/calibration)"
