"""Operational parameters the services need from the settings, and the clock."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from datetime import datetime, timedelta

from app.platform.db.base import utcnow


@dataclass(frozen=True, slots=True)
class Policy:
    debounce: int = 3
    """Consecutive dirty verdicts that open a cleaning task."""
    lease: timedelta = timedelta(minutes=10)
    """How long a claimed task stays with its robot."""
    clock: Callable[[], datetime] = field(default=utcnow)
    """Now, in UTC; tests substitute a controllable clock."""

    def now(self) -> datetime:
        return self.clock()
