"""Row ids for the tables that grow with every frame."""

from __future__ import annotations

import os
import threading
import time
import uuid

_POOL_BYTES = 4096
"""Random bytes read from the OS at once: ``os.urandom`` is a system call that lets go of the
GIL, and every upload paid it, with a wait to take the GIL back under load, for 10 bytes."""


class _RandomPool:
    """Bytes of ``os.urandom``, read a pool at a time and handed out once each. Forgotten in a
    forked child, which would otherwise hand out its parent's next bytes again (the same ids
    in two processes)."""

    def __init__(self) -> None:
        self._forget()
        os.register_at_fork(after_in_child=self._forget)

    def _forget(self) -> None:
        self._lock = threading.Lock()
        self._bytes = b""
        self._at = 0

    def take(self, n: int) -> bytes:
        with self._lock:
            if self._at + n > len(self._bytes):
                self._bytes, self._at = os.urandom(max(n, _POOL_BYTES)), 0
            start, self._at = self._at, self._at + n
            return self._bytes[start : self._at]


_random = _RandomPool()


def time_ordered_id() -> str:
    """A UUID of version 7 (RFC 9562, section 5.7): 48 bits of Unix time in milliseconds,
    then 74 random bits (around the version and variant fields), from the OS's CSPRNG.

    New rows' keys then land at the right-hand end of the primary key's B-tree, in the frames
    table and in every verdict table keyed by the frame: a batch of inserts touches the same
    few index pages instead of a random page per row (random version-4 keys), which on
    PostgreSQL also means fewer full-page images in the WAL once the index outgrows memory.
    """
    ms = time.time_ns() // 1_000_000
    bits = (ms & (1 << 48) - 1) << 80 | int.from_bytes(_random.take(10), "big")
    bits = bits & ~(0xF << 76) | 0x7 << 76  # version 7
    bits = bits & ~(0x3 << 62) | 0x2 << 62  # variant 10 (RFC 9562)
    return str(uuid.UUID(int=bits))
