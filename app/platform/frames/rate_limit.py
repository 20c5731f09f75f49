"""A per-camera frame limit that holds across processes without a query per frame.

Each minute (on the clock) a camera may post ``limit`` frames, counted over every process. A
process reserves the budget in blocks: one ``INSERT … ON CONFLICT DO UPDATE … RETURNING`` on
the camera's row of ``rate_budgets`` adds a block of ``limit / 20`` frames (at least 1) to what
the processes have reserved this minute, and grants the part that is still under the limit.
It then spends the block locally, with no database round trip, and asks again when the block
runs out. Reserved frames a process does not use are lost with the minute: the limit is never
exceeded, and a camera spread over many processes may be refused a few frames early (at most
a block per process).
"""

from __future__ import annotations

import threading
from datetime import datetime

from sqlalchemy import case
from sqlalchemy.dialects import postgresql, sqlite
from sqlalchemy.orm import Session

from app.platform.db.models import RateBudget

BLOCKS_PER_MINUTE = 20
"""The budget is reserved in blocks of ``limit / BLOCKS_PER_MINUTE`` frames (at least 1)."""


def block_size(limit: int) -> int:
    return max(1, limit // BLOCKS_PER_MINUTE)


def minute_of(now: datetime) -> datetime:
    return now.replace(second=0, microsecond=0)


class LocalBudgets:
    """This process's unspent reservations: camera → (minute, frames left)."""

    def __init__(self) -> None:
        self._left: dict[str, tuple[datetime, int]] = {}
        self._lock = threading.Lock()

    def take(self, camera_id: str, minute: datetime) -> bool:
        """Spend one reserved frame of ``minute``; False when none is left."""
        with self._lock:
            window, left = self._left.get(camera_id, (minute, 0))
            if window != minute or left <= 0:
                return False
            self._left[camera_id] = (window, left - 1)
            return True

    def keep(self, camera_id: str, minute: datetime, frames: int) -> None:
        """Keep ``frames`` more reserved frames of ``minute`` for later requests."""
        with self._lock:
            if len(self._left) > 100_000:  # cameras come and go: drop stale minutes
                self._left = {c: v for c, v in self._left.items() if v[0] == minute}
            self._left[camera_id] = (minute, frames)


def reserve(session: Session, camera_id: str, minute: datetime, limit: int) -> int:
    """Reserve a block of the camera's budget for ``minute``; how many frames were granted, 0
    when the minute's budget is spent. In the session's transaction, which the caller commits
    before spending the block (the upload's own short transaction, ``frames.deps``)."""
    block = block_size(limit)
    table = RateBudget.__table__
    dialect = postgresql if session.get_bind().dialect.name == "postgresql" else sqlite
    stmt = dialect.insert(table).values(camera_id=camera_id, window_start=minute, used=block)
    stmt = stmt.on_conflict_do_update(
        index_elements=[table.c.camera_id],
        set_={
            "used": case((table.c.window_start == minute, table.c.used + block), else_=block),
            "window_start": minute,
        },
    ).returning(table.c.used)
    used = int(session.execute(stmt).scalar_one())
    return max(0, min(block, limit - (used - block)))
