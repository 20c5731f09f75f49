"""The application factory."""

from __future__ import annotations

import asyncio
import contextlib
import gc
import logging
from collections.abc import AsyncIterator, Callable
from contextlib import asynccontextmanager
from datetime import timedelta
from functools import partial
from typing import Any

from fastapi import FastAPI
from fastapi_offline import FastAPIOffline

from app import __version__
from app.air import kind as air_kind
from app.air.router import router as air_router
from app.air.services import rolling
from app.air.services import webhook as alert_webhook
from app.air.services.map_cache import MapCache
from app.cells import kind as cells_kind
from app.cells.core import triangulation
from app.cells.router import router as cells_router
from app.platform import health, outbox, viewers, webhooks
from app.platform.auth import admin_token_hash, hash_token
from app.platform.db import schema
from app.platform.db.models import CameraKind
from app.platform.db.session import make_engine, make_read_engine, make_sessionmaker
from app.platform.frames import cameras, jpeg, kinds, rate_limit, retention, sources
from app.platform.frames import deps as frame_deps
from app.platform.frames.bounded_store import BoundedStore
from app.platform.frames.camera_info import TokenCache
from app.platform.frames.router import router as frames_router
from app.platform.frames.storage import StoreUnavailable
from app.platform.frames.stores import frame_store
from app.platform.frames.writer import GroupCommitWriter
from app.platform.http.compression import CompressedReads
from app.platform.http.cors import PublicReadCors
from app.platform.http.crowds import AnonymousLimit, Crowds
from app.platform.http.errors import database_unavailable, install_error_handlers
from app.platform.http.head import HeadAsGet
from app.platform.http.query import CheckedQuery
from app.platform.http.responses import DATABASE_UNAVAILABLE
from app.platform.http.security import SecurityHeaders, tile_source
from app.platform.http.uploads import BodyLimitMiddleware
from app.platform.observability import RequestIdMiddleware, configure_logging
from app.platform.settings import Settings, get_settings
from app.platform.state import AppState, state_of
from app.platform.timing import Timing
from app.solar import kind as solar_kind
from app.solar.router import router as solar_router
from app.solar.services import events as solar_events
from app.solar.services import metrics as solar_metrics
from app.web import router as pages

log = logging.getLogger("vantage")


async def _done_by(deadline: float, fn: Callable[[], object]) -> bool:
    """Run ``fn`` in a thread; True once it has returned (its exception raised here), False
    when the event loop's clock reaches ``deadline`` first: it is then left to end in the
    background, and what it raises is logged."""
    work = asyncio.ensure_future(asyncio.to_thread(fn))
    try:
        left = max(0.0, deadline - asyncio.get_running_loop().time())
        await asyncio.wait_for(asyncio.shield(work), left)
    except TimeoutError:
        work.add_done_callback(_log_failure)
        return False
    return True


def _log_failure(work: asyncio.Future[object]) -> None:
    if not work.cancelled() and (exc := work.exception()) is not None:
        log.error("start-up work left in the background failed: %s", exc, exc_info=exc)


SECURITY_SCHEMES: dict[str, Any] = {
    "bearer": {
        "type": "http",
        "scheme": "bearer",
        "description": "The admin token, a camera's (vc_…), a robot's (vr_…), a viewer's "
        "(vv_…, read-only) or the metrics token.",
    },
    "basic": {
        "type": "http",
        "scheme": "basic",
        "description": "Cameras only: the camera's id as the user name and its token as the "
        "password.",
    },
}


def with_security(app: FastAPI) -> Callable[[], dict[str, Any]]:
    """``app.openapi`` that also declares the service's two ways of authenticating (FastAPI's
    "Extending OpenAPI"), on every operation that may answer 401: ``/docs`` then has an
    Authorize button, and "Try it out" sends the token."""
    build = app.openapi

    def openapi() -> dict[str, Any]:
        schema = build()  # made once and cached by FastAPI; marked once here
        schema.setdefault("components", {}).setdefault("securitySchemes", SECURITY_SCHEMES)
        for name, path in schema.get("paths", {}).items():
            # HTTP Basic is a camera's, posting its frames; everything else takes Bearer
            ways: list[dict[str, list[str]]] = [{"bearer": []}]
            if name.endswith("/frames"):
                ways.append({"basic": []})
            for operation in path.values():
                if isinstance(operation, dict) and "401" in operation.get("responses", {}):
                    operation.setdefault("security", ways)
        return schema

    return openapi


def register_kinds() -> None:
    """Hand the ingest path each domain's handler of its camera kind (``kinds.KindHandler``)."""
    kinds.register(CameraKind.panel, solar_kind.HANDLER)
    kinds.register(CameraKind.sky, air_kind.HANDLER)
    kinds.register(CameraKind.rig, cells_kind.HANDLER)


def create_app(settings: Settings | None = None) -> FastAPI:
    """Build the service. The database schema must already be at the migrations' head."""
    settings = settings or get_settings()
    configure_logging(settings.log_level, settings.log_json)
    register_kinds()
    # the docs pages' scripts and styles served by the service itself, not from a CDN: the
    # networks of street cameras and robot cells are often closed to the internet, where
    # FastAPI's /docs was a blank page
    app = FastAPIOffline(
        title="Vantage",
        version=__version__,
        summary="Cameras as measuring instruments.",
        lifespan=lifespan,
        responses=DATABASE_UNAVAILABLE,
    )
    app.state = build_state(settings)
    install_error_handlers(app)
    app.openapi = with_security(app)  # type: ignore[method-assign]
    add_middleware(app, settings)
    for router in (
        frames_router,  # first: the frame upload is matched first
        health.router,
        solar_router,
        air_router,
        cells_router,
        viewers.router,
        pages.router,
    ):
        app.include_router(router)
    pages.mount_static(app)
    return app


def build_state(settings: Settings) -> AppState:
    """The service's long-lived parts: engines and sessions, the writer, the frame store, the
    token hashes and caches, the clock and its timing, the public lanes' limits."""
    state = AppState()
    state.settings = settings
    state.engine = make_engine(
        settings.effective_database_url,
        pool_size=settings.database_pool_size,
        max_overflow=settings.database_max_overflow,
        statement_timeout_s=settings.database_statement_timeout_seconds,
    )
    if jpeg.decoder_cap() != settings.max_pixels:
        log.warning(
            "OpenCV decodes at most %d pixels, the pixel limit is %d: set VANTAGE_MAX_PIXELS in "
            "the environment (OpenCV reads it once, at start)",
            jpeg.decoder_cap(),
            settings.max_pixels,
        )
    state.sessionmaker = make_sessionmaker(state.engine)
    # a connection per public lane's thread: the computations', and the cheap reads' (which
    # would otherwise wait for a map's session)
    state.read_engine = make_read_engine(
        settings.effective_database_url, 2 * settings.public_work_threads
    )
    state.read_sessionmaker = make_sessionmaker(state.read_engine or state.engine)
    # frame uploads decode in the writer's own threads, apart from the shared pool: with the
    # disk store about as many as there are cores (more only contend for them and the GIL)
    state.writer = GroupCommitWriter(
        state.sessionmaker, preparers=settings.effective_ingest_threads, check=cameras.refusals
    )
    state.admin_token_hash = admin_token_hash(settings)
    metrics = settings.metrics_token
    state.metrics_token_hash = None if metrics is None else hash_token(metrics.get_secret_value())
    state.camera_tokens = TokenCache(ttl=settings.camera_cache_seconds)
    # tokens of callers other than the admin and cameras: (role, owner id of a token hash)
    state.token_owners = (("robot", solar_kind.robot_of),)
    state.rate_budgets = rate_limit.LocalBudgets()
    state.timing = Timing(
        debounce=settings.cleaning_debounce, lease=timedelta(seconds=settings.lease_seconds)
    )
    state.frame_store = frame_store(settings)
    state.bounded_store = BoundedStore(
        state.frame_store, seconds=settings.frame_store_timeout_seconds
    )
    state.isopleth_cache = MapCache(ttl=settings.isopleth_cache_seconds)
    state.crowds = Crowds(
        requests_per_minute=settings.public_requests_per_minute,
        work_per_minute=settings.public_work_per_minute,
        queue=settings.public_work_queue,
    )
    secret = settings.alert_webhook_secret
    state.db_metrics = [solar_metrics.collect]
    state.webhook_key = None if secret is None else webhooks.signing_key(secret.get_secret_value())
    return state


def add_middleware(app: FastAPI, settings: Settings) -> None:
    """The middleware, innermost first: query checks, body limits, CORS for public reads,
    security headers, compression, HEAD, the anonymous limit, and the request log outermost."""
    app.add_middleware(CheckedQuery, service=app)
    app.add_middleware(
        BodyLimitMiddleware, body=settings.max_body_bytes, bulk=settings.max_upload_bytes
    )
    if settings.cors_origins:
        app.add_middleware(PublicReadCors, origins=settings.cors_origins)
    app.add_middleware(
        SecurityHeaders,
        docs_paths=[
            "/docs",
            "/redoc",
            app.swagger_ui_oauth2_redirect_url or "",
        ],  # FastAPIOffline's
        img_sources=[s for s in (tile_source(settings.map_tiles),) if s],
        frame_ancestors=settings.frame_ancestors,
    )
    app.add_middleware(CompressedReads)  # inside HEAD: a HEAD's Content-Length is its GET's
    app.add_middleware(HeadAsGet)  # inside the request log, which records HEAD as sent
    app.add_middleware(AnonymousLimit, crowds=state_of(app).crowds)
    app.add_middleware(RequestIdMiddleware)  # outermost: it logs the 413s too


@asynccontextmanager
async def lifespan(app: FastAPI) -> AsyncIterator[None]:
    """Start: the data directory and the schema checked, orphans swept, the writer and the
    background loops started. Stop: the loops cancelled, the writer drained, all closed."""
    state = state_of(app)
    log.info("vantage %s starting", __version__, extra={"database": state.engine.dialect.name})
    await prepare_storage(state)
    state.writer.start()
    if state.settings.warm_up_triangulation:
        # before serving, not in a thread beside requests: numba's compiler and FastAPI's
        # route building both swap the process-wide warning filters
        triangulation.warm_up()
    tasks = background_loops(state)
    # what start-up built lives as long as the process: frozen out of the cyclic
    # collector's way, so that a full collection does not walk it (a pause of the GIL).
    # Not collected first: a full collection costs a process that imported the
    # scientific stack ~0.3 s, for a little start-up garbage kept
    gc.freeze()
    yield
    gc.unfreeze()
    for task in tasks:
        task.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await task
    state.writer.stop(state.settings.frame_store_timeout_seconds)
    state.frame_store.close()
    state.engine.dispose()
    if state.read_engine is not None:
        state.read_engine.dispose()


async def prepare_storage(state: AppState) -> None:
    """The data directory made, the schema checked and the orphan files swept, each within
    ``frame_store_timeout_seconds``: the data directory (frames; by default the SQLite file
    too) on a network mount whose server is gone hangs, and waiting for it kept the process
    from ever serving, what needs only PostgreSQL included. Past the bound it serves
    meanwhile; /health says what is missing and requests that need it get 503."""
    settings = state.settings
    patience = settings.frame_store_timeout_seconds
    deadline = asyncio.get_running_loop().time() + patience
    made = partial(settings.data_dir.mkdir, mode=0o700, parents=True, exist_ok=True)
    if not await _done_by(deadline, made):
        log.error(
            "data directory %s not answering after %g s: serving meanwhile",
            settings.data_dir,
            patience,
        )
    try:
        await asyncio.to_thread(schema.check, state.engine)
    except schema.SchemaBehind as exc:
        log.error("not starting: %s", exc)
        raise
    except Exception as exc:
        if not database_unavailable(exc):
            raise
        log.error("schema not checked, database unreachable: %s", str(exc).splitlines()[0])
    # files a killed process wrote without committing their rows (only files too old to
    # be in flight: it may go on in the background once the bound is over)
    sweep = partial(
        retention.sweep_orphans,
        state.sessionmaker,
        state.frame_store,
        min_age_s=settings.orphan_min_age_seconds,
    )
    try:
        if not await _done_by(deadline, sweep):
            log.error(
                "orphan sweep still running after %g s (the frame store is slow or hung): "
                "serving meanwhile",
                patience,
            )
    except StoreUnavailable as exc:
        log.error("orphan sweep skipped, frame store unreachable: %s", exc)


def background_loops(state: AppState) -> list[asyncio.Task[None]]:
    """The loops that run beside requests: the retention sweep, the farm's events to its
    webhook, and, as configured, the air alerts' webhook, the cameras' sources and the
    rolling calibration of sky cameras from their stations."""
    settings = state.settings
    tasks = [
        asyncio.create_task(
            retention.run(
                state.sessionmaker,
                state.frame_store,
                state.timing,
                settings.frame_retention_days,
                settings.retention_sweep_seconds,
                settings.history_retention_days,
            )
        ),
        # the farm's events, to the receiver set through PUT /solar/webhook (none: kept)
        asyncio.create_task(
            outbox.run(
                state.sessionmaker, solar_events.TOPIC, state.timing, settings.alert_poll_seconds
            )
        ),
    ]
    if settings.pull_sources:
        tasks.append(asyncio.create_task(puller(state).run()))
    if settings.air_recalibrate_hours:
        tasks.append(
            asyncio.create_task(
                rolling.run(
                    state.sessionmaker,
                    state.timing,
                    hours=settings.air_recalibrate_hours,
                    days=settings.air_recalibrate_days,
                    max_km=settings.air_station_km,
                )
            )
        )
    if settings.alert_webhook_url:
        tasks.append(
            asyncio.create_task(
                alert_webhook.run(
                    state.sessionmaker,
                    settings.alert_webhook_url,
                    state.timing,
                    settings.alert_poll_seconds,
                    timedelta(hours=settings.alert_retry_hours),
                    key=state.webhook_key,
                )
            )
        )
        if settings.alert_webhook_secret is None:
            log.warning(
                "alerts are POSTed unsigned: set VANTAGE_ALERT_WEBHOOK_SECRET so that the"
                " receiver can tell them from forged ones"
            )
    return tasks


def puller(state: AppState) -> sources.Puller:
    """The loop that pulls the frames of cameras registered with a ``source``."""
    settings = state.settings
    return sources.Puller(
        state.sessionmaker,
        state.writer,
        lambda: state.frame_store if settings.store_frames else None,
        lambda: state.timing,
        threads=settings.pull_threads,
        timeout=settings.pull_timeout_seconds,
        max_pixels=settings.max_pixels,
        allowed_networks=settings.source_allowed_networks,
        rate_limit=lambda camera_id: frame_deps.within_rate(
            state.sessionmaker,
            state.rate_budgets,
            state.timing,
            settings.rate_limit_per_minute,
            camera_id,
        ),
    )
