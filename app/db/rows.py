"""Inserting new ORM objects with Core statements: the hot ingest path skips the unit of work."""

from __future__ import annotations

from typing import Any

from sqlalchemy import insert, inspect
from sqlalchemy.orm import Mapper, Session

from app.db.base import Base


def _values(obj: Base, mapper: Mapper[Any]) -> dict[Any, list[dict[str, Any]]]:
    state = inspect(obj)
    out: dict[Any, list[dict[str, Any]]] = {}
    for table in mapper.tables:  # base table first, then the joined subclass tables
        row: dict[str, Any] = {}
        for column in table.columns:
            prop = mapper.get_property_by_column(column)
            if prop.key in state.dict:
                row[column.key] = state.dict[prop.key]
        out[table] = [row]
    return out


def insert_rows(session: Session, *objs: Base) -> None:
    """INSERT each new object's rows (joined-inheritance tables included), in order.

    The objects stay transient: read their attributes, do not expect relationships to load.
    Column defaults (``created_at``) apply as for the ORM.
    """
    for obj in objs:
        mapper = inspect(type(obj))
        for table, rows in _values(obj, mapper).items():
            session.execute(insert(table), rows)
