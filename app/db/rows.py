"""Inserting new ORM objects with Core statements: the hot ingest path skips the unit of work."""

from __future__ import annotations

from functools import cache
from typing import Any

from sqlalchemy import Insert, insert, inspect
from sqlalchemy.orm import Session

from app.db.base import Base


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


def insert_rows(session: Session, *objs: Base) -> None:
    """INSERT each new object's rows (joined-inheritance tables included), in order.

    The objects stay transient: read their attributes, do not expect relationships to load.
    Only the attributes that were set are inserted, so column defaults apply as for the ORM.
    """
    connection = session.connection()
    for obj in objs:
        values: dict[str, Any] = obj.__dict__
        for statement, pairs in _plan(type(obj)):
            row = {col: values[attr] for col, attr in pairs if attr in values}
            connection.execute(statement, row)
