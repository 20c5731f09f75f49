"""Looking a row up by its id, as every endpoint that names one does: the row, or a 404 that
says what was not found."""

from __future__ import annotations

from typing import TypeVar

from sqlalchemy.orm import Session

from app.platform.db.base import Base
from app.platform.http.errors import NotFound

R = TypeVar("R", bound=Base)


def get_or_404(session: Session, model: type[R], key: str, what: str, *, lock: bool = False) -> R:
    """The ``model`` row whose primary key is ``key``; NotFound ("no {what} 'key'") when
    there is none. ``lock``: read it ``FOR UPDATE`` for this transaction (PostgreSQL; SQLite
    has one writer anyway)."""
    row = session.get(model, key, with_for_update=True if lock else None)
    if row is None:
        raise NotFound(f"no {what} {key!r}")
    return row
