"""Reference measurements as the service's levels 1–10: PM2.5 [µg/m³] or US AQI → level.

Source: US EPA, *Technical Assistance Document for the Reporting of Daily Air Quality – the Air
Quality Index (AQI)*, EPA-454/B-24-002 (May 2024), Table 6, with the PM2.5 breakpoints of the
February 2024 revision. PM2.5 is truncated to 0.1 µg/m³ and turned into the AQI by linear
interpolation within its category (the document's eq. 1):

    I = (I_hi − I_lo)/(C_hi − C_lo) · (C − C_lo) + I_lo, rounded to a whole number.

The AQI's six categories fill the service's five, each category's lower and upper half a level
(level 10 the clearest air, 1 the worst):

    AQI   0–25 → 10,  26–50 → 9     Good                              → Very Good
    AQI  51–75 → 8,   76–100 → 7    Moderate                          → Good
    AQI 101–125 → 6, 126–150 → 5    Unhealthy for Sensitive Groups    → Fair
    AQI 151–175 → 4, 176–200 → 3    Unhealthy                         → Poor
    AQI 201–300 → 2, above 300 → 1  Very Unhealthy and Hazardous      → Very Poor
"""

from __future__ import annotations

import math

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


def level_of_pm25(pm25: float) -> int:
    """The level 1–10 of a PM2.5 concentration [µg/m³] (through its AQI)."""
    return level_of_aqi(aqi_of_pm25(pm25))
