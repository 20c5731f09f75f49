"""Liveness, readiness and metrics."""

from __future__ import annotations

import asyncio
import logging
import os
from collections.abc import Callable, Iterable, Iterator
from typing import Literal

from fastapi import APIRouter, Request, Response
from fastapi.concurrency import run_in_threadpool
from fastapi.responses import JSONResponse
from prometheus_client import CONTENT_TYPE_LATEST, CollectorRegistry, generate_latest, multiprocess
from prometheus_client.core import Metric
from prometheus_client.registry import Collector
from sqlalchemy import text
from sqlalchemy.exc import DBAPIError, SQLAlchemyError
from sqlalchemy.orm import Session, sessionmaker

from app import __version__
from app.platform.frames import retention
from app.platform.frames.storage import DiskFull, StoreUnavailable
from app.platform.http.deps import Admin, MetricsReader, get_sessionmaker
from app.platform.http.responses import AUTH_ERRORS
from app.platform.schemas import Health
from app.platform.state import app_state
from app.platform.timing import Timing

router = APIRouter(tags=["health"])
log = logging.getLogger("vantage.health")


@router.get("/health", response_model=Health, responses={503: {"model": Health}})
async def health(request: Request) -> JSONResponse:
    """Whether the service, its database and its frame store answer; the version.

    The two are checked at once: each waits up to its own bound when its server is gone (the
    database's connect timeout, ``VANTAGE_FRAME_STORE_TIMEOUT_SECONDS``), and one after the
    other a probe waited for the sum, with both on one hung mount (SQLite in the data
    directory) longer than a probe's timeout."""
    database, store = await asyncio.gather(
        run_in_threadpool(_database_state, request), _store_state(request)
    )
    ok = database == "ok" and store == "ok"
    body = Health(
        status="ok" if ok else "degraded",
        database=database,
        frame_store=store,
        version=__version__,
    )
    return JSONResponse(body.model_dump(), status_code=200 if ok else 503)


async def _store_state(request: Request) -> Literal["ok", "unreachable", "full"]:
    try:
        await app_state(request).bounded_store.check()
    except DiskFull as exc:
        log.warning("frame store full: %s", exc)
        return "full"
    except StoreUnavailable as exc:
        log.warning("frame store unreachable: %s", exc)
        return "unreachable"
    return "ok"


def _database_state(request: Request) -> Literal["ok", "unreachable", "read_only", "full"]:
    try:
        with get_sessionmaker(request)() as session:
            dialect = session.get_bind().dialect.name
            if dialect == "postgresql":
                # a standby (a failover left this address on one) or a server set read-only
                # answers SELECT 1 while every write fails
                read_only = session.execute(text("SHOW transaction_read_only")).scalar()
                if read_only == "on":
                    log.warning("database read-only: writes are refused")
                    return "read_only"
            else:
                session.execute(text("SELECT 1"))
    except SQLAlchemyError as exc:
        log.warning("database unreachable: %s", exc)
        return "unreachable"
    return _sqlite_writes(request) if dialect == "sqlite" else "ok"


def _sqlite_writes(request: Request) -> Literal["ok", "read_only", "full"]:
    """Whether a write commits on SQLite: the schema's version number written back unchanged
    (one page through the WAL). A SQLite file answers reads, and even begins its IMMEDIATE
    transactions (their lock lives in shared memory), on a filesystem the kernel has stopped
    writing to (ext4's errors=remount-ro after an I/O error), so only a write tells. Alembic
    keeps its revision in a table, not in ``user_version``, which nothing else reads."""
    try:
        with get_sessionmaker(request)() as session, session.begin():
            version = int(session.execute(text("PRAGMA user_version")).scalar_one())
            session.execute(text(f"PRAGMA user_version = {version}"))
    except SQLAlchemyError as exc:
        if isinstance(exc, DBAPIError) and "full" in str(exc.orig):  # SQLITE_FULL
            log.warning("database full: writes are refused: %s", exc)
            return "full"
        log.warning("database read-only: writes are refused: %s", exc)
        return "read_only"
    return "ok"


DbMetrics = Callable[[Session, Timing], Iterable[Metric]]
"""What a domain reads from the database for /metrics when scraped (``app.state.db_metrics``)."""


class _FromDatabase(Collector):
    def __init__(self, sessions: sessionmaker[Session], timing: Timing, sources: list[DbMetrics]):
        self.sessions, self.timing, self.sources = sessions, timing, sources

    def collect(self) -> Iterator[Metric]:
        with self.sessions() as session:
            for source in self.sources:
                yield from source(session, self.timing)


@router.get("/metrics", include_in_schema=False)
def metrics(request: Request, _: MetricsReader) -> Response:
    """Prometheus metrics (the metrics or the admin token): of this process, or summed over
    the workers that share its port (``PROMETHEUS_MULTIPROC_DIR``, set by ``python -m
    app.serve --workers N``); then what the domains read from the database (one reading for
    all processes)."""
    if "PROMETHEUS_MULTIPROC_DIR" not in os.environ:
        body = generate_latest()
    else:
        registry = CollectorRegistry()
        multiprocess.MultiProcessCollector(registry)  # type: ignore[no-untyped-call]
        body = generate_latest(registry)
    sources: list[DbMetrics] = getattr(request.app.state, "db_metrics", [])
    if sources:
        shared = CollectorRegistry()
        shared.register(
            _FromDatabase(get_sessionmaker(request), app_state(request).timing, sources)
        )
        body += generate_latest(shared)
    return Response(body, media_type=CONTENT_TYPE_LATEST)


@router.post("/admin/retention/sweep", tags=["admin"], responses=AUTH_ERRORS)
def sweep_now(request: Request, _: Admin) -> dict[str, int]:
    """Run the frame-retention sweep now (it also runs on its own, hourly)."""
    settings = app_state(request).settings
    swept = retention.sweep(
        app_state(request).sessionmaker,
        app_state(request).frame_store,
        app_state(request).timing,
        settings.frame_retention_days,
        settings.history_retention_days,
    )
    return {"frames": swept.frames, "files": swept.files, "images": swept.images}
