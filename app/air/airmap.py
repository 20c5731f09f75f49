"""Drawing the isopleth bands (OpenCV, no plotting library)."""

from __future__ import annotations

from datetime import UTC, datetime
from typing import Literal

import cv2
import numpy as np
from numpy.typing import NDArray

from app.air.core import isopleths
from app.air.service import Station

COLOURS = {  # BGR, from Very Poor to Very Good
    "Very Poor": (60, 20, 150),
    "Poor": (40, 40, 220),
    "Fair": (40, 200, 240),
    "Good": (80, 200, 120),
    "Very Good": (200, 160, 40),
}
SIZE = 640
LEGEND = 150
MIN_HEIGHT = 330
"""The legend's height [px]: a map wider than tall leaves white below it."""
EMPTY = 240
"""Grey of the cells left unpainted (no camera near enough)."""


def _legend_levels() -> tuple[list[tuple[str, tuple[int, int, int]]], list[tuple[int, int, int]]]:
    """Legend entries (best first) and the colour of each band index (worst first)."""
    entries = [(f"{name} {lo}-{hi}", COLOURS[name]) for name, lo, hi in reversed(isopleths.BANDS)]
    return entries, [COLOURS[name] for name, _, _ in isopleths.BANDS]


def _legend_uncertainty(
    edges: tuple[float, ...], unit: str
) -> tuple[list[tuple[str, tuple[int, int, int]]], list[tuple[int, int, int]]]:
    """Legend entries (least uncertain first) and a colour per band: light to dark."""
    n = len(edges) - 1
    ramp = cv2.applyColorMap(
        np.linspace(40, 230, n).astype(np.uint8).reshape(-1, 1), cv2.COLORMAP_VIRIDIS
    )[::-1]
    colours = [(int(b), int(g), int(r)) for b, g, r in ramp[:, 0]]

    def label(v: float) -> str:
        return f"{v / 1000:g} km" if unit == "m" and v >= 1000 else f"{v:g}"

    entries = [
        (
            f"{label(edges[i])}-{label(edges[i + 1])}" if i + 2 < len(edges) else
            f">= {label(edges[i])}",
            colours[i],
        )
        for i in range(n)
    ]  # fmt: skip
    return entries, colours


def render(
    field: isopleths.Field | None,
    stations: list[Station],
    bbox: tuple[float, float, float, float] | None,
    at: datetime,
    layer: Literal["levels", "uncertainty"] = "levels",
) -> bytes:
    """The bands over the bbox (north up, its longer side ``SIZE`` pixels, east–west and
    north–south at one scale in metres, so that a circle around a camera is drawn round), the
    cameras, a legend and the time the map is of. ``layer``: the category bands, or how
    uncertain they are (kriging's standard deviation, or the distance to the nearest camera)."""
    width = height = SIZE
    if field is not None and bbox is not None:
        dx, dy = isopleths.cell_size_m(field)
        w_m, h_m = dx * len(field.lon), dy * len(field.lat)
        width = max(1, round(SIZE * w_m / max(w_m, h_m)))
        height = max(1, round(SIZE * h_m / max(w_m, h_m)))
    title = "level"
    if layer == "levels" or field is None:
        entries, colours = _legend_levels()
        edges: tuple[float, ...] = isopleths.BAND_EDGES
        z: NDArray[np.float64] | None = None if field is None else field.value
    else:
        edges = isopleths.uncertainty_edges(field)
        unit = isopleths.UNCERTAINTY_UNITS[field.uncertainty_kind]
        entries, colours = _legend_uncertainty(edges, unit)
        z = isopleths.uncertainty_of(field)
        title = "kriging sd [level]" if unit == "level" else "nearest camera"
    # the legend beside the map, not beside a 640-pixel square: a tall map (a city that runs
    # north-south) was a strip at the left with most of the image white between it and the
    # legend
    left = width if field is not None and bbox is not None else SIZE
    canvas = np.full((max(height, MIN_HEIGHT), left + LEGEND, 3), 255, np.uint8)
    if field is not None and bbox is not None and z is not None:
        x0, y0, x1, y1 = bbox
        band = np.full(z.shape, -1, np.int32)
        for i, e in enumerate(edges[:-1]):
            band[(z >= e) & (z < edges[i + 1])] = i
        image = np.full((*z.shape, 3), EMPTY, np.uint8)
        for i, colour in enumerate(colours):
            image[band == i] = colour
        image = cv2.resize(image[::-1], (width, height), interpolation=cv2.INTER_NEAREST)
        canvas[:height, :width] = image
        for s in stations:
            px = int((s.lon - x0) / (x1 - x0) * (width - 1))
            py = int((y1 - s.lat) / (y1 - y0) * (height - 1))
            cv2.circle(canvas, (px, py), 5, (0, 0, 0), -1)
            cv2.circle(canvas, (px, py), 3, (255, 255, 255), -1)
    else:
        cv2.putText(
            canvas,
            "no readings",
            (SIZE // 2 - 80, SIZE // 2),
            cv2.FONT_HERSHEY_SIMPLEX,
            0.9,
            (0, 0, 0),
            2,
        )
    font = cv2.FONT_HERSHEY_SIMPLEX
    cv2.putText(canvas, title, (left + 12, 20), font, 0.42, (0, 0, 0), 1)
    for i, (text, colour) in enumerate(entries):
        y = 44 + 30 * i
        cv2.rectangle(canvas, (left + 12, y - 14), (left + 36, y + 4), colour, -1)
        cv2.putText(canvas, text, (left + 42, y), font, 0.42, (0, 0, 0), 1)
    cv2.putText(canvas, "o camera", (left + 12, 44 + 30 * len(entries)), font, 0.45, (0, 0, 0), 1)
    utc = at.astimezone(UTC)
    for i, text in enumerate((utc.strftime("%Y-%m-%d"), utc.strftime("%H:%M UTC"))):
        y = canvas.shape[0] - 36 + 18 * i
        cv2.putText(canvas, text, (left + 12, y), font, 0.45, (0, 0, 0), 1)
    ok, buf = cv2.imencode(".png", canvas)
    assert ok
    return bytes(buf.tobytes())
