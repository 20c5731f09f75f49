"""What the application builds once at start and every request reads: ``app.state``, typed.

``create_app`` fills an ``AppState``; handlers and dependencies read it through
``app_state(request)``, so that a misspelt attribute or a wrong type is mypy's error, not a
500 at the first request that takes that path.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING, Any, Literal

from starlette.datastructures import State
from starlette.requests import HTTPConnection

if TYPE_CHECKING:
    from sqlalchemy import Engine, orm
    from sqlalchemy.orm import Session

    from app.platform.frames.bounded_store import BoundedStore
    from app.platform.frames.camera_info import TokenCache
    from app.platform.frames.rate_limit import LocalBudgets
    from app.platform.frames.storage import FrameStore
    from app.platform.frames.writer import GroupCommitWriter
    from app.platform.health import DbMetrics
    from app.platform.http.crowds import Crowds
    from app.platform.settings import Settings
    from app.platform.timing import Timing

TokenOwner = tuple[Literal["robot"], "Callable[[Session, str], str | None]"]
"""A role the domains add (``"robot"``) and how to find the id that owns a token's hash."""


class AppState(State):
    """The service's long-lived parts, made by ``create_app``."""

    settings: Settings
    engine: Engine
    read_engine: Engine | None
    """SQLite: the public lanes' own connections (``make_read_engine``); None elsewhere."""
    sessionmaker: orm.sessionmaker[Session]
    read_sessionmaker: orm.sessionmaker[Session]
    """Sessions of the public lanes' reads (SQLite: their own connections)."""
    writer: GroupCommitWriter
    frame_store: FrameStore
    bounded_store: BoundedStore
    """The frame store with every call bounded in time (a hung mount is a 503)."""
    timing: Timing
    admin_token_hash: str
    metrics_token_hash: str | None
    camera_tokens: TokenCache
    token_owners: tuple[TokenOwner, ...]
    rate_budgets: LocalBudgets
    crowds: Crowds
    webhook_key: bytes | None
    """The air alerts' signing key (``VANTAGE_ALERT_WEBHOOK_SECRET``), None: unsigned."""
    db_metrics: list[DbMetrics]
    isopleth_cache: Any
    """The air room's map cache (``app.air.services.map_cache.MapCache``): the platform does
    not name a room's types."""


def state_of(app: Any) -> AppState:
    """The state of ``app`` (a FastAPI application made by ``create_app``)."""
    state = app.state
    assert isinstance(state, AppState), "the app was not made by create_app"
    return state


def app_state(conn: HTTPConnection) -> AppState:
    """The state of the application serving ``conn``."""
    return state_of(conn.app)
