"""Row ids for the tables that grow with every frame."""

from __future__ import annotations

import secrets
import time
import uuid


def time_ordered_id() -> str:
    """A UUID of version 7 (RFC 9562, section 5.7): 48 bits of Unix time in milliseconds,
    then 74 random bits (around the version and variant fields), from the OS's CSPRNG.

    New rows' keys then land at the right-hand end of the primary key's B-tree, in the frames
    table and in every verdict table keyed by the frame: a batch of inserts touches the same
    few index pages instead of a random page per row (random version-4 keys), which on
    PostgreSQL also means fewer full-page images in the WAL once the index outgrows memory.
    """
    ms = time.time_ns() // 1_000_000
    bits = (ms & (1 << 48) - 1) << 80 | int.from_bytes(secrets.token_bytes(10), "big")
    bits = bits & ~(0xF << 76) | 0x7 << 76  # version 7
    bits = bits & ~(0x3 << 62) | 0x2 << 62  # variant 10 (RFC 9562)
    return str(uuid.UUID(int=bits))
