"""Source URLs reach cameras, not the service's own machine or its cloud's metadata: the
address rule at registration and at each connection, no redirects, no secrets shown back."""

from __future__ import annotations

import socket
from collections.abc import Iterator
from http.server import BaseHTTPRequestHandler
from typing import Any

import pytest
from fastapi.testclient import TestClient

from app.main import create_app
from app.platform.frames import addresses, grab
from app.platform.settings import Settings
from tests.factories import empty_tables, served

REFUSED = [
    ("http://127.0.0.1/snap.jpg", "loopback"),
    ("http://localhost:8080/snap.jpg", "loopback"),
    ("http://127.1/snap.jpg", "loopback"),
    ("http://0x7f000001/snap.jpg", "loopback"),
    ("http://2130706433/snap.jpg", "loopback"),
    ("http://0177.0.0.1/snap.jpg", "loopback"),
    ("rtsp://[::1]/stream", "loopback"),
    ("http://[::ffff:127.0.0.1]/snap.jpg", "loopback"),
    ("http://169.254.169.254/latest/meta-data/", "link-local"),
    ("http://[fe80::1]/snap.jpg", "link-local"),
    ("http://0.0.0.0/snap.jpg", "unspecified"),
    ("http://0.1.2.3/snap.jpg", "unspecified"),
    ("rtsp://224.0.0.251/stream", "multicast"),
    ("http://240.0.0.1/snap.jpg", "reserved"),
]
ALLOWED = ["rtsp://10.0.0.7:554/s", "http://192.168.1.20/snap.jpg", "https://8.8.8.8/x.jpg"]


@pytest.fixture
def strict(settings: Settings, engine: Any) -> Iterator[TestClient]:
    """The service as deployed: no network allowed beyond the rule."""
    empty_tables(engine)
    app = create_app(settings.model_copy(update={"source_allowed_networks": []}))
    with TestClient(app, raise_server_exceptions=False) as c:
        yield c


def test_refused_addresses_at_registration(strict: TestClient, admin: dict[str, str]) -> None:
    for url, rule in REFUSED:
        body = {"id": "cam", "kind": "sky", "source": {"url": url, "every_seconds": 5}}
        r = strict.post("/cameras", json=body, headers=admin)
        assert r.status_code == 422, (url, r.text)
        assert r.headers["content-type"] == "application/problem+json"
        assert f"a {rule} address" in r.json()["detail"], (url, r.json())
        assert r.json()["code"] == "source_address_refused"
    assert strict.get("/cameras", headers=admin).json() == []
    strict.post("/cameras", json={"id": "cam", "kind": "sky"}, headers=admin)
    patch = {"source": {"url": "http://169.254.169.254/", "every_seconds": 5}}
    assert strict.patch("/cameras/cam", json=patch, headers=admin).status_code == 422
    assert strict.get("/cameras/cam", headers=admin).json()["source"] is None


def test_lans_and_public_addresses_and_listed_networks_are_allowed(
    strict: TestClient, client: TestClient, admin: dict[str, str]
) -> None:
    for k, url in enumerate(ALLOWED):
        body = {"id": f"c{k}", "kind": "sky", "source": {"url": url, "every_seconds": 60}}
        assert strict.post("/cameras", json=body, headers=admin).status_code == 201, url
    # the operator's list (the tests' settings list 127.0.0.0/8)
    body = {"id": "relay", "kind": "sky", "source": {"url": REFUSED[0][0], "every_seconds": 60}}
    assert client.post("/cameras", json=body, headers=admin).status_code == 201


def test_an_unresolvable_host_is_refused(strict: TestClient, admin: dict[str, str]) -> None:
    body = {
        "id": "c",
        "kind": "sky",
        "source": {"url": "http://no-such-host.invalid/a.jpg", "every_seconds": 60},
    }
    r = strict.post("/cameras", json=body, headers=admin)
    assert r.status_code == 422
    assert "does not resolve" in r.json()["detail"]


class Answering(BaseHTTPRequestHandler):
    """Answers every request with a redirect to ``target`` (set per test), recording them."""

    target = ""
    seen: list[tuple[str, str | None]] = []

    def do_GET(self) -> None:  # noqa: N802
        self.seen.append((self.path, self.headers.get("Authorization")))
        self.send_response(302)
        self.send_header("Location", self.target)
        self.send_header("Content-Length", "0")
        self.end_headers()

    def log_message(self, *args: Any) -> None:
        pass


def test_each_connection_is_checked_again(monkeypatch: pytest.MonkeyPatch) -> None:
    """A name that resolved to a camera at registration and to loopback now: refused before
    a byte is sent; and a connection that reached a refused address despite the check (DNS
    answering otherwise the second time) is closed before its request."""
    Answering.seen = []
    with served(Answering) as base:
        with pytest.raises(grab.GrabError, match="loopback"):
            grab.grab(f"{base}/snap.jpg", username=None, password=None, timeout=2, allowed=())
        assert Answering.seen == []
        monkeypatch.setattr(grab, "resolve_url", lambda *a, **k: [])  # DNS says otherwise
        with pytest.raises(grab.GrabError, match="loopback"):
            grab.grab(f"{base}/snap.jpg", username=None, password=None, timeout=2)
        assert Answering.seen == []


def test_redirects_are_not_followed_and_credentials_stay() -> None:
    local = [addresses.networks(["127.0.0.0/8"])[0]]
    for target in ("ftp://127.0.0.1/x.jpg", "http://127.0.0.2:1/elsewhere.jpg"):
        Answering.seen = []
        Answering.target = target
        with served(Answering) as base:
            with pytest.raises(grab.GrabError, match="redirects are not followed") as caught:
                grab.grab(
                    f"{base}/snap.jpg", username="op", password="pw", timeout=2, allowed=local
                )
        assert caught.value.state == "unreachable"
        assert len(Answering.seen) == 1  # the camera itself, once; nothing followed
        assert target not in str(caught.value)


def test_query_string_secrets_are_masked(client: TestClient, admin: dict[str, str]) -> None:
    url = "http://10.0.0.9/cgi-bin/snap.cgi?chn=1&user=op&pwd=s3cret&token=t0k"
    body = {"id": "cam", "kind": "sky", "source": {"url": url, "every_seconds": 60}}
    r = client.post("/cameras", json=body, headers=admin)
    assert r.status_code == 201, r.text
    shown = r.json()["source"]["url"]
    assert shown == "http://10.0.0.9/cgi-bin/snap.cgi?chn=1&user=op&pwd=***&token=***"
    listed = str(client.get("/cameras", headers=admin).json())
    assert "s3cret" not in listed
    assert "t0k" not in listed


def test_getaddrinfo_is_what_resolves_names() -> None:
    """The rule sees what the connection would: the system resolver's answers."""
    assert addresses.resolve("localhost", 80, addresses.networks(["127.0.0.0/8", "::1/128"]))
    assert socket.getaddrinfo("0x7f000001", 80)[0][4][0] == "127.0.0.1"
