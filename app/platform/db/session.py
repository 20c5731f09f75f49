"""Engine and session factory."""

from __future__ import annotations

import contextlib
import os
from pathlib import Path
from typing import Any

from sqlalchemy import Engine, create_engine, event, make_url
from sqlalchemy.engine import ExceptionContext
from sqlalchemy.orm import Session, sessionmaker

from app.platform.db.rows import READ_ONLY_SQL_TRANSACTION, send_pending_first

PG_STATEMENT_TIMEOUT_S = 30.0
"""How long a statement may run or wait for a lock on PostgreSQL (``statement_timeout``)."""
PG_CONNECT_TIMEOUT_S = 5
"""How long a new connection to PostgreSQL may take, its handshake included."""
PG_POOL_TIMEOUT_S = 10
"""How long a request waits for one of the pool's connections before its 503."""
PG_TCP_USER_TIMEOUT_MS = 15_000
"""How long sent data may go unacknowledged before the connection is dropped."""


def private_sqlite_file(url: str) -> None:
    """Create a SQLite database file (and its folder) readable by this user only, 0600 (0700)
    when it does not exist yet: SQLite would make it 0644, and it holds every token's hash
    and the sources' credentials. Its WAL and shared-memory files take the file's mode."""
    parsed = make_url(url)
    if parsed.get_backend_name() != "sqlite" or parsed.database in (None, "", ":memory:"):
        return
    path = Path(parsed.database)
    path.parent.mkdir(mode=0o700, parents=True, exist_ok=True)
    with contextlib.suppress(FileExistsError):
        os.close(os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600))


def make_engine(
    url: str,
    *,
    pool_size: int = 10,
    max_overflow: int = 20,
    statement_timeout_s: float = PG_STATEMENT_TIMEOUT_S,
) -> Engine:
    """An engine tuned for the backend: WAL and a busy timeout on SQLite, a pool on PostgreSQL
    of ``pool_size`` connections kept and ``max_overflow`` more under load, whose statements
    may take ``statement_timeout_s`` at most (0: no bound)."""
    private_sqlite_file(url)
    engine = _engine(url, pool_size, max_overflow, statement_timeout_s)
    send_pending_first(engine)  # app.platform.db.rows.deferred_inserts
    return engine


def _engine(url: str, pool_size: int, max_overflow: int, statement_timeout_s: float) -> Engine:
    if url.startswith("sqlite"):
        # One connection per process: requests queue for it in Python (fair, no polling) rather
        # than in SQLite's busy handler, whose sleeps grow to 100 ms under contention. Every use
        # of a session is short and never nested, so the queue only ever waits on real work.
        engine = _sqlite(url, connections=1)

        @event.listens_for(engine, "connect")
        def _sqlite_pragmas(dbapi_conn: Any, _record: Any) -> None:
            # let SQLAlchemy, not the driver, open transactions (see _begin_immediate)
            dbapi_conn.isolation_level = None
            cur = dbapi_conn.cursor()
            _wal(cur)
            cur.execute("PRAGMA synchronous=NORMAL")
            cur.execute("PRAGMA foreign_keys=ON")
            cur.close()

        @event.listens_for(engine, "begin")
        def _begin_immediate(conn: Any) -> None:
            # A deferred transaction that reads and then writes fails at once with SQLITE_BUSY
            # when another writer committed in between; taking the write lock up front makes
            # concurrent requests wait for each other (busy timeout) instead.
            conn.exec_driver_sql("BEGIN IMMEDIATE")

        return engine
    engine = create_engine(
        url,
        pool_size=pool_size,
        max_overflow=max_overflow,
        pool_pre_ping=True,
        pool_timeout=PG_POOL_TIMEOUT_S,
        connect_args=_pg_timeouts(url, statement_timeout_s),
    )

    @event.listens_for(engine, "handle_error")
    def _read_only_server(ctx: ExceptionContext) -> None:
        # A write refused as read-only (25006): the server this pool reached is no primary
        # now (a failover left it a standby, its address now the new primary's), or an
        # operator has set it read-only. Taken as a connection lost, the pool's connections
        # are replaced, so that writes reach the primary as soon as its address does, and
        # the request gets a 503 to retry rather than a 500.
        if getattr(ctx.original_exception, "sqlstate", None) == READ_ONLY_SQL_TRANSACTION:
            ctx.is_disconnect = True

    return engine


def _pg_timeouts(url: str, statement_timeout_s: float = PG_STATEMENT_TIMEOUT_S) -> dict[str, Any]:
    """libpq's bounds on waiting for a server that cannot be reached (a failover moving its
    address, a network partition): without them a new connection waits psycopg's default of
    130 s, and a query sent to a server that vanished waits for the kernel's retransmissions
    (~15 minutes), each holding a worker thread, so that requests hang instead of getting
    their 503. And the server's own bound on a statement, ``statement_timeout``: a server
    that answers but whose tables are locked (``VACUUM FULL``, an ``ALTER TABLE``, a
    migration waiting for its lock, which queues every reader behind it) held every request
    on them for as long, with ``/health`` "ok". The database URL's own parameters
    (``?connect_timeout=…``, ``?options=…``) take precedence."""
    ours: dict[str, Any] = {
        "connect_timeout": PG_CONNECT_TIMEOUT_S,
        "tcp_user_timeout": PG_TCP_USER_TIMEOUT_MS,
        "keepalives": 1,
        "keepalives_idle": 30,
        "keepalives_interval": 10,
        "keepalives_count": 3,
    }
    if statement_timeout_s > 0:
        ours["options"] = f"-c statement_timeout={round(statement_timeout_s * 1000)}"
    given = make_url(url).query
    return {k: v for k, v in ours.items() if k not in given}


def make_read_engine(url: str, connections: int) -> Engine | None:
    """On SQLite, an engine for long public reads (a month of readings summed, a city's map):
    connections of their own that begin deferred transactions and may not write. The main
    engine's one connection begins every transaction ``IMMEDIATE``, taking the write lock: a
    read of seconds there held every upload's commit back for as long (in WAL mode a reader
    blocks no writer). None elsewhere: PostgreSQL readers block no writer either."""
    if not url.startswith("sqlite"):
        return None
    engine = _sqlite(url, connections)

    @event.listens_for(engine, "connect")
    def _read_only(dbapi_conn: Any, _record: Any) -> None:
        dbapi_conn.isolation_level = None
        cur = dbapi_conn.cursor()
        _wal(cur)  # when this is the first connection to the file: WAL lets readers be
        cur.execute("PRAGMA query_only=ON")
        cur.close()

    @event.listens_for(engine, "begin")
    def _begin_deferred(conn: Any) -> None:
        conn.exec_driver_sql("BEGIN")  # a snapshot of the database; no lock on the writers

    return engine


def _sqlite(url: str, connections: int) -> Engine:
    """A SQLite engine of ``connections`` connections, shared across threads; a request
    waits for one in Python (up to 60 s) rather than in SQLite's busy handler."""
    return create_engine(
        url,
        connect_args={"timeout": 30, "check_same_thread": False},
        pool_size=connections,
        max_overflow=0,
        pool_timeout=60,
    )


def _wal(cur: Any) -> None:
    """WAL mode, kept by the database file once set. Set only when not yet: setting it again
    waits for every other connection's open transaction to end (a public read of seconds on
    the read engine, see ``make_read_engine``)."""
    if cur.execute("PRAGMA journal_mode").fetchone()[0].lower() != "wal":
        cur.execute("PRAGMA journal_mode=WAL")


def make_sessionmaker(engine: Engine) -> sessionmaker[Session]:
    return sessionmaker(engine, expire_on_commit=False)


def release(session: Session) -> None:
    """End the session's transaction, which has written nothing, and give its connection back
    to the pool, before work that needs no database: a slow upload, decoding images, a frame
    store that may hang. The session's next statement begins a new transaction. With SQLite
    the pool is the one connection every request shares (the uploads' writer too), so holding
    it held the whole service: a GET /cameras waited 5.5 s behind a robot uploading its laser
    images at 500 kB/s. Objects read so far stay usable, detached, with what they loaded."""
    if session.new or session.dirty or session.deleted:
        raise RuntimeError("release() would drop changes not yet flushed")
    session.close()
