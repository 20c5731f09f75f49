"""The panel state machine and the cleaning debounce, as pure functions.

::

                   baseline trained
    no_baseline ─────────────────────► clean ◄──────────────────────────┐
                                        │  ▲                              │ next usable
                     k dirty verdicts   │  │ clean verdict                │ verdict clean
                     in a row: task     ▼  │ (task cancelled)             │ (effective)
                                    needs_cleaning ──── robot claims ──► cleaning
                                        ▲                                 │ complete,
                                        └──── still dirty (ineffective) ──┘ next verdict

``unknown``: no baseline of its own, judged by the fleet model, no usable verdict yet.

A panel's public state is derived from a few stored facts (its debounce counter, its last
usable verdict, whether the last cleaning worked) and its open task, so that a robot claiming or
completing a task changes only the task row.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass
from datetime import datetime


class PanelState(enum.StrEnum):
    no_baseline = "no_baseline"
    unknown = "unknown"
    clean = "clean"
    needs_cleaning = "needs_cleaning"
    cleaning = "cleaning"


class TaskPhase(enum.StrEnum):
    """An open task as the panel sees it (an expired lease counts as pending again)."""

    pending = "pending"
    claimed = "claimed"
    completed = "completed"


@dataclass(frozen=True, slots=True)
class PanelFacts:
    has_model: bool
    """The panel has a baseline, or a fleet model exists to judge it."""
    has_baseline: bool
    dirty_streak: int
    last_clean: bool | None
    ineffective: bool
    task: TaskPhase | None


def task_phase(status: str, lease_expires_at: datetime | None, now: datetime) -> TaskPhase | None:
    """The phase of an open task at ``now``; None for a closed one."""
    if status == "pending":
        return TaskPhase.pending
    if status == "claimed":
        expired = lease_expires_at is None or lease_expires_at <= now
        return TaskPhase.pending if expired else TaskPhase.claimed
    if status == "completed":
        return TaskPhase.completed
    return None


def state_of(facts: PanelFacts, *, debounce: int) -> PanelState:
    """The public state derived from the stored facts."""
    if facts.task is TaskPhase.pending:
        return PanelState.needs_cleaning
    if facts.task in (TaskPhase.claimed, TaskPhase.completed):
        return PanelState.cleaning
    if not facts.has_model:
        return PanelState.no_baseline
    if facts.last_clean is None:
        return PanelState.clean if facts.has_baseline else PanelState.unknown
    if not facts.last_clean and (facts.ineffective or facts.dirty_streak >= debounce):
        return PanelState.needs_cleaning
    return PanelState.clean


class TaskAction(enum.StrEnum):
    none = "none"
    open = "open"
    cancel = "cancel"
    """Close the pending task: the panel came clean on its own (rain, wind)."""
    close_effective = "close_effective"
    close_ineffective = "close_ineffective"


@dataclass(frozen=True, slots=True)
class Transition:
    dirty_streak: int
    last_clean: bool | None
    ineffective: bool
    action: TaskAction


def on_verdict(facts: PanelFacts, clean: bool, *, debounce: int) -> Transition:
    """What one usable verdict does to the panel and its task.

    - no task: a clean verdict resets the counter; a dirty one counts, and the ``debounce``-th
      dirty verdict in a row opens a task (one glare-struck frame does not send a robot);
    - pending task: a clean verdict cancels it; a dirty one counts on;
    - claimed task: the robot is at work, frames show the brushes, not the panel: ignored;
    - completed task: the verdict confirms the cleaning (clean: effective) or not (dirty:
      ineffective, flagged, and the counter restarts at 1, so a new task opens after the
      debounce).
    """
    if debounce < 1:
        raise ValueError(f"debounce must be ≥ 1; got {debounce}")
    streak, ineffective = facts.dirty_streak, facts.ineffective
    if facts.task is TaskPhase.claimed:
        return Transition(streak, facts.last_clean, ineffective, TaskAction.none)
    if facts.task is TaskPhase.completed:
        if clean:
            return Transition(0, True, False, TaskAction.close_effective)
        return Transition(1, False, True, TaskAction.close_ineffective)
    if clean:
        action = TaskAction.cancel if facts.task is TaskPhase.pending else TaskAction.none
        return Transition(0, True, False, action)
    streak += 1
    if facts.task is None and streak >= debounce:
        return Transition(streak, False, ineffective, TaskAction.open)
    return Transition(streak, False, ineffective, TaskAction.none)
