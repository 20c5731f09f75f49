"""Reference values a calibration is made from: levels, or PM2.5 or AQI and the breakpoint
table that makes them levels; what they must be to calibrate; which method grades them best."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from sqlalchemy.orm import Session

from app.air.core import airquality, breakpoints, selection
from app.air.services.cameras import graded_cameras
from app.platform.http.errors import Unprocessable


@dataclass(frozen=True, slots=True)
class References:
    levels: list[int]
    notes: list[str]
    """How the levels were made, for the calibration's warnings."""
    reference: tuple[str, list[float]] | None
    """("pm25" or "aqi", values) when given in a reference unit: the regression's unit."""
    table: str = "us_epa"
    """The breakpoint table the reference values became levels by."""


Raw = tuple[list[int] | None, list[float] | None, list[float] | None]
"""(levels, pm25, aqi) as given, one of them."""


def check_table(table: str | None, pm25_given: bool) -> None:
    """Refuse a table other than the EPA's for references that are not PM2.5."""
    if table is not None and table != "us_epa" and not pm25_given:
        raise Unprocessable(
            f"breakpoints={table} maps PM2.5 to levels: give pm25 (the US AQI and levels "
            "need no table of it)",
            code="breakpoints_without_pm25",
        )


def parse_references(name: str, raw: list[str]) -> Raw:
    """A multipart field of levels (integers 1–10) or of PM2.5 or AQI values (finite, ≥ 0)."""
    if name == "levels":
        try:
            levels = [int(v) for v in raw]
        except ValueError:
            raise Unprocessable("levels must be integers 1–10") from None
        if any(not 1 <= v <= 10 for v in levels):
            raise Unprocessable("levels must be integers 1–10")
        return levels, None, None
    try:
        values = [float(v) for v in raw]
    except ValueError:
        raise Unprocessable(f"{name} must be numbers") from None
    if not all(math.isfinite(v) and v >= 0 for v in values):
        raise Unprocessable(f"{name} must be finite numbers ≥ 0")
    return (None, values, None) if name == "pm25" else (None, None, values)


def of_form(fields: dict[str, list[str]], n_files: int, table: str | None) -> Raw:
    """The references of a multipart calibration: one of levels, pm25 or aqi, one per file
    (422 otherwise), checked (``parse_references``, ``check_table``)."""
    named = {k: fields[k] for k in ("levels", "pm25", "aqi") if fields.get(k)}
    if len(named) != 1:
        raise Unprocessable("give one of levels, pm25 or aqi per file")
    [(name, raw)] = named.items()
    if n_files != len(raw):
        raise Unprocessable(f"{n_files} files but {len(raw)} {name}; give one each")
    given = parse_references(name, raw)
    check_table(table, name == "pm25")
    return given


def as_levels(session: Session, raw: Raw, table: str | None, applies_to: list[str]) -> References:
    """Levels as given, or from reference PM2.5 or AQI values by the breakpoint ``table``
    (``core.breakpoints``); the European table maps PM2.5 only. Without a table, PM2.5 takes
    the one of the graded cameras' place (``breakpoints_of_place``)."""
    levels, pm25, aqi = raw
    check_table(table, pm25 is not None)
    if levels is not None:
        return References(levels, [], None)
    if pm25 is not None:
        chosen, why = (table, "") if table else breakpoints_of_place(session, applies_to)
        mapped = [breakpoints.level_of_pm25(v, chosen) for v in pm25]
        note = f"levels from PM2.5 by the {breakpoints.TABLES[chosen]}"
        if why:
            note += f": {why} (breakpoints=us_epa or eu_eaqi chooses a table)"
        return References(mapped, [note], ("pm25", pm25), chosen)
    assert aqi is not None
    return References(
        [breakpoints.level_of_aqi(v) for v in aqi],
        [f"levels from the {breakpoints.SOURCE}"],
        ("aqi", aqi),
    )


def check_references(
    reference: tuple[str, Sequence[float]] | None, groups: Sequence[str] | None
) -> None:
    """Refuse reference values that cannot calibrate: all equal (nothing to learn the air's
    changes from), or, their days known, of fewer than ``airquality.MIN_GROUPS`` days (a
    day's frames share their weather: fewer days cannot show how a method does on a new
    one)."""
    if reference is None:
        return
    unit, values = reference
    if len(set(values)) < 2:
        raise Unprocessable(
            f"the reference {unit} values are all equal ({values[0]:g}): a calibration needs "
            "the air to vary among its images",
            code="references_all_equal",
        )
    days = len(set(groups)) if groups is not None else None
    if days is not None and days < airquality.MIN_GROUPS:
        raise Unprocessable(
            f"the images cover {days} day{'s' if days != 1 else ''}: a calibration from "
            f"reference values needs at least {airquality.MIN_GROUPS}, so that it is judged "
            "on days it was not fitted to",
            code="too_few_days",
        )


def choose(
    modes: NDArray[np.float64],
    features: NDArray[np.float64] | None,
    levels: Sequence[int],
    reference: tuple[str, Sequence[float]],
    groups: Sequence[str] | None,
    table: str,
    significance: float,
    shrinkage: float,
) -> selection.Selection:
    """The method that grades the reference's images best on days left out."""
    ok = features is not None and features.ndim == 2
    ok = ok and features is not None and features.shape[1] == len(airquality.SKY_FEATURES)
    unit, values = reference
    try:
        return selection.choose(
            modes,
            features if ok else None,
            levels,
            values,
            unit=unit,
            table=table,
            groups=groups,
            significance=significance,
            shrinkage=shrinkage,
        )
    except ValueError as exc:
        raise Unprocessable(f"cannot calibrate: {exc}", code="bad_calibration") from None


def breakpoints_of_place(session: Session, applies_to: Sequence[str]) -> tuple[str, str]:
    """The breakpoint table of the cameras a calibration grades (``graded_cameras``), and
    why: the European index where all those with a position stand in Europe, else the EPA's
    (``breakpoints.table_for_places``)."""
    places = [(c.lat, c.lon) for c in session.scalars(graded_cameras(applies_to))]
    table = breakpoints.table_for_places(places)
    if all(lat is None or lon is None for lat, lon in places):
        return table, "no camera it grades has a position"
    if table == "eu_eaqi":
        return table, "the cameras it grades stand in Europe"
    return table, "a camera it grades stands outside Europe"
