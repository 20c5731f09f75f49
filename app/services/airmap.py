"""Drawing the isopleth bands (OpenCV, no plotting library)."""

from __future__ import annotations

from datetime import UTC, datetime

import cv2
import numpy as np

from app.core import isopleths
from app.services.air import Station

COLOURS = {  # BGR, from Very Poor to Very Good
    "Very Poor": (60, 20, 150),
    "Poor": (40, 40, 220),
    "Fair": (40, 200, 240),
    "Good": (80, 200, 120),
    "Very Good": (200, 160, 40),
}
SIZE = 640
LEGEND = 150
MIN_HEIGHT = 280
"""The legend's height [px]: a map wider than tall leaves white below it."""


def render(
    field: isopleths.Field | None,
    stations: list[Station],
    bbox: tuple[float, float, float, float] | None,
    at: datetime,
) -> bytes:
    """The bands over the bbox (north up, its longer side ``SIZE`` pixels, east–west and
    north–south at one scale in metres, so that a circle around a camera is drawn round), the
    cameras, a legend and the time the map is of."""
    width = height = SIZE
    if field is not None and bbox is not None:
        dx, dy = isopleths.cell_size_m(field)
        w_m, h_m = dx * len(field.lon), dy * len(field.lat)
        width = max(1, round(SIZE * w_m / max(w_m, h_m)))
        height = max(1, round(SIZE * h_m / max(w_m, h_m)))
    canvas = np.full((max(height, MIN_HEIGHT), SIZE + LEGEND, 3), 255, np.uint8)
    if field is not None and bbox is not None:
        x0, y0, x1, y1 = bbox
        z = field.value
        band = np.full(z.shape, -1, np.int32)
        for i, e in enumerate(isopleths.BAND_EDGES[:-1]):
            band[(z >= e) & (z < isopleths.BAND_EDGES[i + 1])] = i
        image = np.full((*z.shape, 3), 240, np.uint8)
        for i, (name, _, _) in enumerate(isopleths.BANDS):
            image[band == i] = COLOURS[name]
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
    for i, (name, lo, hi) in enumerate(reversed(isopleths.BANDS)):
        y = 30 + 36 * i
        cv2.rectangle(canvas, (SIZE + 12, y - 16), (SIZE + 36, y + 6), COLOURS[name], -1)
        cv2.putText(
            canvas,
            f"{name} {lo}-{hi}",
            (SIZE + 42, y),
            cv2.FONT_HERSHEY_SIMPLEX,
            0.42,
            (0, 0, 0),
            1,
        )
    cv2.putText(
        canvas, "o camera", (SIZE + 12, 30 + 36 * 5), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (0, 0, 0), 1
    )
    utc = at.astimezone(UTC)
    for i, text in enumerate((utc.strftime("%Y-%m-%d"), utc.strftime("%H:%M UTC"))):
        y = canvas.shape[0] - 36 + 18 * i
        cv2.putText(canvas, text, (SIZE + 12, y), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (0, 0, 0), 1)
    ok, buf = cv2.imencode(".png", canvas)
    assert ok
    return bytes(buf.tobytes())
