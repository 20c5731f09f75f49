"""Inserting new ORM objects with Core statements: the hot ingest path skips the unit of work.

Inside ``deferred_inserts`` (the group-commit writer's batches) the INSERTs are held back and
sent together per table and column set: at the batch's end, or as soon as anything else is
executed on the connection, so every statement still sees the rows inserted before it. On
PostgreSQL several rows go as one ``COPY … FROM STDIN``: one statement on the server instead of
a parse, bind and execute per row, and psycopg formats the rows in C. Elsewhere (and for a
single row) they go as one executemany.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from functools import cache
from typing import TYPE_CHECKING, Any, cast

from sqlalchemy import Connection, Dialect, Engine, Insert, event, insert, inspect
from sqlalchemy.exc import DBAPIError
from sqlalchemy.orm import Session
from sqlalchemy.sql.type_api import _BindProcessorType

from app.db.base import Base

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
        copy = connection.dialect.name == "postgresql" and connection.dialect.driver == "psycopg"
        for statement, by_columns in rows.items():
            for columns, batch in by_columns.items():
                plan = _copy_plan(statement, columns, connection.dialect) if copy else None
                if plan is not None and len(batch) > 1:
                    _copy(connection, plan, batch)
                else:
                    connection.execute(statement, batch)


@dataclass(frozen=True, slots=True)
class _CopyPlan:
    sql: str
    processors: tuple[_BindProcessorType[Any] | None, ...]
    """Each column's bind processor (its SQLAlchemy type's conversion), in order."""


@cache
def _copy_plan(statement: Insert, columns: tuple[str, ...], dialect: Dialect) -> _CopyPlan | None:
    """The COPY for rows of ``statement``'s table with these columns, or None when COPY would
    not give them what INSERT does: a column left out has a default computed in Python (COPY
    applies only the database's own)."""
    table = statement.table
    if any(c.key not in columns and c.default is not None for c in table.columns):
        return None
    preparer = dialect.identifier_preparer
    sql = (
        f"COPY {preparer.format_table(table)} "
        f"({', '.join(preparer.quote(c) for c in columns)}) FROM STDIN"
    )
    return _CopyPlan(sql, tuple(table.c[c].type._cached_bind_processor(dialect) for c in columns))


def _copy(connection: Connection, plan: _CopyPlan, rows: list[dict[str, Any]]) -> None:
    """The rows in one COPY, their values converted by the columns' types as an INSERT would.

    A failure (a unique violation) raises SQLAlchemy's exception for it, as ``execute`` does.
    """
    dbapi = cast("psycopg.Connection[Any]", connection.connection.dbapi_connection)
    try:
        with dbapi.cursor() as cursor, cursor.copy(plan.sql) as copy:
            for row in rows:
                values = zip(row.values(), plan.processors, strict=True)
                copy.write_row([v if p is None else p(v) for v, p in values])
    except connection.dialect.loaded_dbapi.Error as exc:
        raise DBAPIError.instance(
            plan.sql, None, exc, connection.dialect.loaded_dbapi.Error, dialect=connection.dialect
        ) from exc


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
