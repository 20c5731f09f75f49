"""Reference measurements as the service's levels 1–10: PM2.5 [µg/m³] or US AQI → level, by
one of two published tables (``TABLES``): the US EPA's AQI (the default) or the European Air
Quality Index.

US EPA source: *Technical Assistance Document for the Reporting of Daily Air Quality – the
Air Quality Index (AQI)*, EPA-454/B-24-002 (May 2024), Table 6, with the PM2.5 breakpoints of
the February 2024 revision. PM2.5 is truncated to 0.1 µg/m³ and turned into the AQI by linear
interpolation within its category (the document's eq. 1):

    I = (I_hi − I_lo)/(C_hi − C_lo) · (C − C_lo) + I_lo, rounded to a whole number.

The AQI's six categories fill the service's five, each category's lower and upper half a level
(level 10 the clearest air, 1 the worst):

    AQI   0–25 → 10,  26–50 → 9     Good                              → Very Good
    AQI  51–75 → 8,   76–100 → 7    Moderate                          → Good
    AQI 101–125 → 6, 126–150 → 5    Unhealthy for Sensitive Groups    → Fair
    AQI 151–175 → 4, 176–200 → 3    Unhealthy                         → Poor
    AQI 201–300 → 2, above 300 → 1  Very Unhealthy and Hazardous      → Very Poor

European source: European Environment Agency, *European Air Quality Index* (2017), the PM2.5
bands [µg/m³] Good 0–10, Fair 10–20, Moderate 20–25, Poor 25–50, Very poor 50–75, Extremely
poor 75–800 (upper edges inclusive), applied to the reference values as given. Its first five
bands are the service's five categories, halved into levels as above; the last is level 1:

    0–5 → 10,    5–10 → 9       Good                              → Very Good
    10–15 → 8,   15–20 → 7      Fair                              → Good
    20–22.5 → 6, 22.5–25 → 5    Moderate                          → Fair
    25–37.5 → 4, 37.5–50 → 3    Poor                              → Poor
    50–75 → 2,   above 75 → 1   Very poor and Extremely poor      → Very Poor

Its levels are finer where a European city's air mostly lies (5–50 µg/m³: eight levels against
the EPA table's four), so they rank the hours more finely; its categories are narrower, so a
camera's estimate is more often unsure of its category (bench/README.md, air quality).

A city reads its air by its own index: cameras in Europe (``EUROPE``) take the European table
unless told otherwise, all others the EPA's (``table_for_places``).
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from typing import Literal

import numpy as np

PM25 = (
    (0.0, 9.0, 0, 50),
    (9.1, 35.4, 51, 100),
    (35.5, 55.4, 101, 150),
    (55.5, 125.4, 151, 200),
    (125.5, 225.4, 201, 300),
    (225.5, 325.4, 301, 500),
)
"""(C_lo, C_hi, I_lo, I_hi): PM2.5 [µg/m³, 24-hour] against the AQI (EPA, 2024)."""

LEVEL_EDGES = (
    (25, 10),
    (50, 9),
    (75, 8),
    (100, 7),
    (125, 6),
    (150, 5),
    (175, 4),
    (200, 3),
    (300, 2),
)
"""(highest AQI, level): the level of an AQI is that of the first edge at or above it; 1 beyond."""

SOURCE = "US EPA AQI breakpoints (EPA-454/B-24-002, 2024)"

EAQI_PM25_LEVELS = (
    (5.0, 10),
    (10.0, 9),
    (15.0, 8),
    (20.0, 7),
    (22.5, 6),
    (25.0, 5),
    (37.5, 4),
    (50.0, 3),
    (75.0, 2),
)
"""(highest PM2.5 [µg/m³], level) of the European Air Quality Index's bands, halved; 1 beyond."""

EAQI_SOURCE = "European Air Quality Index PM2.5 bands (EEA, 2017)"

Table = Literal["us_epa", "eu_eaqi"]
"""A breakpoint table's name."""

TABLES: dict[str, str] = {"us_epa": SOURCE, "eu_eaqi": EAQI_SOURCE}
"""The breakpoint tables by name (``Table``), with their sources."""


EUROPE = (
    (-32.0, 36.5),
    (-10.0, 36.0),
    (-5.6, 35.95),
    (-1.5, 36.3),
    (2.0, 37.4),
    (8.0, 37.7),
    (10.5, 37.6),
    (12.0, 36.5),
    (12.2, 35.0),
    (15.0, 34.5),
    (34.7, 34.4),
    (35.9, 36.0),
    (36.6, 36.8),
    (42.4, 37.1),
    (45.0, 37.3),
    (45.0, 82.0),
    (-32.0, 82.0),
)
"""The area whose cameras take the European index by default, (lon, lat) [°] of a polygon:
the continent west of 45° E with its islands (Iceland, the Azores, Malta, Cyprus) and Turkey,
bounded in the south by the Mediterranean's middle, so that the coasts of North Africa and the
Levant stay outside."""


def table_for_places(places: Iterable[tuple[float | None, float | None]]) -> Table:
    """The breakpoint table of cameras at ``places`` ((lat, lon) [°], None where unknown):
    ``eu_eaqi`` when at least one has a position and every one that has lies in ``EUROPE``,
    else ``us_epa``."""
    from shapely import Polygon, contains_xy

    known = [(lon, lat) for lat, lon in places if lat is not None and lon is not None]
    if not known:
        return "us_epa"
    lon, lat = np.array(known, dtype=np.float64).T
    return "eu_eaqi" if bool(np.all(contains_xy(Polygon(EUROPE), lon, lat))) else "us_epa"


def aqi_of_pm25(pm25: float) -> int:
    """The AQI of a PM2.5 concentration [µg/m³], 500 beyond the table. ValueError for a
    negative or non-finite one."""
    if not math.isfinite(pm25) or pm25 < 0:
        raise ValueError(f"PM2.5 must be a finite number ≥ 0 µg/m³; got {pm25}")
    if pm25 > PM25[-1][1]:  # beyond the table (and before 10 × a huge value overflows)
        return 500
    c = math.floor(pm25 * 10 + 1e-9) / 10  # truncated to 0.1 µg/m³, as the document says
    for c_lo, c_hi, i_lo, i_hi in PM25:
        if c <= c_hi:
            return round((i_hi - i_lo) / (c_hi - c_lo) * (c - c_lo) + i_lo)
    return 500


def level_of_aqi(aqi: float) -> int:
    """The level 1–10 of a US AQI value (0–500, higher beyond is 1)."""
    if not math.isfinite(aqi) or aqi < 0:
        raise ValueError(f"the AQI must be a finite number ≥ 0; got {aqi}")
    value = round(min(aqi, 1000.0))
    return next((level for top, level in LEVEL_EDGES if value <= top), 1)


def level_of_pm25(pm25: float, table: str = "us_epa") -> int:
    """The level 1–10 of a PM2.5 concentration [µg/m³] by ``table``: through its US AQI, or
    by the European index's bands. ValueError for a negative or non-finite one."""
    if table == "us_epa":
        return level_of_aqi(aqi_of_pm25(pm25))
    if table != "eu_eaqi":
        raise ValueError(f"table must be one of {sorted(TABLES)}; got {table!r}")
    if not math.isfinite(pm25) or pm25 < 0:
        raise ValueError(f"PM2.5 must be a finite number ≥ 0 µg/m³; got {pm25}")
    return next((level for top, level in EAQI_PM25_LEVELS if pm25 <= top), 1)
