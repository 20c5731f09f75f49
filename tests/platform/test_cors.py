"""Dashboards served from another origin read the public air-quality endpoints."""

from __future__ import annotations

from typing import Any

from fastapi.testclient import TestClient

from app.main import create_app

DASHBOARD = "https://dashboard.city.example"


def test_a_page_elsewhere_reads_the_air_endpoints_and_nothing_else(
    client: TestClient, admin: dict[str, str]
) -> None:
    """Without Access-Control-Allow-Origin a browser hides the answer from the page: a city
    dashboard on its own site could not draw the map."""
    for path in ("/air/readings", "/air/isopleths", "/air/alerts"):
        r = client.get(path, headers={"Origin": DASHBOARD})
        assert r.status_code == 200, r.text
        assert r.headers["access-control-allow-origin"] == "*"
    preflight = {"Origin": DASHBOARD, "Access-Control-Request-Method": "GET"}
    r = client.options("/air/isopleths.png", headers=preflight)
    assert r.status_code == 200, r.text
    assert r.headers["access-control-allow-origin"] == "*"
    assert "GET" in r.headers["access-control-allow-methods"]

    # neither writes nor tokens: a page elsewhere cannot call the service as its user
    r = client.options(
        "/air/calibration", headers={**preflight, "Access-Control-Request-Method": "POST"}
    )
    assert r.status_code == 400
    r = client.options(
        "/air/readings", headers={**preflight, "Access-Control-Request-Headers": "authorization"}
    )
    assert r.status_code == 400
    r = client.get("/cameras", headers={**admin, "Origin": DASHBOARD})
    assert r.status_code == 200
    assert "access-control-allow-origin" not in r.headers
    r = client.options("/cameras", headers=preflight)
    assert "access-control-allow-origin" not in r.headers


def test_a_page_elsewhere_can_page_and_revalidate(client: TestClient) -> None:
    """The next page of readings is named only by ``Link``, which a browser hides from a page
    of another origin unless exposed; a page may also revalidate the map itself."""
    r = client.get("/air/readings?limit=1", headers={"Origin": DASHBOARD})
    exposed = {h.strip().lower() for h in r.headers["access-control-expose-headers"].split(",")}
    assert {"link", "etag", "retry-after", "x-request-id"} <= exposed
    preflight = {
        "Origin": DASHBOARD,
        "Access-Control-Request-Method": "GET",
        "Access-Control-Request-Headers": "if-none-match",
    }
    r = client.options("/air/isopleths", headers=preflight)
    assert r.status_code == 200, r.text
    assert "if-none-match" in r.headers["access-control-allow-headers"].lower()


def test_the_origins_are_a_setting(settings: Any, app: Any) -> None:
    """One dashboard named: others get no header; [] turns it off. (``app`` empties the
    tables; these tests run apps of their own settings.)"""
    named = create_app(settings.model_copy(update={"cors_origins": [DASHBOARD]}))
    with TestClient(named) as client:
        r = client.get("/air/readings", headers={"Origin": DASHBOARD})
        assert r.headers["access-control-allow-origin"] == DASHBOARD
        r = client.get("/air/readings", headers={"Origin": "https://elsewhere.example"})
        assert r.status_code == 200
        assert "access-control-allow-origin" not in r.headers
    off = create_app(settings.model_copy(update={"cors_origins": []}))
    with TestClient(off) as client:
        r = client.get("/air/readings", headers={"Origin": DASHBOARD})
        assert r.status_code == 200
        assert "access-control-allow-origin" not in r.headers
