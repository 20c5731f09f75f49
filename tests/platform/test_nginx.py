"""deploy/nginx.conf in front of the service: it parses, proxies, and its limit_req refuses a
client's crowd (429) before the service sees it, while a camera's frames pass."""

from __future__ import annotations

import shutil
import subprocess
import time
from collections.abc import Iterator
from pathlib import Path

import httpx2 as httpx
import pytest

from tests.factories import ROOT, make_jpeg
from tests.servers import free_port

NGINX = shutil.which("nginx") or (
    Path("/usr/sbin/nginx") if Path("/usr/sbin/nginx").exists() else None
)
pytestmark = pytest.mark.skipif(NGINX is None, reason="needs nginx (apt install nginx-light)")


@pytest.fixture
def proxy(live: str, tmp_path: Path) -> Iterator[str]:
    """nginx with the deployment's own configuration, its upstream the live service."""
    port = free_port()
    conf = (ROOT / "deploy" / "nginx.conf").read_text()
    conf = conf.replace("server vantage:8000;", f"server {live.removeprefix('http://')};")
    conf = conf.replace("listen 80;", f"listen 127.0.0.1:{port};")
    assert f"127.0.0.1:{port}" in conf
    (tmp_path / "vantage.conf").write_text(conf)
    temp = tmp_path / "temp"
    temp.mkdir()
    (tmp_path / "nginx.conf").write_text(
        f"""
        daemon off;
        pid {tmp_path}/nginx.pid;
        error_log {tmp_path}/error.log warn;
        events {{ worker_connections 256; }}
        http {{
            access_log off;
            client_body_temp_path {temp}/body;
            proxy_temp_path {temp}/proxy;
            fastcgi_temp_path {temp}/fastcgi;
            uwsgi_temp_path {temp}/uwsgi;
            scgi_temp_path {temp}/scgi;
            include {tmp_path}/vantage.conf;
        }}
        """
    )
    args = [str(NGINX), "-p", str(tmp_path), "-c", str(tmp_path / "nginx.conf")]
    check = subprocess.run([*args, "-t"], capture_output=True, text=True)
    assert check.returncode == 0, check.stderr
    proc = subprocess.Popen(args, stderr=subprocess.DEVNULL)
    url = f"http://127.0.0.1:{port}"
    try:
        for _ in range(100):
            try:
                httpx.get(f"{url}/health")
                break
            except httpx.TransportError:
                time.sleep(0.05)
        yield url
    finally:
        proc.terminate()
        proc.wait(10)


def test_nginx_refuses_a_crowd_and_lets_cameras_through(proxy: str, admin: dict[str, str]) -> None:
    with httpx.Client(base_url=proxy, timeout=30) as http:
        cam = http.post("/cameras", json={"id": "c", "kind": "rig"}, headers=admin).json()
        answers = [http.get("/air/latest") for _ in range(120)]
        assert answers[0].status_code == 200
        # 10 a second with bursts of 50: 120 at once are too many
        refused = next(r for r in answers if r.status_code == 429)
        assert refused.headers["content-type"].startswith("text/html")  # nginx's, not ours
        assert "nginx/" not in refused.text  # server_tokens off
        for k in range(5):  # the camera's frames are not counted by nginx
            r = http.post(
                "/cameras/c/frames",
                content=make_jpeg(seed=k, noise=3),
                headers={"Authorization": f"Bearer {cam['token']}", "Content-Type": "image/jpeg"},
            )
            assert r.status_code == 201, r.text
