"""The pages in a real browser: Debian's Chromium, headless, driven by Playwright against the
service served by uvicorn on 127.0.0.1. Screenshots go to ``build/screenshots`` for a person
to look at."""

from __future__ import annotations

import shutil
from collections.abc import Iterator
from datetime import UTC, date, datetime, timedelta
from pathlib import Path
from typing import Any

import cv2
import httpx2 as httpx
import numpy as np
import pytest

from tests.factories.air import calibrate, sky_jpeg
from tests.factories.cells import CAMERA_IN_BASE, board_poses, flange_of, pose_json, render
from tests.factories.energy import plant
from tests.factories.solar import CLEAN_RGB, DUST, clean_set, panel_jpeg

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
pytestmark = [
    pytest.mark.skipif(CHROMIUM is None, reason="needs Chromium (apt install chromium)"),
    pytest.mark.slow,  # a real browser driving the pages end to end
]
SHOTS = Path(__file__).resolve().parents[2] / "build" / "screenshots"
TILE = cv2.imencode(".png", np.full((256, 256, 3), 235, np.uint8))[1].tobytes()
"""What the base map's tile server answers in these tests (they have no network)."""


@pytest.fixture
def browser() -> Iterator[Any]:
    from playwright.sync_api import sync_playwright

    with sync_playwright() as p:
        b = p.chromium.launch(executable_path=CHROMIUM, args=["--no-sandbox"])
        yield b
        b.close()


class Page:
    """A page of the browser that records console errors and answers the tile server."""

    def __init__(self, browser: Any, width: int = 1280, height: int = 800) -> None:
        # the pages' own policy forbids eval, which Playwright's wait_for_function needs; the
        # pages under their policy are tested in test_hostile_pages
        self.page = browser.new_page(viewport={"width": width, "height": height}, bypass_csp=True)
        self.errors: list[str] = []
        self.page.on("console", lambda m: self.errors.append(m.text) if m.type == "error" else None)
        self.page.on("pageerror", lambda e: self.errors.append(str(e)))
        self.page.route(
            "https://tile.openstreetmap.org/**",
            lambda route: route.fulfill(status=200, body=TILE, content_type="image/png"),
        )

    def sign_in(self, url: str, headers: dict[str, str]) -> None:
        """Open a board and sign in with the token of ``headers`` through its form."""
        self.page.goto(url)
        self.page.fill("#token", headers["Authorization"].removeprefix("Bearer "))
        self.page.click("#signin button")

    def shot(self, name: str) -> None:
        SHOTS.mkdir(parents=True, exist_ok=True)
        self.page.screenshot(path=SHOTS / f"{name}.png")


def sky_camera(
    http: httpx.Client, admin: dict[str, str], camera_id: str, name: str, lat: float, lon: float
) -> str:
    body = {"id": camera_id, "kind": "sky", "name": name, "lat": lat, "lon": lon}
    r = http.post("/cameras", json={**body, "roi": [0, 0, 160, 55]}, headers=admin)
    assert r.status_code == 201, r.text
    return str(r.json()["token"])


def reading(
    http: httpx.Client, token: str, camera_id: str, level: int, taken: datetime | None = None
) -> None:
    params = {"captured_at": taken.isoformat()} if taken else {}
    r = http.post(
        f"/cameras/{camera_id}/frames",
        content=sky_jpeg(level, seed=level),
        headers={"Authorization": f"Bearer {token}", "Content-Type": "image/jpeg"},
        params=params,
    )
    assert r.status_code == 201, r.text


@pytest.fixture
def city(live: str, admin: dict[str, str]) -> dict[str, str]:
    """Three sky cameras in Milan with a reading each (levels 3, 7, 10), a calibration."""
    with httpx.Client(base_url=live, timeout=30) as http:
        assert calibrate(http, admin, None).status_code == 201  # type: ignore[arg-type]
        tokens = {}
        for cid, name, lat, lon, level in (
            ("duomo", "Duomo", 45.464, 9.190, 3),
            ("brera", "Brera", 45.472, 9.188, 7),
            ("navigli", "Navigli", 45.450, 9.175, 10),
        ):
            tokens[cid] = sky_camera(http, admin, cid, name, lat, lon)
            reading(http, tokens[cid], cid, level)
    return tokens


def test_the_map_labels_every_camera_and_draws_the_bands(
    browser: Any, live: str, city: dict[str, str]
) -> None:
    p = Page(browser)
    p.page.goto(f"{live}/map")
    labels = p.page.locator(".cam-label")
    labels.first.wait_for()
    texts = sorted(labels.all_inner_texts())
    assert texts == ["Brera 7", "Duomo 3", "Navigli 10"]
    bands = p.page.locator("path.leaflet-interactive")
    assert bands.count() >= 3  # the bands and the three markers
    fills = {bands.nth(i).get_attribute("fill") for i in range(bands.count())}
    assert {"#fdae61", "#abd9e9", "#2c7bb6"} <= fills  # Poor, Good, Very Good
    legend = p.page.locator("#legend").inner_text()
    assert "Very Good 9–10" in legend
    assert "no data" in legend
    assert "3 cameras" in p.page.locator("#status").inner_text()
    # once the cameras are in view, the bands are drawn over the whole view
    p.page.wait_for_function("Number(document.body.dataset.maps) >= 2")
    assert sorted(labels.all_inner_texts()) == texts
    p.shot("map")
    # a camera's popup: its category, time, its sky and the chart of its last 24 hours
    p.page.locator(".cam", has_text="Brera 7").locator(".dot").click()
    popup = p.page.locator(".popup")
    popup.wait_for()
    assert "Good, level 7" in popup.inner_text()
    p.page.wait_for_function("document.querySelector('.popup img').naturalWidth === 160")
    p.page.wait_for_function(
        "Chart.getChart(document.querySelector('.popup canvas')) !== undefined"
    )
    p.shot("map-popup")
    p.page.keyboard.press("Escape")
    p.page.locator("#uncertainty").check()
    p.page.wait_for_function("document.querySelector('#legend').innerText.includes(' m')")
    p.shot("map-uncertainty")
    p.page.locator("#uncertainty").uncheck()
    p.page.locator(".leaflet-marker-pane, .leaflet-overlay-pane").first.wait_for(state="attached")
    assert p.errors == []


def test_the_map_draws_the_stations_by_name_and_value(
    browser: Any, live: str, city: dict[str, str], admin: dict[str, str]
) -> None:
    """A reference station is a square marker labelled with its name and measured PM2.5, as
    text: a name that is markup is shown, never run."""
    name = "<img src=x onerror=alert(1)>"
    with httpx.Client(base_url=live, timeout=30) as http:
        station = {"id": "vm", "name": name, "lat": 45.468, "lon": 9.18}
        assert http.post("/air/stations", json=station, headers=admin).status_code == 201
        at = (datetime.now(UTC) - timedelta(minutes=10)).isoformat()
        r = http.post("/air/stations/vm/readings", json=[{"at": at, "pm25": 18.0}], headers=admin)
        assert r.status_code == 200, r.text
    p = Page(browser)
    p.page.goto(f"{live}/map")
    label = p.page.locator(".station .cam-label")
    label.wait_for()
    assert label.inner_text() == f"{name}: 18 µg/m³ (station)"
    assert p.page.locator(".station img").count() == 0
    assert "1 stations" in p.page.locator("#status").inner_text()
    p.shot("map-station")
    assert p.errors == []


def test_the_map_draws_without_a_network(browser: Any, live: str, city: dict[str, str]) -> None:
    """No tile server: the bands, markers and labels draw all the same."""
    page = browser.new_page()
    page.route("https://tile.openstreetmap.org/**", lambda route: route.abort())
    page.goto(f"{live}/map")
    page.locator(".cam-label").first.wait_for()
    assert page.locator(".cam-label").count() == 3
    assert page.locator("path.leaflet-interactive").count() >= 3


def test_the_display_reads_from_across_the_street(
    browser: Any, live: str, city: dict[str, str], admin: dict[str, str]
) -> None:
    """Today's message and the level in the category's colour, no scroll bars at 1920×1080 or
    1280×720; "No current reading" for a camera whose reading is 5 hours old; an unknown
    camera is a page saying so (404); a past moment (``?at=``) before the history kept is a page
    saying why (422)."""
    for width, height in ((1920, 1080), (1280, 720)):
        p = Page(browser, width, height)
        p.page.goto(f"{live}/display/brera")
        p.page.wait_for_function("document.body.dataset.state === 'current'")
        assert p.page.locator("#headline").inner_text() == "Today's Air Quality is Good"
        assert p.page.locator("#level").inner_text() == "7"
        assert p.page.locator("#name").inner_text() == "Brera"
        assert p.page.locator("#scale li.on").inner_text() == "7"  # today's on the 1–10 scale
        overflow = p.page.evaluate(
            "[document.documentElement.scrollWidth > innerWidth,"
            " document.documentElement.scrollHeight > innerHeight]"
        )
        assert overflow == [False, False]
        p.shot(f"display-{width}x{height}")
        assert p.errors == []
    with httpx.Client(base_url=live, timeout=30) as http:
        token = sky_camera(http, admin, "old", "Old Town", 45.46, 9.2)
        reading(http, token, "old", 8, datetime.now(UTC) - timedelta(hours=5))
    p = Page(browser)
    p.page.goto(f"{live}/display/old")
    p.page.wait_for_function("document.body.dataset.state === 'none'")
    assert p.page.locator("#headline").inner_text() == (
        "No reading in the last 3 hours (the latest was taken 5 h ago)"
    )
    assert p.page.locator("#scale li.on").count() == 0
    p.shot("display-stale")
    past = p.page.goto(f"{live}/display/old?at=2001-01-01T00:00:00Z")
    assert past is not None
    assert past.status == 422
    response = p.page.goto(f"{live}/display/nowhere")
    assert response is not None
    assert response.status == 404
    assert "There is no sky camera 'nowhere'" in p.page.locator("#missing").inner_text()


def test_the_farm_board_shows_nothing_until_signed_in(
    browser: Any, live: str, admin: dict[str, str], clock: Any
) -> None:
    """Three panels; p0 dusty with a cleaning task its robot has claimed. Signed out: no data;
    a wrong token: the form with its error; signed in: the panels with their states and the
    task with its robot and lease; a kiosk's #code= link signs in once as a viewer."""
    with httpx.Client(base_url=live, timeout=30) as http:
        for k in range(3):
            r = http.post("/panels", json={"id": f"p{k}", "name": f"Row A {k}"}, headers=admin)
            assert r.status_code == 201, r.text
        camera = http.post(
            "/cameras", json={"id": "c0", "kind": "panel", "panel_id": "p0"}, headers=admin
        ).json()["token"]
        robot = http.post("/robots", json={"id": "r1"}, headers=admin).json()["token"]
        files = [("files", (f"{i}.jpg", f, "image/jpeg")) for i, f in enumerate(clean_set(10))]
        assert http.post("/panels/p0/baseline", files=files, headers=admin).status_code == 201
        for k in range(3):  # dust, frame after frame, until the debounce opens a task
            clock.advance(minutes=10)
            r = http.post(
                "/cameras/c0/frames",
                content=panel_jpeg(CLEAN_RGB + DUST, seed=k),
                headers={"Authorization": f"Bearer {camera}", "Content-Type": "image/jpeg"},
            )
            assert r.status_code == 201, r.text
        claimed = http.post("/cleaning/claim", headers={"Authorization": f"Bearer {robot}"})
        assert claimed.status_code == 200, claimed.text
    p = Page(browser)
    p.page.goto(f"{live}/farm")
    p.page.locator("#signin").wait_for()
    assert p.page.locator("#board").is_hidden()
    assert p.page.locator(".tile").count() == 0
    p.page.fill("#token", "not-the-token")
    p.page.click("#signin button")
    p.page.wait_for_function("document.querySelector('#signin-error').innerText.length > 0")
    assert "not accepted" in p.page.locator("#signin-error").inner_text()
    assert p.page.locator("#board").is_hidden()
    assert p.page.locator(".tile").count() == 0
    p.page.fill("#token", admin["Authorization"].removeprefix("Bearer "))
    p.page.click("#signin button")
    p.page.locator(".tile").first.wait_for()
    assert sorted(p.page.locator(".tile").all_inner_texts()) == [
        "Row A 0 — being cleaned",
        "Row A 1 — no baseline",
        "Row A 2 — no baseline",
    ]
    [task] = p.page.locator("#tasks tbody tr").all_inner_texts()
    assert task.split("\t")[:3] == ["p0", "claimed", "r1"]
    assert p.page.locator("#fleet").inner_text().startswith("No fleet model")
    p.page.locator(".tile.cleaning").click()
    p.page.wait_for_function("document.querySelector('#thumb').naturalWidth > 0")
    p.shot("farm")
    # a kiosk's link carries a one-time code, never a token: it signs in as a viewer, leaves
    # the address bar, and is spent
    with httpx.Client(base_url=live, timeout=30) as http:
        link = http.post("/signin-codes", json={"name": "lobby"}, headers=admin).json()["farm"]
        assert "code=" in link
        assert admin["Authorization"].removeprefix("Bearer ") not in link
    kiosk = Page(browser)
    kiosk.page.goto(f"{live}{link}")
    kiosk.page.locator(".tile").first.wait_for()
    assert "#code" not in kiosk.page.url
    assert kiosk.page.evaluate("() => sessionStorage.getItem('vantage-token')").startswith("vv_")
    again = Page(browser)
    again.page.goto(f"{live}{link}")
    again.page.wait_for_function("document.querySelector('#signin-error').innerText.length > 0")
    assert "used already or has expired" in again.page.locator("#signin-error").inner_text()
    assert again.page.locator(".tile").count() == 0
    # logged: the wrong token's answer, and the fleet model's 404 before there was one
    assert [e for e in p.errors if "401" not in e and "404" not in e] == []
    assert [e for e in kiosk.errors if "404" not in e] == []


def test_the_farm_board_says_how_the_fleet_model_did(
    browser: Any, live: str, admin: dict[str, str]
) -> None:
    """Eight panels, each photographed clean and half covered in sand, trained with their
    panels as groups: the board names the photos, the panels and the accuracy on panels the
    model never saw; trained again without groups, it says the figure may flatter."""
    rng = np.random.default_rng(6)
    files, labels, groups = [], [], []
    for i in range(8):
        c = CLEAN_RGB + rng.normal(0, 6, 3)
        for name, rgb in (("clean", c), ("dust", 0.5 * c + 0.5 * np.array([190, 180, 160]))):
            files.append(("files", (f"{name}{i}.jpg", panel_jpeg(rgb, seed=i), "image/jpeg")))
            labels.append(name)
            groups.append(f"row-{i}")
    with httpx.Client(base_url=live, timeout=60) as http:
        data = {"labels": labels, "groups": groups}
        assert http.post("/fleet/model", files=files, data=data, headers=admin).status_code == 201
        p = Page(browser)
        p.sign_in(f"{live}/farm", admin)
        p.page.wait_for_function("document.querySelector('#fleet').innerText.length > 0")
        assert p.page.locator("#detail").is_hidden()  # no panel chosen: no empty detail
        text = p.page.locator("#fleet").inner_text()
        assert "8 clean, 8 needing cleaning photos of 8 panels" in text, text
        assert "balanced accuracy 1.00 (95 % interval 1.00–1.00) on panels it never saw" in text, (
            text
        )
        assert "It answers 100 % of frames, those at 1.00" in text, text
        data = {"labels": labels}
        assert http.post("/fleet/model", files=files, data=data, headers=admin).status_code == 201
        p.page.reload()
        p.page.wait_for_function("document.querySelector('#fleet').innerText.includes('groups')")
        assert "train with groups" in p.page.locator("#fleet").inner_text()
        p.shot("farm-fleet")
        assert p.errors == []


def test_the_farm_board_shows_the_camera_and_the_output_side_by_side(
    browser: Any, live: str, admin: dict[str, str], clock: Any
) -> None:
    """A dusty panel whose output lost 0.3 % a day for 89 days since a cleaning, and whose
    camera says dirty: the detail gives the ratio with its range, the loss, whether cleaning
    pays, that the two agree, and charts the ratio's band, the cleaning and the camera."""
    p0 = plant(0, start=clock.now.date() - timedelta(days=149))
    days = [
        {"date": date.fromordinal(int(d)).isoformat(), "kwh": float(k), "expected_kwh": float(e)}
        for d, k, e in zip(p0.days, p0.kwh, p0.expected, strict=True)
    ]
    with httpx.Client(base_url=live, timeout=30) as http:
        assert (
            http.post("/panels", json={"id": "p0", "name": "Row B 0"}, headers=admin).status_code
            == 201
        )
        camera = http.post(
            "/cameras", json={"id": "c0", "kind": "panel", "panel_id": "p0"}, headers=admin
        ).json()["token"]
        files = [("files", (f"{i}.jpg", f, "image/jpeg")) for i, f in enumerate(clean_set(10))]
        assert http.post("/panels/p0/baseline", files=files, headers=admin).status_code == 201
        clock.advance(minutes=10)
        r = http.post(
            "/cameras/c0/frames",
            content=panel_jpeg(CLEAN_RGB + DUST, seed=1),
            headers={"Authorization": f"Bearer {camera}", "Content-Type": "image/jpeg"},
        )
        assert r.status_code == 201, r.text
        assert http.post("/panels/p0/energy", json=days, headers=admin).status_code == 200
        prices = {"energy_price_per_kwh": 0.25, "cleaning_cost": 2.0, "currency": "EUR"}
        assert http.put("/solar/economics", json=prices, headers=admin).status_code == 200
    p = Page(browser)
    p.sign_in(f"{live}/farm", admin)
    p.page.locator(".tile").first.click()
    p.page.wait_for_function("document.querySelector('#output').innerText.length > 0")
    text = p.page.locator("#output").inner_text()
    assert "of clean (95 % range" in text, text
    assert "kWh since the cleaning of" in text, text
    assert "Cleaning pays now: the energy lost since" in text, text
    assert "The camera says dirty; the output agrees." in text, text
    p.page.wait_for_function("Chart.getChart(document.querySelector('#trend')) !== undefined")
    drawn = p.page.evaluate(
        "() => Chart.getChart(document.querySelector('#trend')).data.datasets"
        ".map((d) => [d.label, d.data.filter((v) => v != null).length])"
    )
    counts = dict(drawn)
    assert counts["soiling ratio (fit)"] >= 89
    assert counts["cleaning"] == 1
    assert counts["share of frames judged dirty (camera)"] == 1
    p.shot("farm-output")
    assert [e for e in p.errors if "404" not in e] == []  # no fleet model: its 404 is logged


def test_the_cells_page_outlines_a_part(browser: Any, live: str, admin: dict[str, str]) -> None:
    image = np.full((240, 320, 3), 225, np.uint8)
    box = np.array([[80, 60], [250, 80], [230, 190], [70, 170]], np.int32)
    cv2.fillPoly(image, [box], (40, 40, 40))
    ok, png = cv2.imencode(".png", cv2.GaussianBlur(image, (0, 0), 1.0))
    assert ok
    p = Page(browser)
    p.sign_in(f"{live}/cells", admin)
    p.page.locator("#board").wait_for()
    assert "No calibrations yet" in p.page.locator("#calibrations").inner_text()
    p.page.set_input_files(
        "#photo", files=[{"name": "part.png", "mimeType": "image/png", "buffer": png.tobytes()}]
    )
    p.page.click("#outline-form button")
    p.page.locator("#corners tbody tr").nth(3).wait_for()
    assert p.page.locator("#corners tbody tr").count() == 4
    p.page.wait_for_function("document.querySelector('#outlined').naturalWidth > 0")
    p.shot("cells-outline")
    assert p.errors == []


def test_the_cells_page_names_calibrations_and_draws_rigs(
    browser: Any, live: str, admin: dict[str, str]
) -> None:
    """A named camera calibration charted per view (fitted and held out, in px, at least
    300 px wide), a hand-eye calibration of it, and a rig carrying it drawn with its two
    cameras and the robot's base."""
    cs = board_poses(8, seed=21)
    files = render(cs, size=(640, 480))
    views = [("files", (f"v{i}.png", f, "image/png")) for i, f in enumerate(files)]
    board = {"pattern_cols": "9", "pattern_rows": "6", "square_size": "0.03"}
    with httpx.Client(base_url=live, timeout=60) as http:
        r = http.post(
            "/calibrations", files=views, data={**board, "name": "Cell 2, left"}, headers=admin
        )
        assert r.status_code == 201, r.text
        cam = r.json()
        poses = [pose_json(flange_of(c)) for c in cs]
        form = {**board, "calibration_id": cam["id"], "setup": "eye_to_hand", "poses": poses}
        he = http.post("/calibrations/hand-eye", files=views, data=form, headers=admin)
        assert he.status_code == 201, he.text
        cameras = [
            {"K": cam["K"], "dist": cam["dist"], "R": np.eye(3).tolist(), "t": [0.0, 0.0, 0.0]},
            {"K": cam["K"], "dist": cam["dist"], "R": np.eye(3).tolist(), "t": [-0.1, 0.0, 0.0]},
        ]
        rig = {
            "id": "cell2",
            "kind": "calibrated",
            "cameras": cameras,
            "robot": {"hand_eye_id": he.json()["id"]},
        }
        assert http.post("/rigs", json=rig, headers=admin).status_code == 201
    assert (
        np.linalg.norm(np.array(he.json()["camera_to_base"])[:3, 3] - CAMERA_IN_BASE[:3, 3]) < 0.01
    )
    p = Page(browser)
    p.sign_in(f"{live}/cells", admin)
    p.page.locator(".calibration-title").nth(1).wait_for()
    titles = p.page.locator(".calibration-title").all_inner_texts()
    assert any(t.startswith("Cell 2, left · camera · RMS") and "held out" in t for t in titles)
    assert any("hand-eye" in t and "m in the base" in t for t in titles), titles
    chart = p.page.locator(f".calibration[data-id='{cam['id']}'] canvas")
    assert chart.bounding_box()["width"] >= 300
    where = f".calibration[data-id='{cam['id']}'] canvas"
    p.page.wait_for_function(f'Chart.getChart(document.querySelector("{where}")) !== undefined')
    shown = p.page.evaluate(
        f'() => {{ const c = Chart.getChart(document.querySelector("{where}"));'
        " return [c.data.datasets.map((d) => d.label), c.options.scales.y.title.text]; }"
    )
    labels, axis = shown
    assert labels[:2] == ["fitted [px]", "held out [px]"]
    assert labels[2].startswith("held-out RMS")
    assert axis == "reprojection error [px]"
    rig_canvas = p.page.locator(".rig[data-id='cell2'] canvas")
    assert rig_canvas.get_attribute("data-cameras") == "2"
    assert rig_canvas.get_attribute("data-robot") == "yes"
    assert "in the robot's base" in p.page.locator(".rig[data-id='cell2'] figcaption").inner_text()
    p.shot("cells-calibrations")
    assert p.errors == []


def test_a_camera_without_a_reading_stays_on_the_map(
    browser: Any, live: str, admin: dict[str, str], city: dict[str, str]
) -> None:
    with httpx.Client(base_url=live, timeout=30) as http:
        sky_camera(http, admin, "lambrate", "Lambrate", 45.484, 9.238)  # installed, no frame yet
    p = Page(browser)
    p.page.goto(f"{live}/map")
    p.page.locator(".cam.silent .cam-label").wait_for()
    p.page.wait_for_function("Number(document.body.dataset.quiet) >= 2")  # the view fitted
    assert p.page.locator(".cam.silent .cam-label").inner_text() == "Lambrate –"
    assert sorted(p.page.locator(".cam:not(.silent) .cam-label").all_inner_texts()) == [
        "Brera 7",
        "Duomo 3",
        "Navigli 10",
    ]
    assert "1 more without a reading" in p.page.locator("#status").inner_text()
    p.page.locator(".cam.silent .dot").click()
    popup = p.page.locator(".popup")
    popup.wait_for()
    assert "No reading on this map" in popup.inner_text()
    assert "no frames yet" in popup.inner_text()
    p.shot("map-silent-camera")
    assert p.errors == []


def test_a_city_with_no_reading_yet_is_shown_where_its_cameras_are(
    browser: Any, live: str, admin: dict[str, str]
) -> None:
    with httpx.Client(base_url=live, timeout=30) as http:  # in Turin, far from the default view
        sky_camera(http, admin, "mole", "Mole", 45.069, 7.693)
        sky_camera(http, admin, "lingotto", "Lingotto", 45.032, 7.667)
    p = Page(browser)
    p.page.goto(f"{live}/map")
    p.page.wait_for_function("Number(document.body.dataset.quiet) >= 2")  # the view fitted
    assert p.page.locator(".cam.silent").count() == 2
    box = p.page.locator("#map").bounding_box()
    for cam in p.page.locator(".cam.silent .dot").all():
        dot = cam.bounding_box()
        assert box["x"] < dot["x"] < box["x"] + box["width"]
        assert box["y"] < dot["y"] < box["y"] + box["height"]
    assert "Nothing drawn" in p.page.locator("#status").inner_text()
    assert p.errors == []
