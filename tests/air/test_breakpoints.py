"""Reference PM2.5 and AQI as levels (``app.air.core.breakpoints``): the US EPA AQI table
(EPA-454/B-24-002, 2024) and the European Air Quality Index's PM2.5 bands (EEA, 2017) at every
edge, and calibration from reference values over HTTP."""

from __future__ import annotations

import math
from typing import Any

import pytest
from fastapi.testclient import TestClient

from app.air.core.breakpoints import aqi_of_pm25, level_of_aqi, level_of_pm25, table_for_places
from tests.factories.air import sky_jpeg

# (PM2.5 µg/m³, AQI) at each category's edges, as the EPA table and eq. 1 give them
EDGES = [
    (0.0, 0),
    (9.0, 50),
    (9.1, 51),
    (35.4, 100),
    (35.5, 101),
    (55.4, 150),
    (55.5, 151),
    (125.4, 200),
    (125.5, 201),
    (225.4, 300),
    (225.5, 301),
    (325.4, 500),
    (1000.0, 500),
    (1e308, 500),  # 10 × it overflows a float: it was a 500
]


@pytest.mark.parametrize(("pm25", "aqi"), EDGES)
def test_pm25_to_aqi_at_the_table_s_edges(pm25: float, aqi: int) -> None:
    assert aqi_of_pm25(pm25) == aqi


def test_pm25_is_truncated_to_a_tenth_then_interpolated() -> None:
    assert aqi_of_pm25(9.09) == 50  # truncated to 9.0
    assert aqi_of_pm25(12.0) == round((100 - 51) / (35.4 - 9.1) * (12.0 - 9.1) + 51)  # 56


@pytest.mark.parametrize(
    ("aqi", "level"),
    [
        (0, 10), (25, 10), (26, 9), (50, 9), (51, 8), (75, 8), (76, 7), (100, 7), (101, 6),
        (125, 6), (126, 5), (150, 5), (151, 4), (175, 4), (176, 3), (200, 3), (201, 2),
        (300, 2), (301, 1), (500, 1), (999, 1), (1e308, 1),
    ],
)  # fmt: skip
def test_aqi_to_level_at_every_edge(aqi: int, level: int) -> None:
    assert level_of_aqi(aqi) == level


def test_pm25_to_level_follows_the_categories() -> None:
    assert [level_of_pm25(c) for c in (4.5, 9.0, 9.1, 35.4, 35.5, 55.5, 125.5, 225.5)] == [
        10, 9, 8, 7, 6, 4, 2, 1,
    ]  # fmt: skip


@pytest.mark.parametrize(
    ("pm25", "level"),
    [
        (0.0, 10), (5.0, 10), (5.01, 9), (10.0, 9), (10.01, 8), (15.0, 8), (15.01, 7),
        (20.0, 7), (20.01, 6), (22.5, 6), (22.51, 5), (25.0, 5), (25.01, 4), (37.5, 4),
        (37.51, 3), (50.0, 3), (50.01, 2), (75.0, 2), (75.01, 1), (800.0, 1), (1e308, 1),
    ],
)  # fmt: skip
def test_the_european_bands_at_every_edge(pm25: float, level: int) -> None:
    """EEA bands Good ≤ 10, Fair ≤ 20, Moderate ≤ 25, Poor ≤ 50, Very poor ≤ 75 µg/m³, each
    halved; Extremely poor is level 1."""
    assert level_of_pm25(pm25, "eu_eaqi") == level


def test_the_european_categories_are_its_bands() -> None:
    """The service's categories, two levels each, are the index's first five bands."""
    from app.air.core.airquality import category

    said = [category(level_of_pm25(c, "eu_eaqi")) for c in (7.0, 12.0, 21.0, 30.0, 60.0, 90.0)]
    assert said == ["Very Good", "Good", "Fair", "Poor", "Very Poor", "Very Poor"]


def test_an_unknown_table_is_refused() -> None:
    with pytest.raises(ValueError, match="table must be one of"):
        level_of_pm25(10.0, "uk_daqi")


@pytest.mark.parametrize("bad", [-0.1, math.nan, math.inf])
def test_no_level_for_a_bad_value(bad: float) -> None:
    with pytest.raises(ValueError, match="finite number ≥ 0"):
        level_of_pm25(bad)
    with pytest.raises(ValueError, match="finite number ≥ 0"):
        level_of_pm25(bad, "eu_eaqi")
    with pytest.raises(ValueError, match="finite number ≥ 0"):
        level_of_aqi(bad)


PM25_OF_LEVEL = {1: 250.0, 3: 100.0, 5: 52.0, 7: 30.0, 10: 3.0}


def files_and(values: dict[int, Any]) -> tuple[list[Any], list[str]]:
    files, refs = [], []
    for level, value in values.items():
        for k in range(8):
            jpeg = sky_jpeg(level, seed=100 * level + k)
            files.append(("files", (f"{level}-{k}.jpg", jpeg, "image/jpeg")))
            refs.append(str(value))
    return files, refs


def test_a_calibration_from_reference_pm25(
    client: TestClient, admin: dict[str, str], city: dict[str, Any]
) -> None:
    files, refs = files_and(PM25_OF_LEVEL)
    r = client.post(
        "/air/calibration",
        files=files,
        data={"pm25": refs},
        params={"camera_id": "sky0", "significance": 0.01, "breakpoints": "us_epa"},
        headers=admin,
    )
    assert r.status_code == 201, r.text
    assert sorted(c["level"] for c in r.json()["clusters"]) == [1, 3, 5, 7, 10]
    assert any("US EPA AQI" in w for w in r.json()["warnings"])


@pytest.mark.parametrize(
    ("place", "table"),
    [
        # city centres [°], rounded from their Wikipedia coordinates
        ((45.46, 9.19), "eu_eaqi"),  # Milan
        ((64.15, -21.94), "eu_eaqi"),  # Reykjavík
        ((37.74, -25.67), "eu_eaqi"),  # Ponta Delgada, the Azores
        ((35.90, 14.51), "eu_eaqi"),  # Valletta
        ((35.17, 33.36), "eu_eaqi"),  # Nicosia
        ((41.01, 28.98), "eu_eaqi"),  # Istanbul
        ((36.14, -5.35), "eu_eaqi"),  # Gibraltar
        ((40.71, -74.01), "us_epa"),  # New York
        ((28.61, 77.21), "us_epa"),  # New Delhi
        ((36.75, 3.06), "us_epa"),  # Algiers
        ((36.81, 10.18), "us_epa"),  # Tunis
        ((35.77, -5.80), "us_epa"),  # Tangier
        ((33.89, 35.50), "us_epa"),  # Beirut
        ((36.20, 37.13), "us_epa"),  # Aleppo
        ((None, None), "us_epa"),  # nowhere known
    ],
)
def test_the_table_of_a_place(place: tuple[float | None, float | None], table: str) -> None:
    """Cameras in Europe read the European index, the rest of the world the EPA's; the coasts
    facing Europe across the Mediterranean are not Europe."""
    assert table_for_places([place]) == table
    # a camera without a position changes nothing; one outside Europe makes it the EPA's
    assert table_for_places([place, (None, None)]) == table
    assert table_for_places([place, (40.71, -74.01)]) == "us_epa"


def test_pm25_without_a_table_takes_the_one_of_the_cameras_place(
    client: TestClient, admin: dict[str, str], city: dict[str, Any]
) -> None:
    """The city's cameras stand in Milan: its PM2.5 become levels by the European index, and
    the warning says why; cameras elsewhere, or of no known place, keep the EPA's."""
    for cam, lat, lon in (("nyc", 40.71, -74.01), ("nowhere", None, None)):
        body = {"id": cam, "kind": "sky", "lat": lat, "lon": lon, "roi": [0, 0, 160, 55]}
        assert client.post("/cameras", json=body, headers=admin).status_code == 201
    files, refs = files_and({1: 100.0, 3: 45.0, 5: 24.0, 7: 18.0, 10: 3.0})

    def calibrate(applies_to: list[str], kind: str = "pm25") -> dict[str, Any]:
        r = client.post(
            "/air/calibration",
            files=files,
            data={kind: refs},
            params={"camera_id": "sky0", "significance": 0.01, "applies_to": applies_to},
            headers=admin,
        )
        assert r.status_code == 201, r.text
        body: dict[str, Any] = r.json()
        return body

    def said(graded: list[str]) -> str:
        [note] = [w for w in calibrate(graded)["warnings"] if w.startswith("levels from")]
        return note

    milan = calibrate(["sky0", "sky1"])
    assert sorted(c["level"] for c in milan["clusters"]) == [1, 3, 5, 7, 10]  # the EEA's bands
    eu = "European Air Quality Index PM2.5 bands (EEA, 2017): the cameras it grades stand in"
    assert said(["sky0", "sky1"]).startswith(f"levels from PM2.5 by the {eu} Europe")
    assert said(["sky0", "nowhere"]).startswith(f"levels from PM2.5 by the {eu} Europe")
    epa = "levels from PM2.5 by the US EPA AQI breakpoints (EPA-454/B-24-002, 2024): "
    for graded in (["nyc"], ["sky0", "nyc"]):
        levels = sorted(c["level"] for c in calibrate(graded)["clusters"])
        assert levels == [3, 6, 7, 8, 10]  # AQI 182, 124, 79, 68, 17
        assert said(graded).startswith(f"{epa}a camera it grades stands outside Europe")
    assert said(["nowhere"]).startswith(f"{epa}no camera it grades has a position")
    # a city-wide calibration grades every sky camera: New York's among them
    assert said([]).startswith(f"{epa}a camera it grades stands outside Europe")
    # the US AQI needs no table, wherever the cameras stand
    assert any("US EPA AQI" in w for w in calibrate(["sky0"], kind="aqi")["warnings"])


def test_a_calibration_from_pm25_by_the_european_index(
    client: TestClient, admin: dict[str, str], city: dict[str, Any]
) -> None:
    """The same images, their PM2.5 made levels by the European bands: 100 → 1, 45 → 3,
    24 → 5, 18 → 7, 3 → 10 µg/m³ (by the EPA table, AQI 182, 124, 79, 68 and 17: levels 3, 6,
    7, 8 and 10)."""
    files, refs = files_and({1: 100.0, 3: 45.0, 5: 24.0, 7: 18.0, 10: 3.0})
    r = client.post(
        "/air/calibration",
        files=files,
        data={"pm25": refs},
        params={"camera_id": "sky0", "significance": 0.01, "breakpoints": "eu_eaqi"},
        headers=admin,
    )
    assert r.status_code == 201, r.text
    assert sorted(c["level"] for c in r.json()["clusters"]) == [1, 3, 5, 7, 10]
    assert any("European Air Quality Index" in w for w in r.json()["warnings"])


@pytest.mark.parametrize(
    ("data", "params", "fault"),
    [
        ({"pm25": ["-1"] * 40}, {}, "≥ 0"),
        ({"pm25": ["nan"] * 40}, {}, "finite"),
        ({"pm25": ["3"] * 40, "levels": ["10"] * 40}, {}, "one of levels, pm25 or aqi"),
        ({"aqi": ["20"] * 39}, {}, "40 files but 39 aqi"),
        ({"pm25": ["a lot"] * 40}, {}, "numbers"),
        # the European index maps PM2.5 only, by a table the service knows
        ({"levels": ["3"] * 40}, {"breakpoints": "eu_eaqi"}, "give pm25"),
        ({"aqi": ["30"] * 40}, {"breakpoints": "eu_eaqi"}, "give pm25"),
        ({"pm25": ["30"] * 40}, {"breakpoints": "uk_daqi"}, "breakpoints"),
    ],
    ids=[
        "negative", "nan", "both", "lengths", "not-a-number", "eaqi-levels", "eaqi-aqi",
        "unknown-table",
    ],
)  # fmt: skip
def test_bad_reference_values_are_refused_and_nothing_stored(
    client: TestClient,
    admin: dict[str, str],
    city: dict[str, Any],
    data: dict[str, Any],
    params: dict[str, str],
    fault: str,
) -> None:
    files, _ = files_and({1: 0, 3: 0, 5: 0, 7: 0, 10: 0})
    r = client.post("/air/calibration", files=files, data=data, params=params, headers=admin)
    assert r.status_code == 422, r.text
    assert r.headers["content-type"].startswith("application/problem+json")
    assert fault in r.text
    assert client.get("/air/calibrations", headers=admin).json() == []


def test_json_takes_one_reference_per_frame(client: TestClient, admin: dict[str, str]) -> None:
    both = {"frame_ids": ["f1"], "levels": [3], "pm25": [40.0]}
    r = client.post("/air/calibration", json=both, headers=admin)
    assert r.status_code == 422
    assert "one of levels, pm25 or aqi" in r.text
    r = client.post("/air/calibration", json={"frame_ids": ["f1"], "pm25": [-2.0]}, headers=admin)
    assert r.status_code == 422
