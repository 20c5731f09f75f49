"""The pages people look at: the landing page, the city map, the screen below a sky camera,
the solar farm board and the robot-cell tools.

Server-side templates (Jinja2) give each page its frame and settings; the page's own script
reads the service's public or admin JSON API, as any client does. The browser libraries
(Leaflet, Chart.js) are npm packages pinned by ``package.json`` and its lock file, installed
by ``npm ci`` into ``node_modules`` and served from there (no CDN at run time)."""

from __future__ import annotations

from datetime import datetime
from pathlib import Path
from typing import Any

from fastapi import APIRouter, FastAPI, Request
from fastapi.responses import HTMLResponse
from fastapi.staticfiles import StaticFiles
from fastapi.templating import Jinja2Templates
from pydantic import TypeAdapter, ValidationError
from starlette.concurrency import run_in_threadpool

from app.air.core import airquality, isopleths
from app.air.services import cameras, readings
from app.air.services.map_picture import COLOURS
from app.platform.http.deps import UtcTime, get_sessionmaker
from app.platform.http.errors import NotFound, Unprocessable
from app.platform.state import app_state

HERE = Path(__file__).resolve().parent


def node_modules() -> Path:
    """Where ``npm ci`` installed the packages: beside the checkout's ``package.json`` (an
    editable install), else in the working directory (the image's /srv/vantage)."""
    beside = HERE.parents[1] / "node_modules"
    return beside if beside.is_dir() else Path.cwd() / "node_modules"


VENDOR = {"leaflet": "leaflet/dist", "chart.js": "chart.js/dist"}
"""The npm packages the pages load, and the folder of each that is served."""

templates = Jinja2Templates(directory=HERE / "templates")
router = APIRouter(include_in_schema=False)
_MOMENT: TypeAdapter[datetime] = TypeAdapter(UtcTime)


def mount_static(app: FastAPI) -> None:
    """Serve the pages' own files (``/static``) and the npm packages (``/static/vendor/…``)."""
    modules = node_modules()
    for name, folder in VENDOR.items():
        app.mount(
            f"/static/vendor/{name}",
            StaticFiles(directory=modules / folder, check_dir=False),
            name=name,
        )
    app.mount("/static", StaticFiles(directory=HERE / "static"), name="static")


def _categories() -> list[dict[str, Any]]:
    """The categories best first, with their levels and colours (as the PNG map draws them)."""
    return [
        {"name": name, "lo": lo, "hi": hi, "colour": COLOURS[name]}
        for name, lo, hi in reversed(isopleths.BANDS)
    ]


def _page(request: Request, name: str, status: int = 200, **context: Any) -> HTMLResponse:
    config = {"categories": _categories(), **context.pop("config", {})}
    return templates.TemplateResponse(
        request,
        name,
        {"config": config, **context},
        status_code=status,
        headers={"Cache-Control": "no-cache"},
    )


@router.get("/", response_class=HTMLResponse)
def landing(request: Request) -> HTMLResponse:
    """What the service is, and where to go."""
    return _page(request, "index.html", title="Vantage")


@router.get("/map", response_class=HTMLResponse)
def city_map(request: Request) -> HTMLResponse:
    """The city map: isopleth bands over a base map, every sky camera labelled."""
    settings = app_state(request).settings
    config = {"tiles": settings.map_tiles, "attribution": settings.map_attribution}
    return _page(request, "map.html", title="Air quality map", config=config)


@router.get("/display/{camera_id}", response_class=HTMLResponse)
async def display(request: Request, camera_id: str, at: str | None = None) -> HTMLResponse:
    """The screen below a sky camera (ch. 6): today's category for people passing by; with
    ``at`` (RFC 3339, within the history kept), the screen as it was then. An unknown camera
    is a page that says so (404), a moment the service cannot show one too (422)."""
    if at is not None:
        try:
            moment = _MOMENT.validate_python(at)
            state = app_state(request)
            readings.check_moment(moment, state.timing.now(), readings.kept_days_of(state.settings))
        except (ValidationError, Unprocessable) as exc:
            why = exc.detail if isinstance(exc, Unprocessable) else "it is not an RFC 3339 time"
            return _page(
                request, "missing.html", status=422, title="No such moment", message=f"at: {why}"
            )

    def find() -> str | None:
        with get_sessionmaker(request)() as session:
            try:
                camera = cameras.sky_camera(session, camera_id)
            except NotFound:
                return None
            return camera.name or camera.id

    name = await run_in_threadpool(find)
    if name is None:
        return _page(
            request,
            "missing.html",
            status=404,
            title="No such camera",
            message=f"There is no sky camera {camera_id!r}.",
        )
    config = {"camera_id": camera_id, "name": name, "fresh_hours": _fresh_hours(), "at": at}
    return _page(request, "display.html", title=f"Air quality — {name}", config=config)


def _fresh_hours() -> float:
    return airquality.FRESH.total_seconds() / 3600


@router.get("/farm", response_class=HTMLResponse)
def farm(request: Request) -> HTMLResponse:
    """The solar farm board (its data needs the admin token, given in the page)."""
    return _page(request, "farm.html", title="Solar farm")


@router.get("/cells", response_class=HTMLResponse)
def cells(request: Request) -> HTMLResponse:
    """Calibrations and the outline tool of the robot cells (admin token, given in the page)."""
    return _page(request, "cells.html", title="Robot cells")
