"""What a clean panel would make in a day, from the day's insolation, with pvlib's models.

A farm's SCADA export often carries only the measured energy and an irradiance sensor's daily
sum. The soiling ratio needs what the clean panel would have made on the same day: PVWatts'
DC model (pvlib.pvsystem.pvwatts_dc) over the plane-of-array insolation, which for a global
horizontal sum is first spread over the day's hours on a clear-sky shape (Haurwitz), split into
beam and diffuse (Erbs) and turned onto the panel's plane (isotropic sky, pvlib.irradiance).

The cell is taken at the reference 25 °C, as the day's temperature is not given: a constant
factor cancels in the soiling ratio (normalised to the panel after its cleaning), a seasonal
swing of temperature does not, and an export with the inverter's own expected energy is better.
"""

from __future__ import annotations

import numpy as np
import pandas as pd
import pvlib
from numpy.typing import NDArray

HOURS = np.arange(24) + 0.5
"""The day's hours at their middles [h of local solar time]."""

UNIX_ORDINAL = 719163
"""``date(1970, 1, 1).toordinal()``."""


def energy_from_poa(poa_kwh_m2: NDArray[np.float64], kwp: float) -> NDArray[np.float64]:
    """The clean panel's DC energy [kWh] for each day's plane-of-array insolation [kWh/m²].

    PVWatts at the reference temperature, ``P = P₀ · G / 1000 W/m²``, summed over the day:
    ``E = P₀ · H`` with ``P₀ = kwp`` [kW] and ``H`` [kWh/m²]; shapes are kept."""
    poa = np.asarray(poa_kwh_m2, dtype=np.float64)
    # pvwatts_dc is linear in irradiance at a fixed cell temperature: the day's sum in Wh/m²
    # stands for an hour's irradiance in W/m², and P₀ in kW gives kWh
    out = pvlib.pvsystem.pvwatts_dc(
        effective_irradiance=poa * 1000.0, temp_cell=25.0, pdc0=kwp, gamma_pdc=-0.004
    )
    return np.asarray(out, dtype=np.float64)


def poa_from_ghi(
    days: NDArray[np.int64],
    ghi_kwh_m2: NDArray[np.float64],
    *,
    lat: float,
    lon: float,
    tilt: float,
    azimuth: float,
) -> NDArray[np.float64]:
    """Each day's plane-of-array insolation [kWh/m²] from its global horizontal one [kWh/m²].

    ``days``: proleptic Gregorian ordinals (``date.toordinal()``), shape (N,); ``tilt`` [°]
    from horizontal, ``azimuth`` [°] east of north (180: facing south), as pvlib takes them.
    The day's sum is spread over its hours in proportion to Haurwitz's clear sky, split by
    Erbs' correlation and transposed on an isotropic sky; a day without sun (polar night) is 0.
    """
    days = np.asarray(days, dtype=np.int64)
    ghi_day = np.asarray(ghi_kwh_m2, dtype=np.float64)
    if days.shape != ghi_day.shape or days.ndim != 1:
        raise ValueError(
            f"days and ghi must be equal 1-D arrays; got {days.shape}, {ghi_day.shape}"
        )
    if days.size == 0:
        return np.zeros(0)
    # each day's hours in local solar time, as UTC instants (longitude/15 hours from Greenwich)
    hours = (days[:, None] - UNIX_ORDINAL) * 24.0 + HOURS[None, :] - lon / 15.0
    times = pd.to_datetime(np.round(hours.ravel() * 3600.0).astype(np.int64), unit="s", utc=True)
    sun = pvlib.solarposition.get_solarposition(times, lat, lon)
    zenith = sun["zenith"].to_numpy()
    clear = np.asarray(pvlib.clearsky.haurwitz(sun["apparent_zenith"])["ghi"]).reshape(-1, 24)
    clear_sum = clear.sum(axis=1)  # [Wh/m²] over the day's hours
    scale = np.divide(
        ghi_day * 1000.0, clear_sum, out=np.zeros_like(clear_sum), where=clear_sum > 0
    )
    ghi_h = (clear * scale[:, None]).ravel()
    parts = pvlib.irradiance.erbs(ghi_h, zenith, times.day_of_year.to_numpy())
    poa = pvlib.irradiance.get_total_irradiance(
        tilt,
        azimuth,
        zenith,
        sun["azimuth"].to_numpy(),
        np.asarray(parts["dni"]),
        ghi_h,
        np.asarray(parts["dhi"]),
        model="isotropic",
    )["poa_global"]
    poa_h = np.nan_to_num(np.asarray(poa, dtype=np.float64), nan=0.0).reshape(-1, 24)
    daily: NDArray[np.float64] = np.clip(poa_h, 0.0, None).sum(axis=1) / 1000.0
    return daily
