"""Frame ids: RFC 9562 version-7 UUIDs, ordered by time."""

from __future__ import annotations

import time
import uuid

from app.platform.db.ids import time_ordered_id


def test_a_version_7_uuid_carrying_the_time_in_milliseconds() -> None:
    before = time.time_ns() // 1_000_000
    value = uuid.UUID(time_ordered_id())
    after = time.time_ns() // 1_000_000
    assert value.version == 7
    assert value.variant == uuid.RFC_4122
    assert before <= value.int >> 80 <= after


def test_ids_of_later_milliseconds_sort_after_and_never_repeat() -> None:
    ids = []
    for _ in range(5):
        ids += [time_ordered_id() for _ in range(200)]
        time.sleep(0.002)
    assert len(set(ids)) == len(ids)
    stamps = [uuid.UUID(i).int >> 80 for i in ids]
    assert stamps == sorted(stamps)
    assert len(set(stamps)) >= 5
    # as text (the column is a string), they sort by time too
    assert [uuid.UUID(i).int >> 80 for i in sorted(ids)] == stamps


def test_a_forked_process_draws_other_random_bits_than_its_parent() -> None:
    import os

    time_ordered_id()  # the pool now holds unread bytes, which a child would inherit
    read, write = os.pipe()
    pid = os.fork()
    if pid == 0:  # the child: its next id, then out at once
        os.write(write, time_ordered_id().encode())
        os._exit(0)
    os.close(write)
    os.waitpid(pid, 0)
    child = uuid.UUID(os.read(read, 64).decode())
    os.close(read)
    parent = uuid.UUID(time_ordered_id())
    low = (1 << 62) - 1  # the random bits after the variant
    assert child.int & low != parent.int & low
