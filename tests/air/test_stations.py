"""Reference stations over HTTP: registering them, importing their readings (JSON and CSV),
reading both; bad input refused whole."""

from __future__ import annotations

from datetime import UTC, datetime, timedelta
from typing import Any

from fastapi.testclient import TestClient

STATION = {"id": "viale-marche", "name": "Viale Marche", "lat": 45.496, "lon": 9.193}


def create(client: TestClient, admin: dict[str, str], **over: Any) -> Any:
    return client.post("/air/stations", json={**STATION, **over}, headers=admin)


def test_a_station_is_registered_read_changed_and_removed(
    client: TestClient, admin: dict[str, str]
) -> None:
    assert create(client, admin).status_code == 201
    assert create(client, admin).status_code == 409
    assert client.post("/air/stations", json=STATION).status_code == 401
    listed = client.get("/air/stations").json()  # public
    assert listed == [{**STATION, "latest": None}]
    moved = client.patch(
        "/air/stations/viale-marche", json={"lat": 45.5, "name": "Marche"}, headers=admin
    )
    assert moved.status_code == 200, moved.text
    assert (moved.json()["lat"], moved.json()["name"]) == (45.5, "Marche")
    cleared = client.patch("/air/stations/viale-marche", json={"lat": None}, headers=admin)
    assert cleared.status_code == 422
    assert client.get("/air/stations/viale-marche").json()["lon"] == STATION["lon"]
    assert client.delete("/air/stations/viale-marche", headers=admin).status_code == 204
    assert client.get("/air/stations/viale-marche").status_code == 404


def test_bad_stations_are_refused_naming_the_field(
    client: TestClient, admin: dict[str, str]
) -> None:
    for over, field in (({"lat": 91.0}, "lat"), ({"lon": -181.0}, "lon"), ({"id": "a b"}, "id")):
        r = create(client, admin, **over)
        assert r.status_code == 422, over
        assert field in r.text
    assert client.get("/air/stations").json() == []


def test_readings_are_stored_replaced_and_paged(client: TestClient, admin: dict[str, str]) -> None:
    """JSON or CSV; a time sent again takes its new value (an import can be repeated); the
    count says the distinct times stored; newest first, paged; the station lists its
    latest."""
    create(client, admin)
    path = "/air/stations/viale-marche/readings"
    first = [{"at": f"2025-01-29T{h:02d}:00:00Z", "pm25": 10.0 + h} for h in range(8, 12)]
    r = client.post(path, json=first, headers=admin)
    assert r.status_code == 200, r.text
    assert r.json() == {"station_id": "viale-marche", "stored": 4}
    csv_body = "at,pm25\n2025-01-29T11:00:00Z,30.5\n2025-01-29T12:00:00+01:00,25\n"
    r = client.post(path, content=csv_body, headers={**admin, "Content-Type": "text/csv"})
    assert r.json()["stored"] == 1  # 12:00+01:00 is 11:00Z: the file's last value stands
    rows = client.get(path).json()
    assert [(x["at"], x["pm25"]) for x in rows] == [
        ("2025-01-29T11:00:00Z", 25.0),  # replaced
        ("2025-01-29T10:00:00Z", 20.0),
        ("2025-01-29T09:00:00Z", 19.0),
        ("2025-01-29T08:00:00Z", 18.0),
    ]
    page = client.get(path, params={"limit": 2, "offset": 2}).json()
    assert [x["at"] for x in page] == ["2025-01-29T09:00:00Z", "2025-01-29T08:00:00Z"]
    since = client.get(path, params={"since": "2025-01-29T10:00:00Z"}).json()
    assert len(since) == 2
    latest = client.get("/air/stations/viale-marche").json()["latest"]
    assert latest == {"at": "2025-01-29T11:00:00Z", "pm25": 25.0}


def test_a_bad_import_is_refused_whole_naming_its_row(
    client: TestClient, admin: dict[str, str]
) -> None:
    create(client, admin)
    path = "/air/stations/viale-marche/readings"
    good = {"at": "2025-01-29T08:00:00Z", "pm25": 12.0}
    for bad, words in (
        ({"at": "2025-01-29T09:00:00Z", "pm25": -1}, "pm25"),
        ({"at": "yesterday", "pm25": 3}, "at"),
        ({"at": "2025-01-29T09:00:00Z"}, "pm25"),
    ):
        r = client.post(path, json=[good, bad], headers=admin)
        assert r.status_code == 422, bad
        assert r.json()["detail"].startswith(f"readings[1].{words}: ")
    nan = client.post(
        path,
        content='[{"at": "2025-01-29T09:00:00Z", "pm25": NaN}]',
        headers={**admin, "Content-Type": "application/json"},
    )
    assert nan.status_code == 422
    csv_bad = "at,pm25\n2025-01-29T08:00:00Z,12\n2025-01-29T09:00:00Z,lots\n"
    r = client.post(path, content=csv_bad, headers={**admin, "Content-Type": "text/csv"})
    assert r.status_code == 422
    assert r.json()["detail"].startswith("line 3, pm25")
    no_header = client.post(
        path, content="when,value\nx,1\n", headers={**admin, "Content-Type": "text/csv"}
    )
    assert "at and pm25" in no_header.json()["detail"]
    assert client.get(path).json() == []  # nothing of a refused import
    other = client.post(path, content=b"x", headers={**admin, "Content-Type": "image/png"})
    assert other.status_code == 415
    unknown = client.post("/air/stations/nowhere/readings", json=[good], headers=admin)
    assert unknown.status_code == 404
    assert client.post(path, json=[good]).status_code == 401


def test_the_map_is_anchored_by_the_stations(client: TestClient, admin: dict[str, str]) -> None:
    """Stations' newest readings in the window are the map's data points, with the small
    error of a measurement: each is drawn in its own category's band (kriging passes by
    them), named in the collection's ``stations`` with its value and time, and in the PNG;
    stations alone make a map; a reading older than the window is left out."""
    now = datetime.now(UTC).replace(microsecond=0)
    places = {"a": (45.46, 9.15, 6.0), "b": (45.48, 9.19, 30.0), "c": (45.45, 9.22, 60.0)}
    for sid, (lat, lon, pm) in places.items():
        made = create(client, admin, id=sid, name=f"Station {sid}", lat=lat, lon=lon)
        assert made.status_code == 201
        at = (now - timedelta(minutes=10)).isoformat()
        r = client.post(
            f"/air/stations/{sid}/readings", json=[{"at": at, "pm25": pm}], headers=admin
        )
        assert r.status_code == 200, r.text
    old = (now - timedelta(hours=5)).isoformat()
    create(client, admin, id="old", lat=45.47, lon=9.2)
    client.post("/air/stations/old/readings", json=[{"at": old, "pm25": 90.0}], headers=admin)
    fc = client.get("/air/isopleths", params={"method": "kriging", "max_distance": 8000}).json()
    shown = {s["station_id"]: s for s in fc["stations"]}
    assert set(shown) == {"a", "b", "c"}
    expected = {"a": "Very Good", "b": "Poor", "c": "Very Poor"}  # European bands, Milan
    for sid, s in shown.items():
        assert s["value"] == places[sid][2]
        assert s["category"] == expected[sid]
        assert s["band"] == s["category"]  # the map at the station is its reading
    assert fc["cameras"] == []
    assert {b["properties"]["category"] for b in fc["features"]} >= set(expected.values())
    assert fc["islands"][0]["station_ids"] == ["a", "b", "c"]
    png = client.get("/air/isopleths.png", params={"method": "kriging", "max_distance": 8000})
    assert png.status_code == 200
    assert png.headers["content-type"] == "image/png"


def test_names_that_look_like_formulas_are_drawn_as_text(
    client: TestClient, admin: dict[str, str]
) -> None:
    """The PNG labels stations (and cameras) by name: a name such as "$\\frac{$" is text,
    not a formula matplotlib cannot parse (a 500 before)."""
    now = datetime.now(UTC)
    for sid, lat, lon in (("a", 45.46, 9.15), ("b", 45.48, 9.19)):
        made = create(client, admin, id=sid, name="$\\frac{$", lat=lat, lon=lon)
        assert made.status_code == 201
        at = (now - timedelta(minutes=5)).isoformat()
        r = client.post(
            f"/air/stations/{sid}/readings", json=[{"at": at, "pm25": 10}], headers=admin
        )
        assert r.status_code == 200
    png = client.get("/air/isopleths.png")
    assert png.status_code == 200, png.text
    assert png.headers["content-type"] == "image/png"
