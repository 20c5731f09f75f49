"""The disk frame store: frames appended to packs, read back whole, packs by hour."""

from __future__ import annotations

import errno
import os
import random
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from contextlib import suppress
from datetime import UTC, datetime, timedelta
from pathlib import Path

import pytest

from app.platform.frames import storage
from app.platform.frames.storage import (
    PACK_HEADER,
    DiskFrameStore,
    StoreUnavailable,
    digest,
    pack_of,
)

T0 = datetime(2026, 6, 1, 8, 59, 59, tzinfo=UTC)


def frames(n: int, seed: int = 1) -> list[bytes]:
    rng = random.Random(seed)
    return [rng.randbytes(rng.randint(1, 50_000)) for _ in range(n)]


@pytest.mark.parametrize("fsync", [False, True])
def test_frames_from_16_threads_read_back_whole(tmp_path: Path, fsync: bool) -> None:
    store = DiskFrameStore(tmp_path, fsync=fsync)
    bodies = frames(400)
    with ThreadPoolExecutor(16) as pool:
        locators = list(pool.map(lambda b: store.put(b, digest(b), T0), bodies))
    assert len(set(locators)) == 400
    assert [store.read(loc) for loc in locators] == bodies
    (pack,) = store.packs()  # one process, one hour: one pack
    assert {pack_of(loc) for loc in locators} == {pack}
    size = sum(PACK_HEADER.size + len(b) for b in bodies)
    assert (tmp_path / pack).stat().st_size == size  # no gaps, no overlaps


def test_each_frame_is_preceded_by_its_sha256_and_length(tmp_path: Path) -> None:
    store = DiskFrameStore(tmp_path)
    body = b"\xff\xd8 a frame"
    locator = store.put(body, digest(body), T0)
    raw = (tmp_path / store.packs()[0]).read_bytes()
    magic, sha, length = PACK_HEADER.unpack_from(raw)
    assert (magic, sha.hex(), length) == (b"VFR1", digest(body), len(body))
    assert locator == f"{store.packs()[0]}@{PACK_HEADER.size}+{len(body)}"


def test_a_new_hour_starts_a_new_pack_and_a_late_frame_joins_the_newer(tmp_path: Path) -> None:
    store = DiskFrameStore(tmp_path)
    a, b, late = frames(3)
    in_8 = store.put(a, digest(a), T0)
    in_9 = store.put(b, digest(b), T0 + timedelta(seconds=1))
    # a thread that took its time stamp before the hour turned, and writes after
    straggler = store.put(late, digest(late), T0)
    assert str(pack_of(in_8)).startswith("packs/2026-06-01T08/")
    assert str(pack_of(in_9)).startswith("packs/2026-06-01T09/")
    assert pack_of(straggler) == pack_of(in_9)  # expires after the frame's own hour
    assert [store.read(x) for x in (in_8, in_9, straggler)] == [a, b, late]


def test_a_full_pack_is_followed_by_a_new_one(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(storage, "PACK_MAX_BYTES", 100_000)
    store = DiskFrameStore(tmp_path)
    bodies = frames(20)
    locators = [store.put(b, digest(b), T0) for b in bodies]
    assert len(store.packs()) > 1
    assert all(os.path.getsize(tmp_path / p) <= 100_000 for p in store.packs())
    assert [store.read(x) for x in locators] == bodies


def test_a_closed_store_starts_a_new_pack(tmp_path: Path) -> None:
    store = DiskFrameStore(tmp_path)
    a, b = frames(2)
    first = store.put(a, digest(a), T0)
    store.close()
    second = store.put(b, digest(b), T0)
    assert pack_of(first) != pack_of(second)
    assert [store.read(first), store.read(second)] == [a, b]


def test_reading_a_gone_pack_is_none_a_cut_one_unavailable(tmp_path: Path) -> None:
    store = DiskFrameStore(tmp_path)
    a, b = frames(2)
    first, second = (store.put(x, digest(x), T0) for x in (a, b))
    pack = tmp_path / store.packs()[0]
    with open(pack, "r+b") as f:  # cut inside the second frame
        f.truncate(pack.stat().st_size - 10)
    assert store.read(first) == a
    with pytest.raises(StoreUnavailable):
        store.read(second)
    bad = first.replace(f"@{PACK_HEADER.size}+", f"@{PACK_HEADER.size + 1}+")
    with pytest.raises(StoreUnavailable):  # no frame header where the locator points
        store.read(bad)
    pack.unlink()
    assert store.read(first) is None


def test_packs_expire_with_their_hour(tmp_path: Path) -> None:
    store = DiskFrameStore(tmp_path)
    for k, body in enumerate(frames(3)):
        store.put(body, digest(body), T0 + timedelta(hours=k))
    assert [p.split("/")[1] for p in store.packs()] == [
        "2026-06-01T08",
        "2026-06-01T09",
        "2026-06-01T10",
    ]
    end_of_9 = datetime(2026, 6, 1, 10, tzinfo=UTC)
    assert store.expired_packs(end_of_9 - timedelta(microseconds=1)) == store.packs()[:1]
    expired = store.expired_packs(end_of_9)
    assert expired == store.packs()[:2]
    store.delete_packs(expired)
    assert [p.split("/")[1] for p in store.packs()] == ["2026-06-01T10"]
    assert sorted(d.name for d in (tmp_path / "packs").iterdir()) == ["2026-06-01T10"]


def test_a_store_that_cannot_write_raises_unavailable(tmp_path: Path) -> None:
    (tmp_path / "packs").write_bytes(b"")  # a file where the packs' directory should be
    store = DiskFrameStore(tmp_path)
    with pytest.raises(StoreUnavailable):
        store.put(b"x", digest(b"x"), T0)
    (tmp_path / "packs").unlink()
    locator = store.put(b"x", digest(b"x"), T0)
    assert store.read(locator) == b"x"


def test_a_pack_is_idle_once_its_process_is_gone_and_it_has_aged(tmp_path: Path) -> None:
    """A live process's pack is never idle, however old; once the process is killed (-9: no
    chance to close anything), its pack is idle when old enough."""
    store = DiskFrameStore(tmp_path)
    with subprocess.Popen(
        [
            sys.executable,
            "-c",
            "import sys; from datetime import datetime, UTC; "
            "from app.platform.frames.storage import DiskFrameStore, digest; "
            f"s = DiskFrameStore(__import__('pathlib').Path({str(tmp_path)!r})); "
            "s.put(b'frame', digest(b'frame'), datetime.now(UTC)); "
            "print('written', flush=True); sys.stdin.read()",
        ],
        cwd=Path(__file__).resolve().parents[2],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
    ) as child:
        try:
            assert child.stdout is not None
            assert child.stdout.readline() == "written\n"
            (pack,) = store.packs()
            os.utime(tmp_path / pack, (10_000, 10_000))  # old
            assert store.idle_packs(600) == []  # locked by its live writer
        finally:
            child.kill()
    assert store.idle_packs(600) == [pack]
    os.utime(tmp_path / pack)  # touched just now: maybe still being written
    assert store.idle_packs(600) == []
    assert store.idle_packs(0) == [pack]


def test_this_process_s_own_pack_is_not_idle_until_the_store_closes(tmp_path: Path) -> None:
    store = DiskFrameStore(tmp_path)
    store.put(b"x", digest(b"x"), T0)
    assert store.idle_packs(0) == []
    store.close()
    assert store.idle_packs(0) == store.packs()


def test_a_pack_s_locators_stop_at_a_cut_tail(tmp_path: Path) -> None:
    store = DiskFrameStore(tmp_path)
    bodies = frames(3)
    locators = [store.put(b, digest(b), T0) for b in bodies]
    (pack,) = store.packs()
    assert list(store.pack_locators(pack)) == locators
    with open(tmp_path / pack, "r+b") as f:  # a killed process's last write, cut short
        f.truncate((tmp_path / pack).stat().st_size - 1)
    assert list(store.pack_locators(pack)) == locators[:2]
    with open(tmp_path / pack, "r+b") as f:  # not even a whole header
        f.truncate(PACK_HEADER.size - 1)
    assert list(store.pack_locators(pack)) == []
    assert list(store.pack_locators("packs/2026-06-01T08/gone.pack")) == []


def test_without_file_locks_frames_are_stored_and_no_pack_is_idle(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A file system that refuses locks (ENOLCK): uploads go on, and the sweep, unable to
    prove a pack is not being written, leaves every pack alone."""

    def no_locks(fd: int, operation: int) -> None:
        raise OSError(errno.ENOLCK, "No locks available")

    monkeypatch.setattr(storage.fcntl, "flock", no_locks)
    store = DiskFrameStore(tmp_path)
    locator = store.put(b"x", digest(b"x"), T0)
    assert store.read(locator) == b"x"
    store.close()
    assert store.idle_packs(0) == []


@pytest.mark.slow  # a real server or camera process, seconds of waiting
def test_a_bucket_that_never_answers_fails_in_bounded_time(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """An S3 endpoint that takes connections and never answers: a frame's PUT, and the health
    check, fail with StoreUnavailable after the tries' read timeouts (here 2 × 0.5 s), not
    botocore's 3 × 60 s (measured against such an endpoint: 180 s for the check, 183 for a
    PUT; 20 and 22 s with the store's defaults, 2 tries of 10 s)."""
    import socket
    import threading

    from app.platform.frames.stores import S3FrameStore, S3Timeouts

    monkeypatch.setenv("AWS_ACCESS_KEY_ID", "test")
    monkeypatch.setenv("AWS_SECRET_ACCESS_KEY", "test")
    silent = socket.socket()
    silent.bind(("127.0.0.1", 0))
    silent.listen(16)
    held: list[socket.socket] = []

    def accept() -> None:
        with suppress(OSError):
            while True:
                held.append(silent.accept()[0])  # read nothing, answer nothing

    threading.Thread(target=accept, daemon=True).start()
    endpoint = f"http://127.0.0.1:{silent.getsockname()[1]}"
    try:
        defaults = S3FrameStore("frames", endpoint_url=endpoint, region="us-east-1")
        config = defaults._s3.meta.config
        assert (config.connect_timeout, config.read_timeout) == (3.0, 10.0)
        assert config.retries == {"mode": "standard", "total_max_attempts": 2}
        store = S3FrameStore(
            "frames",
            endpoint_url=endpoint,
            region="us-east-1",
            timeouts=S3Timeouts(connect=0.5, read=0.5, attempts=2),
        )
        for attempt in (store.check, lambda: store.put(b"x", digest(b"x"), T0)):
            with pytest.raises(StoreUnavailable, match="timeout"):
                attempt()
    finally:
        silent.close()
        for c in held:
            c.close()


def test_the_same_bytes_put_again_in_the_same_pack_are_stored_once(tmp_path: Path) -> None:
    """A camera's retry of a frame (or a frame measured again) points at the copy already in
    this process's pack for the hour: the pack holds it once."""
    store = DiskFrameStore(tmp_path)
    a, b = frames(2)
    first = store.put(a, digest(a), T0)
    other = store.put(b, digest(b), T0)
    again = store.put(a, digest(a), T0 - timedelta(minutes=5))  # the same hour
    assert again == first != other
    assert store.read(again) == a
    (pack,) = store.packs()
    assert (tmp_path / pack).stat().st_size == 2 * PACK_HEADER.size + len(a) + len(b)


def test_the_same_bytes_in_another_hour_or_pack_are_written_again(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Only the open pack of the frame's own hour is pointed into: a pack expires with its
    hour, and a retired one is no longer locked against the sweep."""
    store = DiskFrameStore(tmp_path)
    (a,) = frames(1)
    in_8 = store.put(a, digest(a), T0)
    in_9 = store.put(a, digest(a), T0 + timedelta(seconds=1))
    assert pack_of(in_8) != pack_of(in_9)
    store.close()  # a new pack next
    after = store.put(a, digest(a), T0 + timedelta(seconds=2))
    assert pack_of(after) not in {pack_of(in_8), pack_of(in_9)}
    assert [store.read(x) for x in (in_8, in_9, after)] == [a, a, a]
    # a pack remembers its last RECENT_FRAMES frames only
    monkeypatch.setattr(storage, "RECENT_FRAMES", 2)
    b, c, d = frames(3, seed=2)
    t = T0 + timedelta(seconds=3)
    first_b = store.put(b, digest(b), t)
    store.put(c, digest(c), t)
    first_d = store.put(d, digest(d), t)  # b is forgotten
    assert store.put(d, digest(d), t) == first_d
    again_b = store.put(b, digest(b), t)
    assert again_b != first_b  # written again
    assert store.read(first_b) == store.read(again_b) == b


def test_a_failed_write_is_not_pointed_at(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    store = DiskFrameStore(tmp_path)
    (a,) = frames(1)
    real = os.pwrite
    calls = 0

    def failing(fd: int, data: object, offset: int) -> int:
        nonlocal calls
        calls += 1
        if calls == 1:
            raise OSError(errno.ENOSPC, "No space left on device")
        return real(fd, data, offset)  # type: ignore[arg-type]

    monkeypatch.setattr(os, "pwrite", failing)
    with pytest.raises(StoreUnavailable):
        store.put(a, digest(a), T0)
    locator = store.put(a, digest(a), T0)  # written, not pointed at the failed write's place
    assert store.read(locator) == a
    assert calls == 2


def test_the_disk_s_free_space_is_read_once_a_second_far_from_the_limit_and_at_every_frame_near_it(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    keep = 100 * 2**20
    store = DiskFrameStore(tmp_path, keep_free_bytes=keep)
    clock = [1000.0]
    monkeypatch.setattr(storage.time, "monotonic", lambda: clock[0])
    disk = [keep + 10 * storage.FREE_SPACE_MARGIN]  # what statvfs says
    reads = []

    def free_bytes() -> int:
        reads.append(disk[0])
        return disk[0]

    monkeypatch.setattr(store, "free_bytes", free_bytes)
    bodies = frames(20, seed=3)
    for body in bodies[:10]:
        store.put(body, digest(body), T0)
    assert len(reads) == 1  # far from the limit: the first reading, less the frames since

    # another process filled the disk meanwhile: seen once the reading is a second old
    disk[0] = keep + 1000
    store.put(bodies[10], digest(bodies[10]), T0)  # the old reading still stands
    clock[0] += storage.FREE_SPACE_READ_S + 0.01
    with pytest.raises(storage.DiskFull):
        store.put(bodies[11], digest(bodies[11]), T0)
    assert len(reads) == 2

    # near the limit every frame asks the disk
    disk[0] = keep + storage.FREE_SPACE_MARGIN // 2
    for body in bodies[12:15]:
        store.put(body, digest(body), T0)
    assert len(reads) == 5


def test_this_process_s_own_frames_count_against_the_last_reading(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Between readings the frames written are taken off the last one: enough of them reach
    the margin, and the disk is asked again before the next."""
    keep = 2**20
    store = DiskFrameStore(tmp_path, keep_free_bytes=keep)
    monkeypatch.setattr(storage.time, "monotonic", lambda: 5.0)  # the clock stands still
    reads = []

    def free_bytes() -> int:
        reads.append(1)
        return keep + storage.FREE_SPACE_MARGIN + 120_000

    monkeypatch.setattr(store, "free_bytes", free_bytes)
    bodies = frames(10, seed=4)  # up to 50 kB each: three or more pass the margin
    for body in bodies:
        store.put(body, digest(body), T0)
    assert 2 <= len(reads) < 10
    before = len(reads)
    store.check()  # /health asks the disk whatever the last reading
    assert len(reads) == before + 1
