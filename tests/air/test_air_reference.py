"""A fixed sky camera calibrated against a reference station's PM2.5, through the API: the
regression's estimate and interval, its doubt, and re-grading the camera's history."""

from __future__ import annotations

from datetime import UTC, datetime, timedelta
from typing import Any

import cv2
import numpy as np
import pytest
from fastapi.testclient import TestClient
from sqlalchemy import Engine
from sqlalchemy.orm import Session

from app.air.core import airquality, breakpoints, public

SKY_ROWS = 50
ROI = [0, 0, 160, SKY_ROWS]
START = datetime(2026, 5, 1, 8, 0, tzinfo=UTC)


def hazy_jpeg(pm25: float, seed: int, *, sky: tuple[float, float, float] | None = None) -> bytes:
    """A street camera's view under PM2.5 ``pm25`` [µg/m³]: a sky that greys with the haze
    above a skyline of dark buildings (grey 30) whose apparent brightness follows
    Koschmieder's law, L = S·(1 − e^(−b·d)) + 30·e^(−b·d), b = PM2.5 / 15 per unit distance,
    d from 1.2 (the farthest, just under the sky) to 0.2 lower down; light ±8 % per frame."""
    rng = np.random.default_rng(seed)
    t = 1 - np.exp(-pm25 / 40)
    s = np.array(sky if sky is not None else (110.0, 150.0, 210.0))
    s = (1 - 0.4 * t) * s + 0.4 * t * np.array([200.0, 200.0, 200.0])
    s = s * rng.uniform(0.92, 1.08)
    h, w = 120, 160
    image = np.empty((h, w, 3))
    image[:SKY_ROWS] = s
    b = pm25 / 15
    for row in range(SKY_ROWS, h):
        d = max(1.2 - (row - SKY_ROWS) / 45, 0.2)
        image[row] = s
        fade = np.exp(-b * d)
        image[row, ::2] = s * (1 - fade) + 30 * fade  # buildings in every other column
    image += rng.normal(0, 2.0, image.shape)
    bgr = np.clip(image, 0, 255).astype(np.uint8)[:, :, ::-1]
    ok, buf = cv2.imencode(".jpg", np.ascontiguousarray(bgr), [cv2.IMWRITE_JPEG_QUALITY, 95])
    assert ok
    return buf.tobytes()


def post(client: TestClient, token: str, jpeg: bytes, taken: datetime) -> Any:
    r = client.post(
        "/cameras/m/frames",
        content=jpeg,
        headers={"Authorization": f"Bearer {token}", "Content-Type": "image/jpeg"},
        params={"captured_at": taken.isoformat()},
    )
    assert r.status_code == 201, r.text
    return r.json()


@pytest.fixture
def station(client: TestClient, admin: dict[str, str], clock: Any) -> dict[str, Any]:
    """Camera ``m`` and 48 frames over 8 days (6 a day, PM2.5 4–60 µg/m³) with their
    reference values, stored before any calibration (so ungraded)."""
    clock.now = START + timedelta(days=10)
    r = client.post("/cameras", json={"id": "m", "kind": "sky", "roi": ROI}, headers=admin)
    assert r.status_code == 201, r.text
    token = r.json()["token"]
    rng = np.random.default_rng(7)
    frames, pm, jpegs, days = [], [], [], []
    for day in range(8):
        base = rng.uniform(5, 45)
        for hour in range(6):
            value = float(np.clip(base * rng.uniform(0.75, 1.3), 4, 60))
            taken = START + timedelta(days=day, hours=hour)
            jpegs.append(hazy_jpeg(value, seed=100 * day + hour))
            v = post(client, token, jpegs[-1], taken)
            assert v["verdict"]["level"] is None
            frames.append(v["frame_id"])
            pm.append(round(value, 1))
            days.append(f"{taken:%Y-%m-%d}")
    return {"token": token, "frames": frames, "pm25": pm, "jpegs": jpegs, "days": days}


def calibrate(
    client: TestClient, admin: dict[str, str], station: dict[str, Any], table: str = "us_epa"
) -> Any:
    r = client.post(
        "/air/calibration",
        json={"frame_ids": station["frames"], "pm25": station["pm25"]},
        params={"method": "regression", "applies_to": "m", "breakpoints": table},
        headers=admin,
    )
    assert r.status_code == 201, r.text
    return r.json()


def test_a_verdict_carries_pm25_with_its_interval(
    client: TestClient, admin: dict[str, str], station: dict[str, Any]
) -> None:
    """Fitted in µg/m³: a new day's frames are estimated within their interval, most of
    them; the level is the breakpoints' level of the estimate when sure."""
    cal = calibrate(client, admin, station)
    assert cal["regression"]["unit"] == "pm25"
    assert cal["regression"]["breakpoints"] == "us_epa"  # the default table
    assert cal["regression"]["sigma_from"] == "days left out"
    assert cal["regression"]["groups"] == 8  # no longitude: UTC's dates
    assert cal["regression"]["n"] == 48
    inside = 0
    truths = (6.0, 12.0, 25.0, 40.0, 55.0)
    for k, truth in enumerate(truths):
        v = post(
            client, station["token"], hazy_jpeg(truth, seed=9000 + k), START + timedelta(days=9)
        )["verdict"]
        e = v["estimate"]
        assert e["unit"] == "pm25"
        assert e["low"] < e["value"] < e["high"]
        assert 0.6 * truth < e["value"] < 1.6 * truth
        inside += e["low"] <= truth <= e["high"]
        if v["uncertain"]:
            assert v["reason"].startswith("uncertain: ")
        if v["uncertain"] and "outside the calibration" in v["reason"]:
            assert v["level"] is None
        else:  # the estimate's level, within the most probable category
            own = breakpoints.level_of_pm25(e["value"])
            assert airquality.category(v["level"]) == v["category"]
            if airquality.category(own) == v["category"]:
                assert v["level"] == own
            else:  # the category's level nearest the estimate's
                assert abs(v["level"] - own) == 1
    assert inside >= 4


def test_a_regression_grades_by_its_own_table(
    client: TestClient, admin: dict[str, str], station: dict[str, Any]
) -> None:
    """Calibrated with the European bands, it keeps them: a frame it is sure of gets the
    European level of its estimate; one it doubts inside its range names the likeliest of
    the index's categories its interval reaches."""
    cal = calibrate(client, admin, station, table="eu_eaqi")
    assert cal["regression"]["breakpoints"] == "eu_eaqi"
    sure = []
    for k, truth in enumerate((6.0, 8.0, 17.0, 30.0, 45.0, 55.0)):
        v = post(
            client, station["token"], hazy_jpeg(truth, seed=9100 + k), START + timedelta(days=9)
        )["verdict"]
        value = v["estimate"]["value"]
        if v["uncertain"] and "outside the calibration" not in v["reason"]:
            low, high = v["estimate"]["low"], v["estimate"]["high"]
            reached = {
                airquality.category(breakpoints.level_of_pm25(x, "eu_eaqi"))
                for x in (low, value, high)
            }
            assert v["probability"] < 0.8
            assert v["category"] in reached, v
        elif not v["uncertain"]:
            assert v["level"] == breakpoints.level_of_pm25(value, "eu_eaqi")
            sure.append(value)
    assert len(sure) >= 3
    # and the table mattered: the EPA's would have given another level to one of them
    assert any(
        breakpoints.level_of_pm25(x, "eu_eaqi") != breakpoints.level_of_pm25(x) for x in sure
    )


TRUTHS = (6.0, 8.0, 17.0, 30.0, 45.0, 55.0, 12.0, 25.0)
"""PM2.5 of the frames a doubted level is tested on [µg/m³]."""


def test_a_doubted_frame_names_its_likeliest_category_and_counts(
    client: TestClient, admin: dict[str, str], station: dict[str, Any], clock: Any
) -> None:
    """Every frame inside the calibration names its most probable category with its
    probability, "likely" below 0.8; all of them count: the smoothed reading is the
    predictive distributions' NowCast (``public.smooth``), the hourly history and the map take
    every graded frame, and a doubted frame alone, hours later, still speaks on the screen."""
    cal = calibrate(client, admin, station, table="eu_eaqi")  # narrow categories: doubts
    reg = cal["regression"]
    shape = public.Shape(reg["dof"], "pm25", "eu_eaqi", reg["day_share"])
    clock.now = START + timedelta(days=20)
    first = clock.now - timedelta(hours=2)
    verdicts = []
    for k, truth in enumerate(TRUTHS):
        taken = first + timedelta(minutes=12 * k)
        v = post(client, station["token"], hazy_jpeg(truth, seed=9100 + k), taken)["verdict"]
        verdicts.append((taken, v))
    graded = [(t, v) for t, v in verdicts if v["level"] is not None]
    doubted = [v for _, v in graded if v["uncertain"]]
    assert doubted
    assert len(graded) >= 6
    for _, v in graded:
        e = v["estimate"]
        p = public.public(public.predictive_of(e["value"], e["low"], e["high"], shape))
        assert v["category"] == p.category
        assert v["probability"] == pytest.approx(p.probability, abs=1e-6)
        assert v["uncertain"] is (p.probability < public.SURE)
        likely = "likely " if v["uncertain"] else ""
        assert v["message"] == f"Today's Air Quality is {likely}{v['category']}"

    def read(taken: datetime, e: dict[str, float]) -> public.Read:
        p = public.predictive_of(e["value"], e["low"], e["high"], shape)
        return public.Read(taken, p.loc, p.scale)

    reads = [read(t, v["estimate"]) for t, v in graded]
    expected = [public.smooth(reads, t, shape) for t, _ in verdicts]
    readings = client.get(
        "/air/readings", params={"camera_id": "m", "since": first.isoformat(), "limit": 100}
    ).json()
    by_time = {datetime.fromisoformat(r["captured_at"]): r for r in readings}
    for (taken, _), p in zip(verdicts, expected, strict=True):
        assert p is not None
        said = public.public(p)
        r = by_time[taken]
        assert r["smoothed_estimate"] == pytest.approx(said.value, rel=1e-9)
        assert (r["smoothed_low"], r["smoothed_high"]) == pytest.approx((said.low, said.high))
        assert r["smoothed_probability"] == pytest.approx(said.probability, abs=1e-9)
        assert r["poor_probability"] == pytest.approx(said.poor, abs=1e-9)
        assert airquality.category(r["smoothed_level"]) == said.category
    hourly = client.get(
        "/air/readings",
        params={"camera_id": "m", "since": first.isoformat(), "aggregate": "hourly"},
    ).json()
    assert sum(h["n"] for h in hourly) == len(graded)  # the doubted ones count
    # on the map: the newest reading's smoothed level
    place = {"lat": 45.46, "lon": 9.19}
    assert client.patch("/cameras/m", json=place, headers=admin).status_code == 200
    shown = client.get("/air/isopleths", params={"window": 3 * 3600}).json()["cameras"]
    assert [c["camera_id"] for c in shown] == ["m"]
    assert shown[0]["level"] == pytest.approx(by_time[verdicts[-1][0]]["smoothed_level"])
    newest = by_time[verdicts[-1][0]]
    assert shown[0]["probability"] == pytest.approx(newest["smoothed_probability"])
    ends = [
        breakpoints.level_of_pm25(newest[k], "eu_eaqi") for k in ("smoothed_low", "smoothed_high")
    ]
    assert shown[0]["level_error"] == pytest.approx(max(abs(ends[0] - ends[1]) / 2.5632, 12**-0.5))
    # a doubted frame alone, hours later: the screen names its likeliest category
    k = next(k for k, (_, v) in enumerate(verdicts) if v in doubted)
    clock.now += timedelta(hours=13)  # past the 12 hours smoothing weighs
    late = post(client, station["token"], hazy_jpeg(TRUTHS[k], seed=9100 + k), clock.now)
    assert late["verdict"]["uncertain"] is True
    latest = client.get("/air/cameras/m/latest").json()
    assert latest["current"] is True
    assert latest["category"] == late["verdict"]["category"]
    assert latest["probability"] == pytest.approx(late["verdict"]["probability"], abs=1e-6)
    assert latest["uncertain"] is True
    assert latest["message"] == f"Today's Air Quality is likely {latest['category']}"
    e = latest["smoothed_estimate"]
    assert e["unit"] == "pm25"
    assert e["value"] == pytest.approx(late["verdict"]["estimate"]["value"], rel=1e-9)
    assert (e["low"], e["high"]) == pytest.approx(
        (late["verdict"]["estimate"]["low"], late["verdict"]["estimate"]["high"])
    )
    shown = client.get("/air/isopleths", params={"window": 3600}).json()["cameras"]
    assert [c["camera_id"] for c in shown] == ["m"]


def test_a_frame_unlike_the_calibration_is_uncertain_and_moves_nothing(
    client: TestClient, admin: dict[str, str], station: dict[str, Any], clock: Any
) -> None:
    """A red sky the calibration never saw: uncertain (outside the calibration), no level
    nor category; with nothing else recent, the screen says the camera cannot judge the air
    now, in public words."""
    calibrate(client, admin, station)
    clock.now = START + timedelta(days=20)
    taken = clock.now - timedelta(minutes=5)
    sure = post(client, station["token"], hazy_jpeg(6.0, seed=1), taken - timedelta(hours=4))
    before = client.get("/air/cameras/m/latest").json()
    v = post(client, station["token"], hazy_jpeg(6.0, seed=2, sky=(230, 60, 40)), taken)
    odd = v["verdict"]
    assert odd["uncertain"] is True
    assert (odd["level"], odd["category"], odd["probability"]) == (None, None, None)
    assert odd["reason"].startswith("uncertain: outside the calibration")
    assert odd["message"].startswith("Not sure")
    latest = client.get("/air/cameras/m/latest").json()
    assert latest["uncertain"] is True
    assert latest["frame_level"] is None
    assert sure["verdict"]["level"] is not None
    assert before["current"] is False
    assert latest["level"] is None
    assert latest["message"] == (
        "The camera cannot judge the air now: its sky is unlike what it was calibrated on"
    )
    assert "POST" not in latest["message"]
    assert odd["span"] is None  # outside: no categories offered
    assert latest["span"] is None
    # it changes no smoothed reading: it has none (nothing graded in the 3 hours before)
    reading = client.get("/air/readings", params={"camera_id": "m", "limit": 1}).json()[0]
    assert reading["uncertain"] is True
    assert reading["smoothed_level"] is None
    assert reading["estimate_unit"] == "pm25"


def test_regrading_makes_the_history_speak_one_calibration(
    client: TestClient, admin: dict[str, str], station: dict[str, Any], clock: Any
) -> None:
    """Frames stored before the calibration are ungraded; re-graded, each names the
    calibration and carries an estimate and smoothed level; a page at a time when limited;
    a second calibration and re-grade replace the first's ids."""
    since = START.isoformat()
    params = {"camera_id": "m", "limit": 100, "since": since}
    assert all(
        r["calibration_id"] is None for r in client.get("/air/readings", params=params).json()
    )
    first = calibrate(client, admin, station)
    page = client.post(
        "/air/cameras/m/regrade", params={"since": since, "limit": 30}, headers=admin
    )
    assert page.status_code == 200, page.text
    body = page.json()
    assert (body["regraded"], body["missing"], body["calibration_id"]) == (30, 0, first["id"])
    assert body["next_since"] is not None
    rest = client.post(
        "/air/cameras/m/regrade", params={"since": body["next_since"]}, headers=admin
    ).json()
    assert (rest["regraded"], rest["next_since"]) == (19, None)  # the page's last, again
    rows = client.get("/air/readings", params=params).json()
    assert len(rows) == 48
    assert {r["calibration_id"] for r in rows} == {first["id"]}
    assert all(r["estimate_unit"] == "pm25" for r in rows)
    graded = [r for r in rows if r["level"] is not None]
    assert graded
    assert all(r["smoothed_level"] is not None for r in graded)
    clock.advance(minutes=1)
    second = client.post(
        "/air/calibration",
        json={"frame_ids": station["frames"], "pm25": station["pm25"]},
        params={"applies_to": "m", "method": "clusters"},
        headers=admin,
    ).json()
    again = client.post("/air/cameras/m/regrade", params={"since": since}, headers=admin)
    assert again.json()["calibration_id"] == second["id"]
    rows = client.get("/air/readings", params=params).json()
    assert {r["calibration_id"] for r in rows} == {second["id"]}
    assert all(r["estimate"] is None for r in rows)  # the clusters estimate nothing


def test_without_a_method_the_better_one_on_days_left_out_grades(
    client: TestClient, admin: dict[str, str], station: dict[str, Any]
) -> None:
    """Reference values without ``method``: both methods scored on days left out, the one
    with the smaller category error kept, the choice and both scores in the calibration; the
    same scores as ``selection.choose`` gives on the same data. Levels keep the clusters."""
    r = client.post(
        "/air/calibration",
        json={"frame_ids": station["frames"], "pm25": station["pm25"]},
        params={"applies_to": "m", "breakpoints": "us_epa"},
        headers=admin,
    )
    assert r.status_code == 201, r.text
    cal = r.json()
    chosen = cal["selection"]
    assert chosen["score"] == "mean absolute category error on days left out"
    assert chosen["folds"] == 7  # 8 days, at most 7 groups of them
    assert set(chosen["scores"]) == {"regression", "clusters"}
    best = min(chosen["scores"], key=lambda m: chosen["scores"][m])
    assert cal["method"] == chosen["chosen"] == best == "regression"
    assert chosen["scores"]["regression"] < chosen["scores"]["clusters"]
    forced = calibrate(client, admin, station)
    assert forced["selection"] is None  # method given: no choice made
    levels = [breakpoints.level_of_pm25(v) for v in station["pm25"]]
    by_levels = client.post(
        "/air/calibration",
        json={"frame_ids": station["frames"], "levels": levels},
        params={"applies_to": "m"},
        headers=admin,
    ).json()
    assert (by_levels["method"], by_levels["selection"]) == ("clusters", None)


def test_references_that_cannot_calibrate_are_refused(
    client: TestClient, admin: dict[str, str], station: dict[str, Any]
) -> None:
    """All equal, or frames of fewer than three days: 422 that says so, nothing made."""
    frames = station["frames"]
    equal = client.post(
        "/air/calibration",
        json={"frame_ids": frames, "pm25": [12.0] * len(frames)},
        headers=admin,
    )
    assert equal.status_code == 422
    assert equal.json()["code"] == "references_all_equal"
    assert "all equal" in equal.json()["detail"]
    two_days = client.post(
        "/air/calibration",
        json={"frame_ids": frames[:12], "pm25": station["pm25"][:12]},
        params={"method": "regression"},
        headers=admin,
    )
    assert two_days.status_code == 422
    assert two_days.json()["code"] == "too_few_days"
    assert "cover 2 days" in two_days.json()["detail"]
    assert client.get("/air/calibrations").json() == []


def test_regrade_refuses_bad_requests(
    client: TestClient, admin: dict[str, str], station: dict[str, Any]
) -> None:
    since = {"since": START.isoformat()}
    assert client.post("/air/cameras/m/regrade", params=since).status_code == 401
    as_camera = {"Authorization": f"Bearer {station['token']}"}
    assert client.post("/air/cameras/m/regrade", params=since, headers=as_camera).status_code == 403
    missing = client.post("/air/cameras/nope/regrade", params=since, headers=admin)
    assert missing.status_code == 404
    assert missing.headers["content-type"] == "application/problem+json"
    assert client.post("/air/cameras/m/regrade", headers=admin).status_code == 422
    bad = client.post("/air/cameras/m/regrade", params={**since, "limit": 0}, headers=admin)
    assert bad.status_code == 422


def test_reference_values_are_checked(
    client: TestClient, admin: dict[str, str], station: dict[str, Any]
) -> None:
    """Negative, NaN, both levels and pm25, or a count that differs: 4xx, nothing made."""
    frames = station["frames"][:12]
    for body in (
        {"frame_ids": frames, "pm25": [-1.0] + [10.0] * 11},
        {"frame_ids": frames, "pm25": [10.0] * 11},
        {"frame_ids": frames, "pm25": [10.0] * 12, "levels": [5] * 12},
    ):
        r = client.post("/air/calibration", json=body, headers=admin)
        assert r.status_code == 422, body
    nan = client.post(
        "/air/calibration",
        content='{"frame_ids": ["a"], "pm25": [NaN]}',
        headers={**admin, "Content-Type": "application/json"},
    )
    assert nan.status_code in (400, 422)
    assert client.get("/air/calibrations").json() == []


def test_uploaded_images_left_out_a_day_at_a_time(
    client: TestClient, admin: dict[str, str], station: dict[str, Any]
) -> None:
    """The same 48 images uploaded with their days as ``groups`` are calibrated as their
    stored frames are: σ from days left out, equal to 1e-9. Without groups, σ comes from images
    left out (the frames of a day are alike, so it is smaller). A count that differs or an empty
    group: 422, nothing made."""
    stored = calibrate(client, admin, station)["regression"]

    def upload(groups: list[str] | None) -> Any:
        data: dict[str, Any] = {"pm25": [str(v) for v in station["pm25"]]}
        if groups is not None:
            data["groups"] = groups
        files = [("files", (f"{i}.jpg", j, "image/jpeg")) for i, j in enumerate(station["jpegs"])]
        params = {"method": "regression", "camera_id": "m", "applies_to": "m"}
        return client.post("/air/calibration", files=files, data=data, params=params, headers=admin)

    grouped = upload(station["days"])
    assert grouped.status_code == 201, grouped.text
    g = grouped.json()["regression"]
    assert g["sigma_from"] == "days left out"
    assert g["sigma"] == pytest.approx(stored["sigma"], abs=1e-9)
    alone = upload(None).json()["regression"]
    assert alone["sigma_from"] == "images left out"
    assert alone["sigma"] < g["sigma"]
    made = len(client.get("/air/calibrations").json())
    assert upload(station["days"][:-1]).json()["code"] == "groups_mismatch"
    assert upload([*station["days"][:-1], " "]).json()["code"] == "empty_group"
    assert len(client.get("/air/calibrations").json()) == made


def test_a_regression_stored_before_the_choice_of_table_grades_by_the_epa_s() -> None:
    """A regression kept without ``breakpoints`` was made when the EPA table was the only
    one: 30 µg/m³ is AQI 89, level 7 (by the European bands it would be 4)."""
    from app.air.core import airquality
    from app.air.models import AirCalibration
    from app.air.services import calibration

    k = len(airquality.SKY_FEATURES)
    stored = {
        "features": list(airquality.SKY_FEATURES),
        "unit": "pm25",
        "mean": [0.0] * k,
        "scale": [1.0] * k,
        "coef": [0.0] * k,
        "intercept": float(np.log1p(30.0)),
    }
    row = AirCalibration(id="before-tables", regression=stored)
    regression = calibration.as_regression(row)
    assert regression is not None
    assert regression.table == "us_epa"
    assert regression.level(np.zeros(k)) == 7 == breakpoints.level_of_pm25(30.0)
    assert breakpoints.level_of_pm25(30.0, "eu_eaqi") == 4


def earlier_features(monkeypatch: pytest.MonkeyPatch, names: tuple[str, ...]) -> None:
    """The service as a version that measured the first ``len(names)`` features, by these
    names, would be."""
    measure = airquality.sky_features
    monkeypatch.setattr(airquality, "SKY_FEATURES", names)
    monkeypatch.setattr(airquality, "sky_features", lambda *a, **k: measure(*a, **k)[: len(names)])


def calibrate_as_earlier(
    client: TestClient,
    admin: dict[str, str],
    station: dict[str, Any],
    monkeypatch: pytest.MonkeyPatch,
    names: tuple[str, ...],
) -> Any:
    """The station's frames measured again and calibrated by the earlier version; then the
    current version again."""
    earlier_features(monkeypatch, names)
    since = {"since": START.isoformat()}
    r = client.post("/air/cameras/m/regrade", params=since, headers=admin)
    assert r.status_code == 200, r.text
    cal = calibrate(client, admin, station)
    assert cal["regression"]["features"] == list(names)
    monkeypatch.undo()
    return cal


def test_a_regression_made_before_features_were_added_grades_by_its_own(
    client: TestClient,
    admin: dict[str, str],
    station: dict[str, Any],
    monkeypatch: pytest.MonkeyPatch,
    engine: Engine,
) -> None:
    """A calibration fitted when the skyline's edges were not yet measured keeps grading the
    camera's new frames, by the features it was fitted on: the same estimate as its
    regression on those features of the frame."""
    from app.air.models import AirCalibration
    from app.air.services import calibration

    n = len(airquality.SKY_FEATURES) - len(airquality.SKYLINE_BANDS)
    cal = calibrate_as_earlier(client, admin, station, monkeypatch, airquality.SKY_FEATURES[:n])
    jpeg = hazy_jpeg(25.0, seed=4242)
    v = post(client, station["token"], jpeg, START + timedelta(days=9))["verdict"]
    assert v["calibration_id"] == cal["id"]
    assert v["estimate"] is not None, v["reason"]
    with Session(engine) as session:
        earlier = calibration.as_regression(session.get_one(AirCalibration, cal["id"]))
    assert earlier is not None
    assert earlier.columns == tuple(range(n))
    # the frame's features as the camera measures them: its region, the strip below
    from app.air.kind import band_below
    from app.platform.frames.jpeg import decode_rgb

    _, image = decode_rgb(jpeg, max_pixels=10**6)
    x, y, w, h = ROI
    features = airquality.sky_features(image[y : y + h, x : x + w], band_below(image, ROI))
    assert len(features) == len(airquality.SKY_FEATURES)
    alone = airquality.Regression(**{**_fields(earlier), "columns": None})
    want = alone.estimate(features[:n])
    assert earlier.estimate(features) == want
    assert v["estimate"]["value"] == pytest.approx(want.value, rel=1e-9)
    assert v["estimate"]["low"] == pytest.approx(want.low, rel=1e-9)


def test_a_regression_on_a_feature_no_longer_measured_grades_nothing(
    client: TestClient,
    admin: dict[str, str],
    station: dict[str, Any],
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """A calibration fitted on a feature the service no longer measures (here one renamed)
    cannot grade, and the frame says why."""
    names = ("mode_r_before", *airquality.SKY_FEATURES[1:])
    calibrate_as_earlier(client, admin, station, monkeypatch, names)
    v = post(client, station["token"], hazy_jpeg(25.0, seed=4243), START + timedelta(days=9))
    verdict = v["verdict"]
    assert verdict["level"] is None
    assert verdict["estimate"] is None
    assert "earlier set of sky features" in verdict["reason"]


def _fields(regression: airquality.Regression) -> dict[str, Any]:
    return {name: getattr(regression, name) for name in regression.__dataclass_fields__}


def test_days_are_the_sun_s_days_at_the_camera(
    client: TestClient, admin: dict[str, str], clock: Any
) -> None:
    """A camera at Sydney's longitude (151.21° E, mean solar time UTC + 10 h 05 min) films 8
    mornings, 07:00–12:00 by the sun: 21:00–02:00 UTC, across UTC midnight. The regression
    leaves out its 8 days, not the 9 UTC dates they touch."""
    clock.now = START + timedelta(days=10)
    body = {"id": "syd", "kind": "sky", "roi": ROI, "lat": -33.87, "lon": 151.21}
    r = client.post("/cameras", json=body, headers=admin)
    assert r.status_code == 201, r.text
    auth = {"Authorization": f"Bearer {r.json()['token']}", "Content-Type": "image/jpeg"}
    rng = np.random.default_rng(9)
    frames, pm, dates = [], [], set()
    for day in range(8):
        base = rng.uniform(5, 45)
        for hour in range(6):
            value = float(np.clip(base * rng.uniform(0.75, 1.3), 4, 60))
            taken = START.replace(hour=21) + timedelta(days=day, hours=hour)
            dates.add(taken.date())
            r = client.post(
                "/cameras/syd/frames",
                content=hazy_jpeg(value, seed=100 * day + hour),
                headers=auth,
                params={"captured_at": taken.isoformat()},
            )
            assert r.status_code == 201, r.text
            frames.append(r.json()["frame_id"])
            pm.append(round(value, 1))
    assert len(dates) == 9
    r = client.post(
        "/air/calibration",
        json={"frame_ids": frames, "pm25": pm},
        params={"method": "regression", "applies_to": "syd"},
        headers=admin,
    )
    assert r.status_code == 201, r.text
    assert r.json()["regression"]["groups"] == 8


def test_alerts_follow_the_probability_of_poor_or_worse(
    client: TestClient, admin: dict[str, str], station: dict[str, Any], clock: Any
) -> None:
    """A regression's camera raises an alert when its smoothed probability of Poor or worse
    reaches ``public.ALERT_RAISE``, once for the episode, and clears it when that probability
    falls to ``public.ALERT_CLEAR``; each alert carries the probability."""
    calibrate(client, admin, station, table="eu_eaqi")  # Poor: above 25 µg/m³
    clock.now = START + timedelta(days=20)
    t = clock.now

    def frame(truth: float, seed: int) -> Any:
        nonlocal t
        t += timedelta(minutes=30)
        clock.now = t
        return post(client, station["token"], hazy_jpeg(truth, seed=seed), t)["verdict"]

    for k in range(4):
        frame(6.0, 7000 + k)
    assert client.get("/air/alerts").json() == []
    for k in range(6):
        frame(45.0, 7100 + k)
    raised = client.get("/air/alerts").json()
    assert [a["kind"] for a in raised] == ["raised"]
    assert raised[0]["probability"] >= public.ALERT_RAISE
    assert raised[0]["category"] in airquality.ALERT_CATEGORIES
    latest = client.get("/air/cameras/m/latest").json()
    assert latest["poor_probability"] >= public.ALERT_RAISE
    for k in range(24):  # clean air for up to 12 hours: the smoothed probability falls
        frame(6.0, 7200 + k)
        if len(client.get("/air/alerts").json()) == 2:
            break
    cleared, first = client.get("/air/alerts").json()
    assert first["id"] == raised[0]["id"]
    assert cleared["kind"] == "cleared"
    assert cleared["probability"] <= public.ALERT_CLEAR


def test_an_archive_is_imported_in_its_own_time_and_shown_as_it_was(
    client: TestClient,
    admin: dict[str, str],
    station: dict[str, Any],
    settings: Any,
    clock: Any,
) -> None:
    """With a year of history kept, an admin imports last season's frames (backfill=true):
    graded and smoothed in their own time, raising no alert; the camera's own upload of them
    is refused with the way to do it; ``/latest?at=`` and the display show the moment, and
    without ``at`` the screen says how old the reading is. A moment before the history
    kept is a 422, on the page too."""
    from app.main import create_app

    calibrate(client, admin, station, table="eu_eaqi")
    year = create_app(settings.model_copy(update={"history_retention_days": 365.0}))
    now = datetime.now(UTC)
    taken = now - timedelta(days=200)
    with TestClient(year, raise_server_exceptions=False) as archive:
        live = archive.post(
            "/cameras/m/frames",
            content=hazy_jpeg(45.0, seed=1),
            headers={"Authorization": f"Bearer {station['token']}", "Content-Type": "image/jpeg"},
            params={"captured_at": taken.isoformat()},
        )
        assert (live.status_code, live.json()["code"]) == (422, "bad_time")
        assert "backfill=true" in live.json()["detail"]
        verdicts = []
        for k in range(4):
            r = archive.post(
                "/cameras/m/frames",
                content=hazy_jpeg(35.0, seed=50 + k),
                headers={**admin, "Content-Type": "image/jpeg"},
                params={
                    "captured_at": (taken + timedelta(minutes=20 * k)).isoformat(),
                    "backfill": "true",
                },
            )
            assert r.status_code == 201, r.text
            verdicts.append(r.json()["verdict"])
        assert all(v["level"] is not None for v in verdicts), verdicts
        assert archive.get("/air/alerts").json() == []  # history, not news
        rows = archive.get("/air/readings", params={"camera_id": "m", "limit": 4}).json()
        assert all(r["smoothed_estimate"] is not None for r in rows)
        assert rows[0]["poor_probability"] >= public.ALERT_RAISE  # an alert, had it been live
        then = taken + timedelta(minutes=70)
        past = archive.get("/air/cameras/m/latest", params={"at": then.isoformat()}).json()
        assert past["current"] is True
        assert past["captured_at"] == rows[0]["captured_at"]
        assert past["category"] in airquality.ALERT_CATEGORIES
        assert past["message"].startswith("Today's Air Quality is")
        today = archive.get("/air/cameras/m/latest").json()
        assert today["current"] is False
        assert today["message"].startswith("No reading in the last 3 hours")
        assert today["message"].endswith("days ago)")
        everyone = archive.get("/air/latest", params={"at": then.isoformat()}).json()
        assert [c["category"] for c in everyone] == [past["category"]]
        page = archive.get("/display/m", params={"at": then.isoformat()})
        assert page.status_code == 200
        assert then.isoformat() in page.text  # the page's script asks for that moment
        too_old = (now - timedelta(days=400)).isoformat()
        refused = archive.get("/air/cameras/m/latest", params={"at": too_old})
        assert (refused.status_code, refused.json()["code"]) == (422, "bad_time")
        assert archive.get("/display/m", params={"at": too_old}).status_code == 422
        assert archive.get("/display/m", params={"at": "yesterday"}).status_code == 422


def test_an_episode_ends_with_the_night(
    client: TestClient, admin: dict[str, str], station: dict[str, Any], clock: Any
) -> None:
    """An alert not cleared before the camera went dark (no reading for 12 hours) ends its
    episode: the next day's Poor air raises a new alert; within the day, it does not."""
    calibrate(client, admin, station, table="eu_eaqi")
    start = START + timedelta(days=20)
    for day in range(2):
        for k in range(4):
            clock.now = start + timedelta(days=day, minutes=30 * k)
            post(client, station["token"], hazy_jpeg(45.0, seed=7300 + 10 * day + k), clock.now)
    alerts = client.get("/air/alerts").json()
    assert [a["kind"] for a in alerts] == ["raised", "raised"]
    assert alerts[0]["created_at"] > alerts[1]["created_at"]


def test_a_camera_calibrates_itself_from_a_station_near_it(
    client: TestClient, admin: dict[str, str], station: dict[str, Any]
) -> None:
    """``from=stations``: the camera's stored frames pair with the readings of a station 1 km
    away (within 30 minutes, 10 minutes off here) and calibrate as from pm25 does; the same
    regression as from the values given by hand. A station farther than max_distance_km is
    a 422 naming its distance; fewer than three days paired, one naming them."""
    located = client.patch("/cameras/m", json={"lat": 45.46, "lon": 9.19}, headers=admin)
    assert located.status_code == 200
    monitor = {"id": "st-1", "name": "Monitor", "lat": 45.469, "lon": 9.19}  # 1.0 km north
    assert client.post("/air/stations", json=monitor, headers=admin).status_code == 201
    readings = [
        {"at": (START + timedelta(days=k // 6, hours=k % 6, minutes=10)).isoformat(), "pm25": v}
        for k, v in enumerate(station["pm25"][:12])
    ]  # two days of readings first
    path = "/air/stations/st-1/readings"
    assert client.post(path, json=readings, headers=admin).status_code == 200
    params = {"from": "stations", "applies_to": "m", "breakpoints": "us_epa"}
    few = client.post("/air/calibration", params=params, headers=admin)
    assert (few.status_code, few.json()["code"]) == (422, "too_few_days")
    assert "12 frames of m pair" in few.json()["detail"]
    assert "over 2 days" in few.json()["detail"]
    readings = [
        {"at": (START + timedelta(days=k // 6, hours=k % 6, minutes=10)).isoformat(), "pm25": v}
        for k, v in enumerate(station["pm25"])
    ]
    assert client.post(path, json=readings, headers=admin).json()["stored"] == 48
    r = client.post("/air/calibration", params=params, headers=admin)
    assert r.status_code == 201, r.text
    cal = r.json()
    assert cal["n_images"] == 48
    assert cal["camera_ids"] == ["m"]
    assert cal["method"] == "regression"
    assert any("from stations st-1: 48 frames paired over 8 days" in w for w in cal["warnings"])
    by_hand = calibrate(client, admin, station)
    assert cal["regression"]["sigma"] == pytest.approx(by_hand["regression"]["sigma"])
    far = client.post("/air/calibration", params={**params, "max_distance_km": 0.5}, headers=admin)
    assert (far.status_code, far.json()["code"]) == (422, "no_station_near")
    assert "the nearest, 'st-1', is 1.0 km away" in far.json()["detail"]


def test_a_rolling_calibration_follows_the_station_and_flags_a_drift(
    client: TestClient, admin: dict[str, str], station: dict[str, Any], clock: Any
) -> None:
    """``POST /air/stations/recalibrate`` (what ``VANTAGE_AIR_RECALIBRATE_HOURS`` runs on
    its schedule): a located camera with a station 1 km away is calibrated from the pairs of
    the last 30 days; one without a place or a station near is skipped, with why. When the
    camera's later frames disagree with the station (here the station reads five times the
    haze the frames show, as if the camera had been moved), the next pass flags it
    ``recalibrate`` in ``GET /cameras/{id}`` and on the map."""
    located = client.patch("/cameras/m", json={"lat": 45.46, "lon": 9.19}, headers=admin)
    assert located.status_code == 200
    client.post(
        "/cameras", json={"id": "far", "kind": "sky", "lat": 40.0, "lon": 3.0}, headers=admin
    )
    monitor = {"id": "st-1", "lat": 45.469, "lon": 9.19}
    assert client.post("/air/stations", json=monitor, headers=admin).status_code == 201
    path = "/air/stations/st-1/readings"

    def reading(at: datetime, pm25: float) -> None:
        r = client.post(path, json=[{"at": at.isoformat(), "pm25": pm25}], headers=admin)
        assert r.status_code == 200, r.text

    for k, v in enumerate(station["pm25"]):
        reading(START + timedelta(days=k // 6, hours=k % 6), v)
    first = client.post("/air/stations/recalibrate", headers=admin)
    assert first.status_code == 200, first.text
    done = first.json()
    assert done["recalibrated"] == ["m"]
    assert "no station within max_distance_km=10" in done["skipped"]["far"]
    assert done["drifting"] == []
    assert client.get("/air/calibration", params={"camera_id": "m"}).json()["n_images"] == 48
    # a week later: eight frames a day over two days, the station reading five times more
    for day in range(2):
        for hour in range(8):
            taken = START + timedelta(days=8 + day, hours=hour)
            clock.now = taken + timedelta(minutes=1)
            truth = 8.0 + 2 * hour
            post(client, station["token"], hazy_jpeg(truth, seed=8000 + 10 * day + hour), taken)
            reading(taken, 5 * truth)
    moved = client.post("/air/stations/recalibrate", headers=admin).json()
    assert moved["drifting"] == ["m"]
    camera = client.get("/cameras/m", headers=admin).json()
    assert camera["attention"][0].startswith("recalibrate: its readings' 80 % ranges missed")
    place = client.get("/air/isopleths", params={"window": 86400}).json()["cameras"]
    assert [c["recalibrate"] for c in place if c["camera_id"] == "m"] == [True]
    assert client.get("/cameras/far", headers=admin).json()["attention"] == []


def test_a_camera_with_more_pairs_than_a_calibration_takes_is_sampled_evenly(
    client: TestClient,
    admin: dict[str, str],
    station: dict[str, Any],
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """More pairs than ``stations.MAX_PAIRS`` (a camera posting every minute pairs 43,000
    frames a month, past what a calibration from stored frames takes: a 500 before): evenly
    spaced ones over its days calibrate it."""
    from app.air.services import stations

    monkeypatch.setattr(stations, "MAX_PAIRS", 20)
    located = client.patch("/cameras/m", json={"lat": 45.46, "lon": 9.19}, headers=admin)
    assert located.status_code == 200
    monitor = {"id": "st-1", "lat": 45.469, "lon": 9.19}
    assert client.post("/air/stations", json=monitor, headers=admin).status_code == 201
    readings = [
        {"at": (START + timedelta(days=k // 6, hours=k % 6)).isoformat(), "pm25": v}
        for k, v in enumerate(station["pm25"])
    ]
    r = client.post("/air/stations/st-1/readings", json=readings, headers=admin)
    assert r.status_code == 200
    params = {"from": "stations", "applies_to": "m", "method": "regression"}
    cal = client.post("/air/calibration", params=params, headers=admin)
    assert cal.status_code == 201, cal.text
    assert cal.json()["n_images"] == 20
    assert cal.json()["regression"]["groups"] == 8  # still every day
    assert stations.evenly(5, 3) == [0, 2, 4]
    assert stations.evenly(3, 5) == [0, 1, 2]
