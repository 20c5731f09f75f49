"""Inserting new ORM objects with Core statements: the hot ingest path skips the unit of work.

Inside ``deferred_inserts`` (the group-commit writer's batches) the INSERTs are held back and
sent together per table and column set: at the batch's end, or as soon as anything else is
executed on the connection, so every statement still sees the rows inserted before it. On
PostgreSQL several rows go as one ``COPY … FROM STDIN``: one statement on the server instead of
a parse, bind and execute per row, and psycopg formats the rows in C. On SQLite they go as one
multi-row ``INSERT … VALUES (…), (…)``: one statement step per table instead of one per row.
The sqlite3 module releases the GIL around every step, and under load the writer then waits
to get it back: fewer steps, fewer waits. Elsewhere (and for a single row) they go as one
executemany.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from functools import cache
from typing import TYPE_CHECKING, Any, cast

from sqlalchemy import Connection, Dialect, Engine, Insert, event, insert, inspect
from sqlalchemy.exc import DBAPIError
from sqlalchemy.orm import Session
from sqlalchemy.sql.type_api import _BindProcessorType

from app.platform.db.base import Base

READ_ONLY_SQL_TRANSACTION = "25006"
"""PostgreSQL's sqlstate of a write (or a row lock) refused by a read-only server or
transaction."""

if TYPE_CHECKING:
    import psycopg

_PENDING = "vantage.pending_inserts"


@cache
def _plan(cls: type[Base]) -> tuple[tuple[Insert, tuple[tuple[str, str], ...]], ...]:
    """Per mapped class: for each of its tables (base first), the INSERT and its
    (column key, attribute key) pairs."""
    mapper = inspect(cls)
    plan = []
    for table in mapper.tables:
        pairs = tuple(
            (column.key, mapper.get_property_by_column(column).key) for column in table.columns
        )
        plan.append((insert(table), pairs))
    return tuple(plan)


class _Pending:
    """Rows waiting to be inserted: per statement (in the order first used), per column set.

    Sending the tables in the order they were first used keeps foreign keys satisfied: a row
    refers only to rows its own job inserted before it, so the table it refers to was used first.
    """

    def __init__(self) -> None:
        self._rows: dict[Insert, dict[tuple[str, ...], list[dict[str, Any]]]] = {}

    def add(self, statement: Insert, row: dict[str, Any]) -> None:
        by_columns = self._rows.setdefault(statement, {})
        by_columns.setdefault(tuple(row), []).append(row)

    def send(self, connection: Connection) -> None:
        rows, self._rows = self._rows, {}  # emptied first: these executes come back here
        dialect = connection.dialect
        bulk = _bulk_sender(dialect)
        for statement, by_columns in rows.items():
            for columns, batch in by_columns.items():
                plan = _bulk_plan(statement, columns, dialect) if len(batch) > 1 else None
                if bulk is None or plan is None:
                    connection.execute(statement, batch)
                else:
                    bulk(connection, plan, batch)


@dataclass(frozen=True, slots=True)
class _BulkPlan:
    sql: str
    """PostgreSQL: the COPY statement; SQLite: the INSERT up to its VALUES."""
    processors: tuple[_BindProcessorType[Any] | None, ...]
    """Each column's bind processor (its SQLAlchemy type's conversion), in order."""


@cache
def _bulk_plan(statement: Insert, columns: tuple[str, ...], dialect: Dialect) -> _BulkPlan | None:
    """The COPY (PostgreSQL) or multi-row INSERT (SQLite) for rows of ``statement``'s table with
    these columns, or None when it would not give them what SQLAlchemy's INSERT does: a column
    left out has a default computed in Python (the database applies only its own)."""
    table = statement.table
    if any(c.key not in columns and c.default is not None for c in table.columns):
        return None
    preparer = dialect.identifier_preparer
    names = ", ".join(preparer.quote(c) for c in columns)
    processors = tuple(table.c[c].type._cached_bind_processor(dialect) for c in columns)
    if dialect.name == "postgresql":
        return _BulkPlan(f"COPY {preparer.format_table(table)} ({names}) FROM STDIN", processors)
    return _BulkPlan(f"INSERT INTO {preparer.format_table(table)} ({names}) VALUES ", processors)


def _converted(plan: _BulkPlan, row: dict[str, Any]) -> list[Any]:
    """A row's values, in the plan's column order, as the columns' types bind them."""
    values = zip(row.values(), plan.processors, strict=True)
    return [v if p is None else p(v) for v, p in values]


def _copy(connection: Connection, plan: _BulkPlan, rows: list[dict[str, Any]]) -> None:
    """The rows in one COPY, their values converted by the columns' types as an INSERT would.

    A failure (a unique violation) raises SQLAlchemy's exception for it, as ``execute`` does.
    """
    dbapi = cast("psycopg.Connection[Any]", connection.connection.dbapi_connection)
    with _as_sqlalchemy_error(connection, plan.sql):
        with dbapi.cursor() as cursor, cursor.copy(plan.sql) as copy:
            for row in rows:
                copy.write_row(_converted(plan, row))


SQLITE_MAX_VARIABLES = 999
"""The bound parameters a statement may have in SQLite before 3.32 (32,766 since)."""


def _values(connection: Connection, plan: _BulkPlan, rows: list[dict[str, Any]]) -> None:
    """The rows as one INSERT … VALUES (…), (…) (SQLite), as few as the parameter limit allows.

    A failure (a unique violation) raises SQLAlchemy's exception for it, as ``execute`` does.
    """
    per_statement = max(1, SQLITE_MAX_VARIABLES // len(plan.processors))
    row = "(" + ", ".join("?" * len(plan.processors)) + ")"
    cursor = connection.connection.dbapi_connection.cursor()  # type: ignore[union-attr]
    try:
        for start in range(0, len(rows), per_statement):
            chunk = rows[start : start + per_statement]
            sql = plan.sql + ", ".join([row] * len(chunk))
            params = [v for row in chunk for v in _converted(plan, row)]
            with _as_sqlalchemy_error(connection, sql):
                cursor.execute(sql, params)
    finally:
        cursor.close()


@contextmanager
def _as_sqlalchemy_error(connection: Connection, sql: str) -> Iterator[None]:
    """The driver's errors raised as SQLAlchemy's (``IntegrityError`` …), as ``execute`` does;
    a statement refused as read-only (PostgreSQL's 25006: a standby after a failover) as a
    connection lost, as the engine's ``handle_error`` takes it for statements it runs
    (``app.platform.db.session``), so that the request gets 503 and the pool new connections."""
    dbapi_error = connection.dialect.loaded_dbapi.Error
    try:
        yield
    except dbapi_error as exc:
        lost = getattr(exc, "sqlstate", None) == READ_ONLY_SQL_TRANSACTION
        if lost:
            connection.invalidate(exc)
        raise DBAPIError.instance(
            sql, None, exc, dbapi_error, connection_invalidated=lost, dialect=connection.dialect
        ) from exc


def select_rows(session: Session, sql: str, params: Sequence[Any]) -> list[tuple[Any, ...]]:
    """A plain SELECT sent through the driver itself, on the session's connection (its held
    inserts first), placeholders written ``?``. For a query the writer makes in every batch,
    where SQLAlchemy's statement building costs ten times the query itself."""
    connection = session.connection()
    if connection.dialect.paramstyle != "qmark":
        sql = sql.replace("?", "%s")
    pending: _Pending | None = connection.info.get(_PENDING)
    if pending is not None:
        pending.send(connection)
    cursor = connection.connection.dbapi_connection.cursor()  # type: ignore[union-attr]
    try:
        with _as_sqlalchemy_error(connection, sql):
            cursor.execute(sql, list(params))
            return [tuple(row) for row in cursor.fetchall()]
    finally:
        cursor.close()


def _bulk_sender(
    dialect: Dialect,
) -> Callable[[Connection, _BulkPlan, list[dict[str, Any]]], None] | None:
    """How several rows of one table and column set are sent on this dialect and driver."""
    if dialect.name == "postgresql" and dialect.driver == "psycopg":
        return _copy
    if dialect.name == "sqlite" and dialect.driver == "pysqlite":
        return _values
    return None


def insert_rows(session: Session, *objs: Base) -> None:
    """INSERT each new object's rows (joined-inheritance tables included), in order.

    The objects stay transient: read their attributes, do not expect relationships to load.
    Only the attributes that were set are inserted, so column defaults apply as for the ORM.
    """
    connection = session.connection()
    pending: _Pending | None = connection.info.get(_PENDING)
    for obj in objs:
        values: dict[str, Any] = obj.__dict__
        for statement, pairs in _plan(type(obj)):
            row = {col: values[attr] for col, attr in pairs if attr in values}
            if pending is not None:
                pending.add(statement, row)
            else:
                connection.execute(statement, row)


@contextmanager
def deferred_inserts(session: Session) -> Iterator[None]:
    """Within the block, ``insert_rows`` collects rows and sends them together (before any
    other statement on the session's connection, and at the block's end)."""
    connection = session.connection()
    pending = _Pending()
    info = connection.info  # kept: a connection lost meanwhile refuses to give it again
    info[_PENDING] = pending
    try:
        yield
        pending.send(connection)
    finally:
        info.pop(_PENDING, None)


def send_pending_first(engine: Engine) -> None:
    """Make every statement on ``engine`` send the held-back inserts of its connection first."""

    @event.listens_for(engine, "before_execute")
    def _send_pending(connection: Connection, *_: Any) -> None:
        pending: _Pending | None = connection.info.get(_PENDING)
        if pending is not None:
            pending.send(connection)
