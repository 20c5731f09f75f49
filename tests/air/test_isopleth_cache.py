"""The isopleth map cache: kept for its period, bounded in entries and bytes."""

from __future__ import annotations

import gzip
import re

from app.air.services.map_cache import MapCache


def test_kept_for_its_period_then_computed_again() -> None:
    now = [0.0]
    calls: list[str] = []
    cache = MapCache(ttl=30.0, clock=lambda: now[0])

    def compute(body: bytes) -> bytes:
        calls.append(body.decode())
        return body

    a1 = cache.get("k", lambda: compute(b"a"))
    now[0] = 29.9
    a2 = cache.get("k", lambda: compute(b"b"))
    assert a1 == a2
    assert calls == ["a"]
    now[0] = 30.0
    b, etag, zipped = cache.get("k", lambda: compute(b"b"))
    assert (b, calls) == (b"b", ["a", "b"])
    assert etag != a1[1]
    assert re.fullmatch(r'W/"[0-9a-f]{32}"', etag)  # weak: the body may go gzipped
    assert zipped is None  # not asked for


def test_a_map_is_kept_gzipped_when_asked_and_counted_so() -> None:
    """Compressed once when computed, not at every poll; its bytes count against the cap."""
    body = b'{"type":"FeatureCollection","features":[' + b'{"a":1},' * 200 + b"]}"
    zipped = len(gzip.compress(body, 6, mtime=0))
    # room for two bodies and one gzipped copy: two maps fit only if the copies were not counted
    cache = MapCache(ttl=30.0, max_bytes=2 * len(body) + zipped, clock=lambda: 0.0)
    kept = cache.get("k", lambda: body, compress=True)
    assert kept.gzipped is not None
    assert gzip.decompress(kept.gzipped) == body
    assert len(kept.gzipped) == zipped < len(body) / 10
    assert cache.kept("k") is kept  # served as it is, not compressed again
    assert cache.get("small", lambda: b"{}", compress=True).gzipped is None  # under 1 KiB
    cache.get("k2", lambda: body, compress=True)
    assert cache.kept("k") is None
    assert cache.kept("k2") is not None


def test_bounded_in_entries_and_in_bytes() -> None:
    cache = MapCache(ttl=60.0, max_entries=3, max_bytes=100, clock=lambda: 0.0)
    calls: list[int] = []

    def body(i: int, size: int) -> bytes:
        calls.append(i)
        return bytes(size)

    for i in range(4):  # the oldest of four goes
        cache.get(i, lambda i=i: body(i, 10))
    cache.get(0, lambda: body(0, 10))
    assert calls == [0, 1, 2, 3, 0]
    cache.get(9, lambda: body(9, 90))  # 90 more bytes: the older entries go until ≤ 100
    cache.get(9, lambda: body(9, 90))
    cache.get(0, lambda: body(0, 10))
    assert calls == [0, 1, 2, 3, 0, 9]
    cache.get(3, lambda: body(3, 10))
    assert calls[-1] == 3
    cache.get(8, lambda: body(8, 101))  # larger than the whole cache: served, not kept
    cache.get(8, lambda: body(8, 101))
    assert calls[-2:] == [8, 8]


def test_off_with_no_period() -> None:
    cache = MapCache(ttl=0.0)
    calls: list[int] = []

    def compute() -> bytes:
        calls.append(1)
        return b"x"

    for _ in range(2):
        cache.get("k", compute)
    assert calls == [1, 1]
