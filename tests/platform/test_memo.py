"""The cache of values made from rows that never change."""

from __future__ import annotations

from app.platform.memo import ById


def test_a_value_is_made_once_and_the_least_recent_goes_first() -> None:
    made: list[str] = []
    cache: ById[str] = ById(limit=2)

    def make(key: str) -> str:
        made.append(key)
        return key.upper()

    assert cache.get("a", lambda: make("a")) == "A"
    assert cache.get("a", lambda: make("a")) == "A"
    assert cache.get("b", lambda: make("b")) == "B"
    assert cache.get("a", lambda: make("a")) == "A"  # a is now the most recent
    assert cache.get("c", lambda: make("c")) == "C"  # b goes
    assert cache.get("a", lambda: make("a")) == "A"
    assert cache.get("b", lambda: make("b")) == "B"  # made again
    assert made == ["a", "b", "c", "b"]
