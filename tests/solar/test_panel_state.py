"""The panel state machine, transition by transition, and the debounce."""

from __future__ import annotations

from dataclasses import replace
from datetime import UTC, datetime, timedelta

import pytest

from app.solar.core.panel_state import (
    PanelFacts,
    PanelState,
    TaskAction,
    TaskPhase,
    on_verdict,
    state_of,
    task_phase,
)

K = 3
CLEAN = PanelFacts(
    has_model=True, has_baseline=True, dirty_streak=0, last_clean=True, ineffective=False, task=None
)


def run(facts: PanelFacts, verdicts: list[bool]) -> tuple[PanelFacts, list[TaskAction]]:
    """Feed verdicts; an opened task becomes pending, a closed one disappears."""
    actions = []
    for clean in verdicts:
        t = on_verdict(facts, clean, debounce=K)
        task = facts.task
        if t.action is TaskAction.open:
            task = TaskPhase.pending
        elif t.action is not TaskAction.none:
            task = None
        facts = replace(
            facts,
            dirty_streak=t.dirty_streak,
            last_clean=t.last_clean,
            ineffective=t.ineffective,
            task=task,
        )
        actions.append(t.action)
    return facts, actions


class TestStates:
    def test_no_model(self) -> None:
        facts = PanelFacts(False, False, 0, None, False, None)
        assert state_of(facts, debounce=K) is PanelState.no_baseline

    def test_fleet_only_before_first_verdict_is_unknown(self) -> None:
        facts = PanelFacts(True, False, 0, None, False, None)
        assert state_of(facts, debounce=K) is PanelState.unknown

    def test_baseline_just_trained_is_clean(self) -> None:
        facts = PanelFacts(True, True, 0, None, False, None)
        assert state_of(facts, debounce=K) is PanelState.clean

    @pytest.mark.parametrize(
        ("phase", "state"),
        [
            (TaskPhase.pending, PanelState.needs_cleaning),
            (TaskPhase.claimed, PanelState.cleaning),
            (TaskPhase.completed, PanelState.cleaning),
        ],
    )
    def test_open_task_decides(self, phase: TaskPhase, state: PanelState) -> None:
        assert state_of(replace(CLEAN, task=phase), debounce=K) is state


class TestDebounce:
    def test_task_opens_on_the_kth_dirty_verdict_only(self) -> None:
        facts, actions = run(CLEAN, [False, False])
        assert actions == [TaskAction.none, TaskAction.none]
        assert state_of(facts, debounce=K) is PanelState.clean  # one glare frame sends no robot
        facts, actions = run(facts, [False])
        assert actions == [TaskAction.open]
        assert state_of(facts, debounce=K) is PanelState.needs_cleaning

    def test_a_clean_verdict_resets_the_count(self) -> None:
        facts, actions = run(CLEAN, [False, False, True, False, False])
        assert TaskAction.open not in actions
        assert facts.dirty_streak == 2

    def test_never_a_second_task(self) -> None:
        _, actions = run(CLEAN, [False] * 10)
        assert actions.count(TaskAction.open) == 1

    def test_pending_task_cancelled_when_panel_comes_clean(self) -> None:
        facts, actions = run(CLEAN, [False, False, False, True])
        assert actions[-1] is TaskAction.cancel
        assert state_of(facts, debounce=K) is PanelState.clean

    @pytest.mark.parametrize("k", [0, -1])
    def test_debounce_must_be_positive(self, k: int) -> None:
        with pytest.raises(ValueError, match="debounce"):
            on_verdict(CLEAN, False, debounce=k)


class TestCleaning:
    def test_claimed_task_ignores_frames(self) -> None:
        facts = replace(CLEAN, dirty_streak=3, last_clean=False, task=TaskPhase.claimed)
        for clean in (True, False):
            t = on_verdict(facts, clean, debounce=K)
            assert t.action is TaskAction.none
            assert t.dirty_streak == 3

    def test_completed_then_clean_is_effective(self) -> None:
        facts = replace(CLEAN, dirty_streak=3, last_clean=False, task=TaskPhase.completed)
        assert state_of(facts, debounce=K) is PanelState.cleaning
        after, actions = run(facts, [True])
        assert actions == [TaskAction.close_effective]
        assert state_of(after, debounce=K) is PanelState.clean
        assert not after.ineffective

    def test_completed_then_dirty_is_ineffective_and_a_new_task_follows_the_debounce(self) -> None:
        facts = replace(CLEAN, dirty_streak=3, last_clean=False, task=TaskPhase.completed)
        after, actions = run(facts, [False])
        assert actions == [TaskAction.close_ineffective]
        assert after.ineffective
        assert state_of(after, debounce=K) is PanelState.needs_cleaning
        after, actions = run(after, [False])
        assert actions == [TaskAction.none]
        after, actions = run(after, [False])
        assert actions == [TaskAction.open]

    def test_failed_task_reopens_on_the_next_dirty_verdict(self) -> None:
        # a failed task closes; the panel keeps its count and is still dirty
        facts = replace(CLEAN, dirty_streak=3, last_clean=False, task=None)
        assert state_of(facts, debounce=K) is PanelState.needs_cleaning
        _, actions = run(facts, [False])
        assert actions == [TaskAction.open]


def test_expired_lease_counts_as_pending() -> None:
    now = datetime(2026, 6, 1, 12, tzinfo=UTC)
    assert task_phase("claimed", now + timedelta(seconds=1), now) is TaskPhase.claimed
    assert task_phase("claimed", now, now) is TaskPhase.pending
    assert task_phase("completed", None, now) is TaskPhase.completed
    assert task_phase("closed", None, now) is None
