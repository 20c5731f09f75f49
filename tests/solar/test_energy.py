"""A panel's output through the API: energy in (JSON, CSV, modelled by pvlib), the soiling
ratio and whether cleaning pays, the farm's prices, the trigger that weighs them, and the
history that shows the camera and the output side by side."""

from __future__ import annotations

import json
from datetime import date, timedelta
from typing import Any

import numpy as np
import pytest
from fastapi.testclient import TestClient

from tests.factories import bearer
from tests.factories.energy import plant
from tests.factories.solar import CLEAN_RGB, DUST, clean_set, post_frame, train

TODAY = date(2026, 6, 1)  # the test clock's day


def days_of(p: Any, *, upto: int | None = None) -> list[dict[str, Any]]:
    n = p.days.size if upto is None else upto
    return [
        {
            "date": date.fromordinal(int(p.days[i])).isoformat(),
            "kwh": round(float(p.kwh[i]), 5),
            "expected_kwh": round(float(p.expected[i]), 5),
        }
        for i in range(n)
    ]


def post_energy(client: TestClient, admin: dict[str, str], body: Any, panel: str = "p1") -> Any:
    return client.post(f"/panels/{panel}/energy", json=body, headers=admin)


def stored(client: TestClient, admin: dict[str, str]) -> list[Any]:
    r = client.get("/panels/p1/energy", headers=admin)
    assert r.status_code == 200, r.text
    return list(r.json())


class TestEnergyIn:
    def test_json_days_are_stored_and_a_day_sent_again_replaces_it(
        self, client: TestClient, admin: dict[str, str], farm: dict[str, Any]
    ) -> None:
        r = post_energy(
            client,
            admin,
            [
                {"date": "2026-05-01", "kwh": 1.5, "expected_kwh": 2.0},
                {"date": "2026-05-02", "kwh": 1.4, "expected_kwh": 1.9, "rain_mm": 3},
            ],
        )
        assert r.status_code == 200, r.text
        assert r.json() == {
            "panel_id": "p1",
            "stored": 2,
            "modelled": 0,
            "first": "2026-05-01",
            "last": "2026-05-02",
        }
        again = post_energy(client, admin, [{"date": "2026-05-01", "kwh": 1.7, "expected_kwh": 2}])
        assert again.json()["stored"] == 1
        days = stored(client, admin)
        assert [(d["day"], d["kwh"], d["expected_from"]) for d in days] == [
            ("2026-05-01", 1.7, "given"),
            ("2026-05-02", 1.4, "given"),
        ]
        assert days[1]["rain_mm"] == 3

    def test_csv_with_other_columns_and_empty_cells(
        self, client: TestClient, admin: dict[str, str], farm: dict[str, Any]
    ) -> None:
        body = (
            "date,kwh,expected_kwh,rain_mm,inverter\n"
            "2026-05-01,1.5,2.0,,A\n"
            "2026-05-02,1.4,1.9,7,A\n"
        )
        r = client.post(
            "/panels/p1/energy",
            content=body.encode(),
            headers={**admin, "Content-Type": "text/csv"},
        )
        assert r.status_code == 200, r.text
        assert [d["rain_mm"] for d in stored(client, admin)] == [None, 7.0]

    def test_pvlib_models_the_expected_energy_from_insolation(
        self, client: TestClient, admin: dict[str, str], farm: dict[str, Any]
    ) -> None:
        rating = {"kwp": 0.4, "tilt": 0, "azimuth": 180, "lat": 45.0, "lon": 9.0}
        assert client.patch("/panels/p1", json=rating, headers=admin).status_code == 200
        r = post_energy(
            client,
            admin,
            [
                {"date": "2026-05-01", "kwh": 1.5, "poa_kwh_m2": 5.0},
                {"date": "2026-05-02", "kwh": 1.5, "ghi_kwh_m2": 5.0},
            ],
        )
        assert r.status_code == 200, r.text
        assert r.json()["modelled"] == 2
        days = stored(client, admin)
        # PVWatts at 25 °C: 0.4 kW × 5 kWh/m² ÷ 1 kW/m²; a flat panel's plane is the horizontal
        assert [d["expected_from"] for d in days] == ["poa", "ghi"]
        assert days[0]["expected_kwh"] == pytest.approx(2.0, rel=1e-9)
        assert days[1]["expected_kwh"] == pytest.approx(2.0, rel=1e-6)

    def test_an_unknown_panel_is_404_and_a_viewer_cannot_post(
        self, client: TestClient, admin: dict[str, str], farm: dict[str, Any]
    ) -> None:
        day = [{"date": "2026-05-01", "kwh": 1, "expected_kwh": 1}]
        assert post_energy(client, admin, day, panel="nope").status_code == 404
        viewer = client.post("/viewers", json={"name": "board"}, headers=admin).json()["token"]
        assert post_energy(client, bearer(viewer), day).status_code == 403
        assert client.get("/panels/p1/soiling", headers=bearer(viewer)).status_code == 200


class TestBadInput:
    """Each refused with a 422 naming the field; nothing stored from a refused request."""

    GOOD = {"date": "2026-05-01", "kwh": 1.0, "expected_kwh": 1.2}

    @pytest.mark.parametrize(
        ("day", "named"),
        [
            ({"date": "2026-02-30", "kwh": 1.0, "expected_kwh": 1.2}, "days[1].date"),
            ({"date": "2026-13-01", "kwh": 1.0, "expected_kwh": 1.2}, "days[1].date"),
            ({"date": "2027-01-01", "kwh": 1.0, "expected_kwh": 1.2}, "days[1].date"),
            ({"date": "1899-01-01", "kwh": 1.0, "expected_kwh": 1.2}, "days[1].date"),
            ({"date": "2026-05-02", "kwh": -0.1, "expected_kwh": 1.2}, "days[1].kwh"),
            ({"date": "2026-05-02", "kwh": 1.0, "expected_kwh": -1}, "days[1].expected_kwh"),
            ({"date": "2026-05-02", "kwh": 1.0, "expected_kwh": 0}, "expected_kwh"),
            ({"date": "2026-05-02", "kwh": 1.0}, "days[1].expected_kwh"),
            ({"date": "2026-05-02", "kwh": 1.0, "poa_kwh_m2": 5}, "days[1].poa_kwh_m2"),
            ({"date": "2026-05-02", "kwh": 1.0, "ghi_kwh_m2": 5}, "days[1].ghi_kwh_m2"),
            ({"date": "2026-05-02", "kwh": 1.0, "expected_kwh": 1, "volts": 3}, "days[1].volts"),
        ],
    )
    def test_refused_naming_the_field(
        self,
        client: TestClient,
        admin: dict[str, str],
        farm: dict[str, Any],
        day: dict[str, Any],
        named: str,
    ) -> None:
        r = post_energy(client, admin, [self.GOOD, day])
        assert r.status_code == 422, r.text
        assert r.headers["content-type"].startswith("application/problem+json")
        assert named in r.json()["detail"]
        assert stored(client, admin) == []

    def test_nan_and_infinity_are_refused(
        self, client: TestClient, admin: dict[str, str], farm: dict[str, Any]
    ) -> None:
        for bad in ("NaN", "Infinity"):
            second = f'{{"date": "2026-05-02", "kwh": {bad}, "expected_kwh": 1}}'
            body = f"[{json.dumps(self.GOOD)}, {second}]"
            r = client.post(
                "/panels/p1/energy",
                content=body.encode(),
                headers={**admin, "Content-Type": "application/json"},
            )
            assert r.status_code == 422, r.text
            assert "days[1].kwh" in r.json()["detail"]
        assert stored(client, admin) == []

    def test_a_bad_csv_line_is_named(
        self, client: TestClient, admin: dict[str, str], farm: dict[str, Any]
    ) -> None:
        body = "date,kwh,expected_kwh\n2026-05-01,1.5,2.0\n2026-05-02,nan,1.9\n"
        r = client.post(
            "/panels/p1/energy",
            content=body.encode(),
            headers={**admin, "Content-Type": "text/csv"},
        )
        assert r.status_code == 422
        assert "line 3, kwh" in r.json()["detail"]
        missing = client.post(
            "/panels/p1/energy",
            content=b"day,energy\n",
            headers={**admin, "Content-Type": "text/csv"},
        )
        assert missing.status_code == 422
        assert "date and kwh" in missing.json()["detail"]
        assert stored(client, admin) == []

    def test_other_media_types_are_415(
        self, client: TestClient, admin: dict[str, str], farm: dict[str, Any]
    ) -> None:
        r = client.post(
            "/panels/p1/energy", content=b"<x/>", headers={**admin, "Content-Type": "text/xml"}
        )
        assert r.status_code == 415


class TestSoiling:
    def test_the_simulated_plant_through_the_api(
        self, client: TestClient, admin: dict[str, str], farm: dict[str, Any]
    ) -> None:
        p = plant(0, start=TODAY - timedelta(days=150))
        assert post_energy(client, admin, days_of(p)).status_code == 200
        r = client.get("/panels/p1/soiling", headers=admin)
        assert r.status_code == 200, r.text
        out = r.json()
        assert out["soiling_ratio"] == pytest.approx(p.truth[-1], abs=0.015)
        assert out["low"] < out["soiling_ratio"] < out["high"]
        assert out["rate_per_day"] == pytest.approx(-0.003, abs=0.0003)
        assert [i["cause"] for i in out["intervals"]] == ["start", "detected"]
        assert out["since_cleaning_days"] == pytest.approx(89, abs=1)
        assert out["last_cleaning"] == out["intervals"][1]["start"]
        assert out["loss_kwh_per_day"] > 0
        assert out["loss_since_cleaning_kwh"] > out["loss_kwh_per_day"]
        assert out["days"] == 150
        assert out["recommendation"] is None
        assert "PUT /solar/economics" in out["reason"]

    def test_no_output_says_so(
        self, client: TestClient, admin: dict[str, str], farm: dict[str, Any]
    ) -> None:
        out = client.get("/panels/p1/soiling", headers=admin).json()
        assert out["soiling_ratio"] is None
        assert out["reason"] == "no output stored for this panel"
        assert client.get("/panels/nope/soiling", headers=admin).status_code == 404

    def test_a_robots_cleaning_begins_an_interval(
        self, client: TestClient, admin: dict[str, str], farm: dict[str, Any]
    ) -> None:
        train(client, admin, clean_set(10))
        for _ in range(3):
            post_frame(client, farm, CLEAN_RGB + DUST)
        robot = bearer(farm["robots"]["r1"])
        task = client.post("/cleaning/claim", headers=robot).json()["task_id"]
        assert client.post(f"/cleaning/tasks/{task}/complete", headers=robot).status_code == 200
        # 60 days of output before the cleaning (the test clock's day), 30 after, no recovery
        # in the output at the cleaning (it is known from the robot's task)
        cleaned = TODAY + timedelta(days=1)
        p = plant(2, days=90, cleanings=(60,), start=cleaned - timedelta(days=60))
        farm["clock"].advance(days=40)
        assert post_energy(client, admin, days_of(p)).status_code == 200
        out = client.get("/panels/p1/soiling", headers=admin).json()
        assert [i["cause"] for i in out["intervals"]] == ["start", "robot"]
        assert out["last_cleaning"] == cleaned.isoformat()

    def test_when_cleaning_pays(
        self, client: TestClient, admin: dict[str, str], farm: dict[str, Any]
    ) -> None:
        p = plant(0, start=TODAY - timedelta(days=150))
        post_energy(client, admin, days_of(p))
        prices = {"energy_price_per_kwh": 0.25, "cleaning_cost": 20.0, "cost_per": "visit"}
        r = client.put("/solar/economics", json={**prices, "panels_per_visit": 10}, headers=admin)
        assert r.status_code == 200, r.text
        assert r.json()["per_panel_cost"] == 2.0
        cleaned = p.days[60]
        early = date.fromordinal(int(cleaned) + 10).isoformat()
        off = client.get("/panels/p1/soiling", params={"at": early}, headers=admin).json()
        assert off["as_of"] == early
        assert off["recommendation"]["clean"] is False
        assert off["recommendation"]["by"] > early
        on = client.get("/panels/p1/soiling", headers=admin).json()["recommendation"]
        assert on["clean"] is True
        assert on["lost_value"] >= on["cleaning_cost"] == 2.0
        assert on["optimal_interval_days"] > 0


class TestEconomics:
    def test_put_get_and_bad_values(
        self, client: TestClient, admin: dict[str, str], farm: dict[str, Any]
    ) -> None:
        assert client.get("/solar/economics", headers=admin).status_code == 404
        body = {"energy_price_per_kwh": 0.2, "cleaning_cost": 3, "currency": "EUR"}
        r = client.put("/solar/economics", json=body, headers=admin)
        assert r.status_code == 200
        got = client.get("/solar/economics", headers=admin).json()
        assert got["trigger"] == "camera"
        assert got["cost_per"] == "panel"
        assert got["per_panel_cost"] == 3
        for bad in (
            {**body, "currency": "euro"},
            {**body, "energy_price_per_kwh": 0},
            {**body, "trigger": "x"},
        ):
            assert client.put("/solar/economics", json=bad, headers=admin).status_code == 422
        viewer = client.post("/viewers", json={"name": "board"}, headers=admin).json()["token"]
        assert client.put("/solar/economics", json=body, headers=bearer(viewer)).status_code == 403


class TestTrigger:
    """``camera_and_pays``: a dirty panel gets a task when its output says cleaning pays, or
    when it has no recent output to weigh; the verdict and the task say which."""

    def _dirty(self, client: TestClient, admin: dict[str, str], farm: dict[str, Any]) -> Any:
        train(client, admin, clean_set(10))
        return [post_frame(client, farm, CLEAN_RGB + DUST) for _ in range(3)]

    def _prices(self, client: TestClient, admin: dict[str, str], cost: float) -> None:
        body = {"energy_price_per_kwh": 0.25, "cleaning_cost": cost, "trigger": "camera_and_pays"}
        assert client.put("/solar/economics", json=body, headers=admin).status_code == 200

    def test_dirty_but_not_paying_opens_no_task(
        self, client: TestClient, admin: dict[str, str], farm: dict[str, Any]
    ) -> None:
        p = plant(0, days=75, start=TODAY - timedelta(days=74))  # 14 days after its cleaning
        post_energy(client, admin, days_of(p))
        self._prices(client, admin, 2.0)
        verdicts = self._dirty(client, admin, farm)
        assert verdicts[-1]["clean"] is False
        assert verdicts[-1]["cleaning"].startswith("dirty, no task opened: camera: 3 dirty")
        assert "pays from" in verdicts[-1]["cleaning"]
        assert client.get("/panels/p1/trigger", headers=admin).json()["clean_now"] is False
        assert client.get("/cleaning/tasks", headers=admin).json() == []

    def test_dirty_and_paying_opens_a_task_saying_why(
        self, client: TestClient, admin: dict[str, str], farm: dict[str, Any]
    ) -> None:
        p = plant(0, start=TODAY - timedelta(days=149))
        post_energy(client, admin, days_of(p))
        self._prices(client, admin, 2.0)
        verdicts = self._dirty(client, admin, farm)
        assert verdicts[-1]["cleaning"].startswith("opened a cleaning task: camera: 3 dirty")
        tasks = client.get("/cleaning/tasks", headers=admin).json()
        assert len(tasks) == 1
        assert "output: the energy lost since" in tasks[0]["evidence"]

    def test_no_recent_output_leaves_it_to_the_camera(
        self, client: TestClient, admin: dict[str, str], farm: dict[str, Any]
    ) -> None:
        p = plant(0, days=75, start=TODAY - timedelta(days=120))  # ends 45 days ago
        post_energy(client, admin, days_of(p))
        self._prices(client, admin, 2.0)
        self._dirty(client, admin, farm)
        tasks = client.get("/cleaning/tasks", headers=admin).json()
        assert len(tasks) == 1
        assert tasks[0]["evidence"].endswith("no output in the last 7 days to weigh")

    def test_the_camera_trigger_is_the_default(
        self, client: TestClient, admin: dict[str, str], farm: dict[str, Any]
    ) -> None:
        self._dirty(client, admin, farm)
        tasks = client.get("/cleaning/tasks", headers=admin).json()
        assert tasks[0]["evidence"] == "camera: 3 dirty verdicts in a row"


def test_history_shows_camera_and_output_side_by_side(
    client: TestClient, admin: dict[str, str], farm: dict[str, Any]
) -> None:
    p = plant(0, start=TODAY - timedelta(days=149))
    post_energy(client, admin, days_of(p))
    train(client, admin, clean_set(10))
    post_frame(client, farm, CLEAN_RGB + DUST)
    since = (TODAY - timedelta(days=100)).isoformat() + "T00:00:00Z"
    until = (TODAY + timedelta(days=1)).isoformat() + "T00:00:00Z"
    rows = client.get(
        "/panels/p1/history", params={"since": since, "until": until}, headers=admin
    ).json()
    assert len(rows) == 101
    today = rows[-1]
    assert today["frames"] == 1
    assert today["dirty"] == 1
    assert today["kwh"] == pytest.approx(p.kwh[-1], abs=1e-4)
    assert today["soiling_ratio"] == pytest.approx(p.truth[-1], abs=0.015)
    assert today["soiling_low"] < today["soiling_ratio"] < today["soiling_high"]
    cleaned = [date.fromisoformat(r["start"][:10]).toordinal() for r in rows if r["cleaned"]]
    assert len(cleaned) == 1
    assert abs(cleaned[0] - int(p.days[60])) <= 1
    assert np.isclose(rows[0]["performance_index"], p.kwh[49] / p.expected[49], atol=1e-3)
