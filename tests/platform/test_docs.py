"""The API's documentation pages work on a network closed to the internet."""

from __future__ import annotations

import re

import pytest
from fastapi.testclient import TestClient


@pytest.mark.parametrize(
    ("page", "script"), [("/docs", "swagger-ui-bundle.js"), ("/redoc", "redoc.standalone.js")]
)
def test_the_docs_pages_load_everything_from_the_service(
    client: TestClient, page: str, script: str
) -> None:
    """FastAPI's pages loaded their scripts and styles from cdn.jsdelivr.net: without the
    internet (street cameras' and robot cells' networks often have none), a blank page."""
    r = client.get(page)
    assert r.status_code == 200
    assert r.headers["content-type"].startswith("text/html")
    assert "/openapi.json" in r.text
    linked = re.findall(r'(?:src|href)="([^"]+)"', r.text)
    assert any(u.endswith(script) for u in linked), linked
    assert not [u for u in linked if "//" in u]  # no other host
    assert "//" not in "".join(re.findall(r"url: ?'([^']*)'", r.text))
    for url in linked:
        asset = client.get(url)
        assert asset.status_code == 200, url
        assert len(asset.content) > 1000, url
    bundle = client.get(next(u for u in linked if u.endswith(script)))
    assert bundle.headers["content-type"].startswith("text/javascript")


def test_a_gzipped_asset_has_a_weak_etag_and_is_revalidated(client: TestClient) -> None:
    """A strong ETag names one body; the gzipped one is another, so it goes weak (RFC 9110
    §8.8.1), and ``If-None-Match`` with it still answers 304."""
    url = "/static-offline-docs/swagger-ui-bundle.js"
    plain = client.get(url, headers={"Accept-Encoding": "identity"})
    zipped = client.get(url, headers={"Accept-Encoding": "gzip"})
    assert "content-encoding" not in plain.headers
    assert zipped.headers["content-encoding"] == "gzip"
    assert zipped.content == plain.content  # decoded by the client
    strong = plain.headers["etag"]
    assert not strong.startswith("W/")
    assert zipped.headers["etag"] == f"W/{strong}"
    again = client.get(url, headers={"Accept-Encoding": "gzip", "If-None-Match": f"W/{strong}"})
    assert again.status_code == 304


def test_the_docs_know_how_to_authenticate(client: TestClient) -> None:
    """``/docs`` has an Authorize button (Bearer and HTTP Basic declared), and every operation
    that may answer 401 says it takes them; public ones say nothing."""
    schema = client.get("/openapi.json").json()
    schemes = schema["components"]["securitySchemes"]
    assert schemes["bearer"] == {**schemes["bearer"], "type": "http", "scheme": "bearer"}
    assert schemes["basic"] == {**schemes["basic"], "type": "http", "scheme": "basic"}
    operations = {
        (m.upper(), p): o
        for p, item in schema["paths"].items()
        for m, o in item.items()
        if isinstance(o, dict)
    }
    for key, op in operations.items():
        assert ("security" in op) == ("401" in op["responses"]), key
    both = [{"bearer": []}, {"basic": []}]
    assert operations["POST", "/cameras/{camera_id}/frames"]["security"] == both
    assert operations["POST", "/admin/retention/sweep"]["security"] == [{"bearer": []}]
    assert "security" not in operations["GET", "/air/latest"]
    assert "security" not in operations["GET", "/health"]
