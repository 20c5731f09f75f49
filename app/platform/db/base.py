"""Declarative base with a constraint naming convention and a UTC timestamp type."""

from __future__ import annotations

from datetime import UTC, datetime
from typing import Any

from sqlalchemy import BigInteger, DateTime, MetaData
from sqlalchemy.engine import Dialect
from sqlalchemy.ext.compiler import compiles
from sqlalchemy.orm import DeclarativeBase
from sqlalchemy.sql.functions import FunctionElement
from sqlalchemy.types import TypeDecorator

NAMING_CONVENTION = {
    "ix": "ix_%(column_0_label)s",
    "uq": "uq_%(table_name)s_%(column_0_N_name)s",
    "ck": "ck_%(table_name)s_%(constraint_name)s",
    "fk": "fk_%(table_name)s_%(column_0_name)s_%(referred_table_name)s",
    "pk": "pk_%(table_name)s",
}


class UTCDateTime(TypeDecorator[datetime]):
    """A timezone-aware UTC datetime on every backend.

    SQLite has no time zones: values are stored as naive UTC and come back aware.
    """

    impl = DateTime(timezone=True)
    cache_ok = True

    def process_bind_param(self, value: datetime | None, dialect: Dialect) -> datetime | None:
        if value is None:
            return None
        if value.tzinfo is None:
            raise ValueError("naive datetime: Vantage stores UTC-aware times only")
        value = value.astimezone(UTC)
        return value.replace(tzinfo=None) if dialect.name == "sqlite" else value

    def process_result_value(self, value: Any, dialect: Dialect) -> datetime | None:
        if value is None:
            return None
        assert isinstance(value, datetime)
        return value.replace(tzinfo=UTC) if value.tzinfo is None else value.astimezone(UTC)


def utcnow() -> datetime:
    return datetime.now(UTC)


class Base(DeclarativeBase):
    metadata = MetaData(naming_convention=NAMING_CONVENTION)


class time_slot(FunctionElement[int]):  # noqa: N801  (a SQL function's name)
    """The index of the ``seconds``-long slot a UTC time falls in, its clock shifted by
    ``offset`` seconds (a time zone's UTC offset: its local hours and days):
    floor((epoch + offset) / seconds), computed by the database (SQLite and PostgreSQL)."""

    type = BigInteger()
    inherit_cache = True


@compiles(time_slot, "sqlite")
def _time_slot_sqlite(element: time_slot, compiler: Any, **kw: Any) -> str:
    column, seconds, offset = list(element.clauses)
    # stored as naive UTC text: strftime('%s') reads it as UTC; integer division floors (≥ 1970)
    return (
        f"((CAST(strftime('%s', {compiler.process(column, **kw)}) AS INTEGER)"
        f" + {compiler.process(offset, **kw)}) / {compiler.process(seconds, **kw)})"
    )


@compiles(time_slot)
def _time_slot_default(element: time_slot, compiler: Any, **kw: Any) -> str:
    column, seconds, offset = list(element.clauses)
    return (
        f"CAST(floor((extract(epoch from {compiler.process(column, **kw)})"
        f" + {compiler.process(offset, **kw)}) / {compiler.process(seconds, **kw)}) AS BIGINT)"
    )
