"""When things happen: the clock, and the cleaning queue's two rules of time (after how many
dirty verdicts a task opens, how long a robot's claim lasts), read from the settings once."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from datetime import datetime, timedelta

from app.platform.db.base import utcnow


@dataclass(frozen=True, slots=True)
class Timing:
    """The service's clock and the cleaning queue's timing rules, handed to every service."""

    debounce: int = 3
    """Consecutive dirty verdicts that open a cleaning task."""
    lease: timedelta = timedelta(minutes=10)
    """How long a claimed task stays with its robot."""
    clock: Callable[[], datetime] = field(default=utcnow)
    """Now, in UTC; tests substitute a controllable clock."""

    def now(self) -> datetime:
        """Now, in UTC (the clock's)."""
        return self.clock()
