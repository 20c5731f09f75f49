"""The isopleth map as a picture (matplotlib's Agg, no pyplot: figures are objects of the
request, not of a global state machine shared between threads).

One panel per island (``isopleths.Island``), each in its own longitude and latitude at one
scale in metres (aspect 1/cos φ), with smooth filled bands, the cameras labelled with their
names and levels, a scale bar and a legend with units; cells with no camera within the mask
distance are left blank, and the legend says so. Colours: ColorBrewer's RdYlBu, 5 classes,
marked colour-blind safe by its authors (Brewer, colorbrewer2.org)."""

from __future__ import annotations

import io
import math
from collections.abc import Sequence
from datetime import UTC, datetime
from typing import Any, Literal

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.patches import Patch
from matplotlib.patheffects import withStroke
from mpl_toolkits.axes_grid1.anchored_artists import AnchoredSizeBar

from app.air.core import airquality, isopleths
from app.air.services.maps import Monitor, Station

COLOURS = {
    "Very Poor": "#d7191c",
    "Poor": "#fdae61",
    "Fair": "#ffffbf",
    "Good": "#abd9e9",
    "Very Good": "#2c7bb6",
}
"""Fill of each category (ColorBrewer RdYlBu, 5 classes)."""
NO_DATA = "#e6e6e6"
MAX_PANELS = 4
"""Islands drawn at most; the rest are named in the title's note."""
PANEL_INCHES = 5.0
DPI = 110
KM_PER_DEGREE = math.radians(1) * isopleths.EARTH_RADIUS / 1000


def _nice(length_km: float) -> float:
    """A round length near ``length_km``: 1, 2 or 5 × 10ⁿ km."""
    if length_km <= 0:
        return 1.0
    p = 10.0 ** math.floor(math.log10(length_km))
    return float(next(m * p for m in (5, 2, 1) if m * p <= length_km))


def _km(km: float) -> str:
    return f"{km:g} km" if km >= 1 else f"{km * 1000:g} m"


def figure(
    islands: Sequence[isopleths.Island],
    stations: Sequence[Station],
    at: datetime,
    *,
    layer: Literal["levels", "uncertainty"] = "levels",
    max_distance: float = 5000.0,
    empty_reason: str | None = None,
    monitors: Sequence[Monitor] = (),
) -> Figure:
    """The map as a matplotlib Figure: a panel per island (the ``MAX_PANELS`` with the most
    cameras), a shared legend, the time it is of. Without islands, a figure that says why
    (``empty_reason``)."""
    shown = sorted(islands, key=lambda i: -len(i.cameras))[:MAX_PANELS]
    n = max(len(shown), 1)
    fig = Figure(figsize=(PANEL_INCHES * n + 2.2, PANEL_INCHES), dpi=DPI, layout="constrained")
    FigureCanvasAgg(fig)
    when = at.astimezone(UTC).strftime("%Y-%m-%d %H:%M UTC")
    title = f"Air quality {when}" if layer == "levels" else f"Uncertainty of the map {when}"
    if len(islands) > len(shown):
        title += f" — {len(islands) - len(shown)} more islands not drawn: ask with a bbox"
    fig.suptitle(title)
    if not shown:
        ax = fig.add_subplot()
        ax.set_axis_off()
        ax.text(
            0.5, 0.5, f"No map: {empty_reason or 'no readings'}", ha="center", va="center",
            wrap=True, fontsize=12, transform=ax.transAxes,
        )  # fmt: skip
        return fig
    kinds = {i.field.uncertainty_kind for i in shown}
    handles: list[Patch] = []
    axes = fig.subplots(1, n, squeeze=False)[0]
    for ax, island in zip(axes, shown, strict=True):
        handles = _panel(ax, island, stations, monitors, layer)
    if layer == "levels":
        label = "Category (level 1–10)"
    elif kinds == {"kriging_sd"}:
        label = "Kriging sd [level]"
    else:
        label = "Distance to nearest camera"
    handles.append(
        Patch(
            facecolor=NO_DATA,
            edgecolor="grey",
            label=f"no data: no camera within {_km(max_distance / 1000)}",
        )
    )
    handles.append(Patch(facecolor="black", edgecolor="white", label="camera: name (level)"))
    fig.legend(handles=handles, title=label, loc="outside right center", fontsize=8)
    return fig


def _markers(
    ax: Any, island: isopleths.Island, stations: Sequence[Station], monitors: Sequence[Monitor]
) -> None:
    """The island's cameras (dots, with name and level) and reference stations (squares,
    with name and PM2.5) on ``ax``."""
    halo = [withStroke(linewidth=3, foreground="white")]
    for k in island.cameras.tolist():
        if k >= len(stations):
            m = monitors[k - len(stations)]
            ax.plot(m.lon, m.lat, "s", ms=7, mfc="white", mec="black", mew=1.5)
            ax.annotate(
                f"{m.name or m.station_id} ({m.pm25:.0f} µg/m³)", (m.lon, m.lat),
                xytext=(5, -10), textcoords="offset points", fontsize=8, path_effects=halo,
                parse_math=False,  # a name is text: "$…$" in it is no formula
            )  # fmt: skip
            continue
        s = stations[k]
        ax.plot(s.lon, s.lat, "o", ms=6, mfc="black", mec="white", mew=1.5)
        name = s.name or s.camera_id
        ax.annotate(
            f"{name} ({airquality.rounded(s.level)})", (s.lon, s.lat), xytext=(5, 5),
            textcoords="offset points", fontsize=8, path_effects=halo, parse_math=False,
        )  # fmt: skip


def _panel(
    ax: object,
    island: isopleths.Island,
    stations: Sequence[Station],
    monitors: Sequence[Monitor],
    layer: str,
) -> list[Patch]:
    """One island's bands, cameras (dots), reference stations (squares) and scale bar on
    ``ax``; the legend's entries."""
    from matplotlib.axes import Axes

    assert isinstance(ax, Axes)
    f = island.field
    x0, y0, x1, y1 = island.bbox
    mid = math.radians((y0 + y1) / 2)
    ax.set_facecolor(NO_DATA)
    handles: list[Patch] = []
    if layer == "levels":
        colours = [COLOURS[name] for name, _, _ in isopleths.BANDS]
        z = np.ma.masked_invalid(f.value)
        if z.count():
            ax.contourf(f.lon, f.lat, z, levels=list(isopleths.BAND_EDGES), colors=colours)
        handles = [
            Patch(facecolor=COLOURS[name], edgecolor="grey", label=f"{name} {lo}–{hi}")
            for name, lo, hi in reversed(isopleths.BANDS)
        ]
    else:
        edges = isopleths.uncertainty_edges(f)
        u = np.ma.masked_invalid(isopleths.uncertainty_of(f))
        metres = f.uncertainty_kind == "nearest_camera_m"
        scale = 1000.0 if metres else 1.0
        cmap = "viridis_r"
        if u.count():
            ax.contourf(f.lon, f.lat, u / scale, levels=[e / scale for e in edges], cmap=cmap)
        from matplotlib import colormaps

        ramp = colormaps[cmap](np.linspace(0, 1, len(edges) - 1))
        unit = " km" if metres else ""
        handles = [
            Patch(
                facecolor=ramp[i],
                edgecolor="grey",
                label=(
                    f"{edges[i] / scale:g}–{edges[i + 1] / scale:g}{unit}"
                    if i + 2 < len(edges)
                    else f"≥ {edges[i] / scale:g}{unit}"
                ),
            )
            for i in range(len(edges) - 1)
        ]
    _markers(ax, island, stations, monitors)
    ax.set_xlim(x0, x1)
    ax.set_ylim(y0, y1)
    ax.set_aspect(1 / math.cos(mid))  # one metre east-west as long as one north-south
    ax.set_xlabel("longitude [°E]")
    ax.set_ylabel("latitude [°N]")
    ax.tick_params(labelsize=7)
    width_km = (x1 - x0) * KM_PER_DEGREE * math.cos(mid)
    bar_km = _nice(width_km / 4)
    ax.add_artist(
        AnchoredSizeBar(
            ax.transData, bar_km / (KM_PER_DEGREE * math.cos(mid)), _km(bar_km),
            "lower left", pad=0.4, frameon=True, size_vertical=0,
        )
    )  # fmt: skip
    return handles


def png(fig: Figure) -> bytes:
    """A figure (``figure``) as PNG bytes."""
    out = io.BytesIO()
    fig.savefig(out, format="png")
    return out.getvalue()
