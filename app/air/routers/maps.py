"""The city's map (public): category bands as GeoJSON or PNG."""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from functools import partial
from typing import Annotated, Any, Literal

from fastapi import APIRouter, Depends, Query, Request
from fastapi.responses import Response
from sqlalchemy.orm import Session

from app.air.core import isopleths
from app.air.services import maps, readings
from app.air.services.map_cache import MapCache
from app.air.services.maps import MapQuery
from app.platform.http.compression import accepts_gzip
from app.platform.http.crowds import Crowds
from app.platform.http.deps import (
    SettingsDep,
    TimingDep,
    UtcTime,
    get_principal,
    public_work,
)
from app.platform.http.errors import (
    Unprocessable,
)
from app.platform.http.responses import (
    UNPROCESSABLE,
    not_modified,
)
from app.platform.state import app_state

router = APIRouter(prefix="/air", tags=["air quality"])


def _bbox(value: str | None) -> tuple[float, float, float, float] | None:
    if value is None:
        return None
    try:
        parts = tuple(float(v) for v in value.split(","))
        isopleths.check_bbox(parts)
    except isopleths.IsoplethError as exc:
        raise Unprocessable(str(exc)) from None
    except ValueError:
        raise Unprocessable("bbox must be minlon,minlat,maxlon,maxlat") from None
    x0, y0, x1, y1 = parts
    return x0, y0, x1, y1


Method = Annotated[Literal["idw", "kriging", "rbf"], Query(description="Interpolation.")]


Bbox = Annotated[str | None, Query(description="minlon,minlat,maxlon,maxlat [°].")]


Window = Annotated[int, Query(ge=60, le=30 * 86400, description="Readings of the last … [s].")]


Resolution = Annotated[int, Query(ge=8, le=512, description="Grid cells per side.")]


MaxDistance = Annotated[
    float,
    Query(
        gt=0, le=200_000, description="Leave cells farther than this from every camera empty [m]."
    ),
]


At = Annotated[
    UtcTime | None,
    Query(
        description="The map as it was at this time (RFC 3339): each camera's latest reading "
        "in the window before it. Default: now."
    ),
]


Layer = Annotated[
    Literal["levels", "uncertainty"],
    Query(
        description="levels: the category bands; uncertainty: how far to trust them, as bands "
        "of kriging's standard deviation [level] (method=kriging) or of the distance to the "
        "nearest camera [m] (idw, rbf)."
    ),
]


ANONYMOUS_RESOLUTION = 256
"""The finest map an anonymous caller may ask for: the grid is what a map's CPU grows with
(kriging at 512 cells a side took ~7.6 s, at 256 a quarter of that); a token lifts it to 512."""


ANONYMOUS_WINDOW = 86_400
"""The longest window of readings an anonymous map may gather [s] (a day; a past moment is
``at``): the readings' query grows with it; a token lifts it to 30 days."""


def _map_query(
    request: Request,
    timing: TimingDep,
    settings: SettingsDep,
    bbox: Bbox = None,
    window: Window = 3600,
    method: Method = "idw",
    resolution: Resolution = 128,
    max_distance: MaxDistance = 5000.0,
    at: At = None,
    layer: Layer = "levels",
) -> MapQuery:
    """The map's parameters. For an anonymous caller, the resolution and window bounded
    (``ANONYMOUS_RESOLUTION``, ``ANONYMOUS_WINDOW``; 422 past them; max_distance, which costs
    little, keeps its own bound) and the parameters rounded so that nearby
    requests share the cache: the bbox outward to 0.01°, ``at`` down to the minute, the
    window to the minute, max_distance to 100 m, the resolution to a multiple of 16. A
    token given must be valid (401)."""
    box = _bbox(bbox)
    if at is not None:  # within the history kept (422 otherwise)
        readings.check_moment(at, timing.now(), readings.kept_days_of(settings))
    crowds: Crowds = app_state(request).crowds
    anonymous = crowds.anonymous(request.scope)
    if anonymous and request.headers.get("authorization"):
        get_principal(request)  # a token given must be valid (401)
        anonymous = False
    if anonymous:
        if resolution > ANONYMOUS_RESOLUTION:
            raise Unprocessable(
                f"resolution: at most {ANONYMOUS_RESOLUTION} without a token; got {resolution}"
            )
        if window > ANONYMOUS_WINDOW:
            raise Unprocessable(
                f"window: at most {ANONYMOUS_WINDOW} s without a token; got {window}"
            )
        if box is not None:
            box = (
                max(-180.0, math.floor(box[0] * 100) / 100),
                max(-90.0, math.floor(box[1] * 100) / 100),
                min(180.0, math.ceil(box[2] * 100) / 100),
                min(90.0, math.ceil(box[3] * 100) / 100),
            )
        at = at.replace(second=0, microsecond=0) if at is not None else None
        window = max(60, round(window / 60) * 60)
        max_distance = max(100.0, round(max_distance / 100) * 100.0)
        resolution = max(16, round(resolution / 16) * 16)
    return MapQuery(box, window, method, resolution, max_distance, at, layer)


MapQueryDep = Annotated[MapQuery, Depends(_map_query)]


async def _cached_map(
    request: Request,
    key: tuple[object, ...],
    compute: Callable[[Session], bytes],
    media_type: str,
    *,
    compress: bool = False,
) -> Response:
    """The map for ``key``, computed at most once per ``VANTAGE_ISOPLETH_CACHE_SECONDS`` (as
    ``public_work``, one at a time; a kept map waits for none); 304 when the client's
    ``If-None-Match`` names it. With ``compress``, kept gzipped too, and sent so to clients
    that take it (compressed once, not at every poll)."""
    cache: MapCache = app_state(request).isopleth_cache
    kept = cache.kept(key)
    if kept is None:
        kept = await public_work(
            request, lambda session: cache.get(key, partial(compute, session), compress=compress)
        )
    headers = {"ETag": kept.etag, "Cache-Control": f"public, max-age={int(cache.ttl)}"}
    # Vary as the 200 would carry it (app.platform.http.compression adds it to a body sent as it is)
    varies = {"Vary": "Accept-Encoding"} if kept.gzipped is not None else {}
    if not_modified(request.headers.get("if-none-match"), kept.etag):
        return Response(status_code=304, headers={**headers, **varies})
    if kept.gzipped is not None and accepts_gzip(request.headers):
        # app.platform.http.compression passes a body already encoded as it is
        encoded = {**headers, **varies, "Content-Encoding": "gzip"}
        return Response(kept.gzipped, media_type=media_type, headers=encoded)
    return Response(kept.body, media_type=media_type, headers=headers)


MAP_RESPONSES: dict[int | str, dict[str, Any]] = {
    **UNPROCESSABLE,
    304: {"description": "Not modified: the map named by If-None-Match is current."},
}


@router.get(
    "/isopleths",
    response_class=Response,
    responses={**MAP_RESPONSES, 200: {"content": {"application/geo+json": {}}}},
)
async def isopleths_geojson(request: Request, timing: TimingDep, q: MapQueryDep) -> Response:
    """City-wide category bands (RFC 7946 GeoJSON), one feature per category present: now,
    or as they were at ``at`` (``at`` in the answer says which).

    Kept for ``VANTAGE_ISOPLETH_CACHE_SECONDS`` (30): ``computed_at`` says when it was made,
    and its ETag answers ``If-None-Match`` with 304."""

    def compute(session: Session) -> bytes:
        m = maps.field(session, timing, q)
        off_map = maps.unplaced(session, since=m.since, until=m.at)
        body = maps.geojson(m, off_map, timing.now(), q)
        return json.dumps(body, ensure_ascii=False, allow_nan=False, separators=(",", ":")).encode()

    return await _cached_map(
        request, ("geojson", q), compute, "application/geo+json", compress=True
    )


@router.get(
    "/isopleths.png",
    response_class=Response,
    responses={**MAP_RESPONSES, 200: {"content": {"image/png": {}}}},
)
async def isopleths_png(request: Request, timing: TimingDep, q: MapQueryDep) -> Response:
    """The map drawn (matplotlib): a panel per island with its bands, the cameras labelled
    with name and level, coordinates, a scale bar, a legend with units and what blank means;
    without readings, why not. Kept as the GeoJSON is."""
    from app.air.services.map_picture import figure, png

    def compute(session: Session) -> bytes:
        m = maps.field(session, timing, q)
        off_map = maps.unplaced(session, since=m.since, until=m.at)
        return png(
            figure(
                m.islands,
                m.stations,
                m.at,
                layer=q.layer,
                max_distance=q.max_distance,
                empty_reason=maps.empty_reason(m, off_map, q.window),
                monitors=m.monitors,
            )
        )

    return await _cached_map(request, ("png", q), compute, "image/png")
