"""Where frame bytes live: a directory that several processes may share, or an S3-compatible
object store (AWS S3, MinIO, Ceph …) that several machines share. Both behind one interface.

On disk, frames are appended to pack files, each preceded by its SHA-256 and length; in S3 each
frame is an object named by its SHA-256 (``frames/ab/<sha256>.jpg``), so identical frames share
one. The database keeps the metadata, the SHA-256 and the locator the store returned; nothing
else refers to a stored frame.
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import hashlib
import os
import re
import struct
import tempfile
import threading
import time
from collections.abc import Generator
from contextlib import suppress
from dataclasses import dataclass, field
from datetime import UTC, datetime, timedelta
from pathlib import Path
from typing import TYPE_CHECKING, Protocol

from app.platform.http.errors import RETRY_AFTER_SECONDS, ServiceUnavailable

if TYPE_CHECKING:
    pass


class StoreUnavailable(ServiceUnavailable):
    """The frame store cannot be reached or written: 503, try again shortly."""

    def __init__(
        self,
        detail: str,
        *,
        code: str = "store_unavailable",
        retry_after: int = RETRY_AFTER_SECONDS,
    ) -> None:
        super().__init__(detail, retry_after=retry_after, code=code)


DISK_FULL_RETRY_AFTER = 60
"""A full disk is not freed in seconds: cameras need not ask again every 5."""


class DiskFull(StoreUnavailable):
    """The frame store's disk is down to the space kept free for the database: 503, try again
    when retention (or an operator) has freed some."""

    def __init__(self, detail: str) -> None:
        super().__init__(detail, code="disk_full", retry_after=DISK_FULL_RETRY_AFTER)


def digest(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def relative_path(sha256: str) -> str:
    return f"frames/{sha256[:2]}/{sha256}.jpg"


class FrameStore(Protocol):
    """Frame bytes by the locator ``put`` returned (a path relative to the store)."""

    def put(self, data: bytes, sha256: str, received_at: datetime) -> str:
        """Store the bytes whole, before returning their locator (no row refers to bytes not
        yet written); ``received_at`` is when the frame arrived, by the service's clock."""
        ...

    def read(self, relative: str) -> bytes | None:
        """The stored bytes, or None when they are not (or no longer) kept."""
        ...

    def delete(self, relatives: list[str]) -> None:
        """Remove these frames' bytes, or let them go with their pack; those already gone are
        skipped."""
        ...

    def expired_packs(self, cutoff: datetime) -> list[str]:
        """Packs whose every frame was received before ``cutoff`` (none in a store without)."""
        ...

    def delete_packs(self, packs: list[str]) -> None:
        """Delete these packs (retention has moved out the frames still referred to)."""
        ...

    def older_than(self, seconds: float) -> list[str]:
        """Every stored frame written at least ``seconds`` ago, as relative paths."""
        ...

    def idle_packs(self, seconds: float) -> list[str]:
        """Packs no live process writes to, unchanged for ``seconds`` (none in a store
        without)."""
        ...

    def pack_locators(self, pack: str) -> Generator[str, None, None]:
        """The locators of the frames whose bytes a pack holds whole, read as asked for."""
        ...

    def check(self) -> None:
        """Raise StoreUnavailable unless the store answers."""
        ...

    def close(self) -> None:
        """Release what the store holds open (at shutdown)."""
        ...


PACK_MAGIC = b"VFR1"
PACK_HEADER = struct.Struct(">4s32sQ")
"""Before each frame in a pack: magic, the frame's SHA-256 (raw), its length in bytes."""
PACK_MAX_BYTES = 256 * 1024 * 1024
"""A process starts a new pack once its current one holds this much."""
RECENT_FRAMES = 1024
"""Frames a pack remembers by SHA-256 (``_Pack.recent``): a camera's retry comes seconds after
the original, and 1,024 entries hold ~100 kB."""
FREE_SPACE_READ_S = 1.0
"""How long a reading of the disk's free space (statvfs), less the frames this process wrote
since, stands in for a new one. Each ``statvfs`` lets go of the GIL, and under load every
upload then waited to take it back. Other processes' writes go unseen for at most this long."""
FREE_SPACE_MARGIN = 64 * 2**20
"""Nearer than this to the space kept free, the disk is asked before every frame [bytes]."""

PACK_BUCKET = "%Y-%m-%dT%H"
"""Packs are grouped by the hour (UTC) their frames were received in: ``packs/<hour>/``."""


def private_dirs(path: Path) -> None:
    """``path`` and any missing folder above it, each made 0700 (``os.makedirs`` gives the
    mode to the last folder only)."""
    missing = []
    while not path.exists():
        missing.append(path)
        path = path.parent
    for folder in reversed(missing):
        with contextlib.suppress(FileExistsError):
            folder.mkdir(mode=0o700)


_LOCATOR = re.compile(r"(packs/[0-9T-]+/[0-9a-z-]+\.pack)@(\d+)\+(\d+)")


def bucket_of(when: datetime) -> str:
    return when.astimezone(UTC).strftime(PACK_BUCKET)


def bucket_end(bucket: str) -> datetime:
    return datetime.strptime(bucket, PACK_BUCKET).replace(tzinfo=UTC) + timedelta(hours=1)


def locator_in(pack: str, start: int, length: int) -> str:
    """The locator of the ``length`` bytes at ``start`` in ``pack`` (what ``_LOCATOR`` reads)."""
    return f"{pack}@{start}+{length}"


def pack_of(locator: str) -> str | None:
    """The pack file (relative path) holding a stored frame, or None for a file of its own."""
    match = _LOCATOR.fullmatch(locator)
    return match.group(1) if match else None


def extent_of(locator: str) -> tuple[str, int]:
    """The file holding a stored frame (relative path), and the size it needs to hold it."""
    match = _LOCATOR.fullmatch(locator)
    if match is None:  # a file of its own
        return locator, 1
    return match.group(1), int(match.group(2)) + int(match.group(3))


@dataclass(slots=True)
class _Pack:
    """A pack this process appends to; closed once retired and no write is still using it."""

    bucket: str
    relative: str
    fd: int
    size: int = 0
    writers: int = 0
    retired: bool = False
    recent: dict[str, int] = field(default_factory=dict)
    """Where the frames written whole into this pack lately begin, by SHA-256, at most
    ``RECENT_FRAMES``: the same bytes put again point there instead of being written twice."""


class DiskFrameStore:
    """Frame bytes under ``root``: appended to pack files, ``packs/<hour>/<name>.pack``.

    Content-addressed as git's packs are: every frame in a pack is preceded by a header with its
    SHA-256 and length, and the database row keeps its SHA-256 beside its locator
    ``packs/<hour>/<name>.pack@<offset>+<length>``. A file per frame would cost an inode and its
    kernel CPU per frame (more than the rest of the store and the database together); appending
    to an open file costs a tenth of that.

    Each process appends to packs of its own (never two writers in one file), one per hour of
    reception, a new one every ``PACK_MAX_BYTES``. A frame's row is committed only after its
    bytes are written, so a row always has its bytes; a process killed mid-write leaves at most
    the tail of a pack that no row refers to, which goes with the pack, or a pack no row refers
    to at all, which the start-up sweep deletes (``idle_packs``). Retention deletes a pack
    once its hour has expired, after moving out the frames that are kept regardless of age
    (``app.platform.frames.retention``).

    Frames stored by earlier versions as files of their own (``frames/ab/<sha256>.jpg``) are
    still read, swept when orphaned and deleted by retention.
    """

    def __init__(
        self,
        root: Path,
        *,
        fsync: bool = False,
        keep_free_bytes: int = 0,
        largest_frame_bytes: int = 0,
    ) -> None:
        self.root = root
        self.fsync = fsync
        self.largest_frame_bytes = largest_frame_bytes
        """``check`` fails when a frame this large would be refused."""
        self.keep_free_bytes = keep_free_bytes
        """Frames are refused (``DiskFull``) rather than take the disk's last bytes: the
        database beside them (SQLite in the same directory, by default) keeps room to record
        a robot's claim, an alert, a retention sweep [B]."""
        self._lock = threading.Lock()
        self._pack: _Pack | None = None
        self._free: tuple[float, int] | None = None
        """(when read, bytes free then less the frames written since): ``_make_room``. Read
        and replaced without the store's lock: two frames at once may be taken off as one,
        which the margin and the one-second bound absorb."""

    def free_bytes(self) -> int:
        """Bytes free on the store's disk for this process (statvfs: ~0.6 µs)."""
        st = os.statvfs(self.root)
        return st.f_bavail * st.f_frsize

    def _make_room(self, size: int, *, ask: bool = False) -> None:
        """Refuse (``DiskFull``) ``size`` bytes more that would eat into the space kept free.
        The disk is asked (``ask``, or when the last reading is old or near the limit), else
        the last reading less the bytes let through since stands in."""
        if not self.keep_free_bytes:
            return
        now = time.monotonic()
        last = self._free
        if (
            ask
            or last is None
            or now - last[0] > FREE_SPACE_READ_S
            or last[1] - size < self.keep_free_bytes + FREE_SPACE_MARGIN
        ):
            last = (now, self.free_bytes())
        read_at, free = last
        fits = free - size >= self.keep_free_bytes
        self._free = (read_at, free - size) if fits and not ask else last
        if not fits:
            raise DiskFull(
                f"{self.root}: {free / 2**20:.1f} MiB free, and "
                f"{self.keep_free_bytes / 2**20:.1f} MiB are kept for the database "
                "(VANTAGE_KEEP_FREE_DISK_MB): frames are refused until space is freed "
                "(retention, VANTAGE_FRAME_RETENTION_DAYS, or a larger disk)"
            )

    def path(self, relative: str) -> Path:
        return self.root / relative

    def put(self, data: bytes, sha256: str, received_at: datetime) -> str:
        """Append the frame to this process's pack for its hour; return its locator.

        The same bytes put again while this process writes the same pack (a camera's retry of
        a frame it got no answer for, a frame measured again) get the locator of the copy
        already there: a retried 550 kB frame was stored twice, and stayed so for the whole
        retention. Only in the pack open for the same hour: that pack is locked (no sweep
        deletes it) and expires with every frame that points into it.

        With ``fsync`` (off by default) the pack's data is flushed before returning: power-loss
        safety, not only a process crash's.
        """
        bucket = bucket_of(received_at)
        with self._lock:
            pack = self._pack
            if pack is not None and pack.bucket == bucket and sha256 in pack.recent:
                return locator_in(pack.relative, pack.recent[sha256], len(data))
        record = PACK_HEADER.pack(PACK_MAGIC, bytes.fromhex(sha256), len(data)) + data
        try:
            self._make_room(len(record))
            pack, offset = self._reserve(bucket, len(record))
        except OSError as exc:
            raise StoreUnavailable(f"{self.root}: storing the frame failed: {exc}") from exc
        start = offset + PACK_HEADER.size
        whole: tuple[str, int] | None = None  # set once the frame is written whole
        try:
            view = memoryview(record)
            at = offset
            while view:  # a regular file takes it whole unless the disk is full
                written = os.pwrite(pack.fd, view, at)
                view, at = view[written:], at + written
            if self.fsync:
                os.fdatasync(pack.fd)
            whole = (sha256, start)
        except OSError as exc:  # full, read-only, gone: the client should retry later
            raise StoreUnavailable(f"{self.root}: storing the frame failed: {exc}") from exc
        finally:
            self._release(pack, whole)
        return locator_in(pack.relative, start, len(data))

    def _reserve(self, bucket: str, size: int) -> tuple[_Pack, int]:
        """The pack to append ``size`` bytes to, and where; a new pack for a new hour or when
        the current one is full. A frame whose hour is older than the current pack's (a thread
        that lost the race at the turn of the hour) goes into the current one: a pack never
        holds a frame received after its hour, so it expires after every frame in it."""
        with self._lock:
            pack = self._pack
            full = pack is not None and pack.size > 0 and pack.size + size > PACK_MAX_BYTES
            if pack is None or bucket > pack.bucket or full:
                pack = self._open_pack(max(bucket, pack.bucket) if pack else bucket)
            offset = pack.size
            pack.size += size
            pack.writers += 1
            return pack, offset

    def _open_pack(self, bucket: str) -> _Pack:
        directory = f"{self.root}/packs/{bucket}"
        private_dirs(Path(directory))
        name = f"{time.time_ns()}-{os.getpid()}-{os.urandom(4).hex()}.pack"
        flags = os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_CLOEXEC
        fd = os.open(f"{directory}/{name}", flags, 0o600)  # frames are this user's only
        # held while the pack is open: the start-up sweep leaves locked packs alone
        # (``idle_packs``); the kernel drops it when the process dies, even by kill -9. On a
        # file system without locks (NFSv3 without lockd) writing goes on, and the sweep,
        # which cannot take a lock there either, deletes no pack.
        with suppress(OSError):
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        pack = _Pack(bucket, f"packs/{bucket}/{name}", fd)
        if self._pack is not None:
            self._retire(self._pack)
        self._pack = pack
        return pack

    def _retire(self, pack: _Pack) -> None:
        pack.retired = True
        if pack.writers == 0:
            os.close(pack.fd)

    def _release(self, pack: _Pack, written: tuple[str, int] | None = None) -> None:
        """A write into ``pack`` is over; ``written``: the SHA-256 of the frame it wrote whole
        and where the frame begins."""
        with self._lock:
            pack.writers -= 1
            if written is not None and not pack.retired:
                if len(pack.recent) >= RECENT_FRAMES:
                    del pack.recent[next(iter(pack.recent))]  # the oldest
                pack.recent[written[0]] = written[1]
            if pack.retired and pack.writers == 0:
                os.close(pack.fd)

    def close(self) -> None:
        """Close this process's pack (it is not reopened: the next frame starts a new one)."""
        with self._lock:
            if self._pack is not None:
                self._retire(self._pack)
                self._pack = None

    def read(self, relative: str) -> bytes | None:
        match = _LOCATOR.fullmatch(relative)
        try:
            if match is None:  # a file of its own
                return self.path(relative).read_bytes()
            pack, offset, length = match.group(1), int(match.group(2)), int(match.group(3))
            fd = os.open(self.root / pack, os.O_RDONLY | os.O_CLOEXEC)
            try:
                header = offset - PACK_HEADER.size
                record = os.pread(fd, PACK_HEADER.size + length, header)
            finally:
                os.close(fd)
        except FileNotFoundError:
            return None
        except OSError as exc:  # unreadable: a failing disk, a lost mount
            raise StoreUnavailable(f"{self.root}: reading the frame failed: {exc}") from exc
        if len(record) != PACK_HEADER.size + length:
            raise StoreUnavailable(f"{self.root}: {pack} ends before the frame at {offset}")
        magic, _, size = PACK_HEADER.unpack_from(record)
        if magic != PACK_MAGIC or size != length:
            raise StoreUnavailable(f"{self.root}: no frame header in {pack} before {offset}")
        return record[PACK_HEADER.size :]

    def delete(self, relatives: list[str]) -> None:
        """Delete frames stored as files of their own; a frame in a pack goes with its pack."""
        for relative in relatives:
            if pack_of(relative) is None:
                self.path(relative).unlink(missing_ok=True)

    def expired_packs(self, cutoff: datetime) -> list[str]:
        """Packs (relative paths) whose hour ended at or before ``cutoff``."""
        base = self.root / "packs"
        if not base.exists():
            return []
        return sorted(
            f"packs/{d.name}/{p.name}"
            for d in base.iterdir()
            if (end := _bucket_end_of(d.name)) is not None and end <= cutoff
            for p in d.glob("*.pack")
        )

    def delete_packs(self, packs: list[str]) -> None:
        """Delete these packs, and their hours' directories once empty."""
        for relative in packs:
            self.path(relative).unlink(missing_ok=True)
            with suppress(OSError):  # not empty yet, or already gone
                self.path(relative).parent.rmdir()

    def files(self) -> list[str]:
        """Every frame stored as a file of its own, as relative paths."""
        base = self.root / "frames"
        if not base.exists():
            return []
        return sorted(str(p.relative_to(self.root)) for p in base.glob("*/*.jpg"))

    def packs(self) -> list[str]:
        """Every pack, as relative paths."""
        base = self.root / "packs"
        return sorted(str(p.relative_to(self.root)) for p in base.glob("*/*.pack"))

    def older_than(self, seconds: float) -> list[str]:
        """Frames stored as files of their own, written at least ``seconds`` ago (the bytes
        in packs that no row refers to go with their pack instead)."""
        now = time.time()
        old = []
        for relative in self.files():
            try:
                if now - self.path(relative).stat().st_mtime >= seconds:
                    old.append(relative)
            except FileNotFoundError:  # deleted meanwhile by another process
                continue
        return old

    def idle_packs(self, seconds: float) -> list[str]:
        """Packs unchanged for ``seconds`` that no process holds open for writing: a process
        locks its pack (``flock``) from creating it until it retires it.

        Over NFS, ``flock`` is only as good as the server's locking (NFSv4: whole-file locks
        work); the age is the second guard, for a pack retired while its last frames' rows were
        still being committed.
        """
        now = time.time()
        idle = []
        for relative in self.packs():
            try:
                fd = os.open(self.path(relative), os.O_RDONLY | os.O_CLOEXEC)
            except FileNotFoundError:  # deleted meanwhile by another process
                continue
            try:
                if now - os.fstat(fd).st_mtime < seconds:
                    continue
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except OSError:  # a live process's, or no locks here to prove it is not
                continue
            finally:
                os.close(fd)  # and with it the lock just taken
            idle.append(relative)
        return idle

    def pack_locators(self, pack: str) -> Generator[str, None, None]:
        """The locators of the frames a pack holds whole, in order, read header by header as
        they are asked for, up to the first that is cut off or not a header (the tail a killed
        process left)."""
        try:
            fd = os.open(self.path(pack), os.O_RDONLY | os.O_CLOEXEC)
        except FileNotFoundError:
            return
        try:
            end = os.fstat(fd).st_size
            offset = 0
            while offset + PACK_HEADER.size <= end:
                magic, _, length = PACK_HEADER.unpack(os.pread(fd, PACK_HEADER.size, offset))
                start = offset + PACK_HEADER.size
                if magic != PACK_MAGIC or start + length > end:
                    break
                yield locator_in(pack, start, length)
                offset = start + length
        finally:
            os.close(fd)

    def check(self) -> None:
        if not (self.root.is_dir() and os.access(self.root, os.W_OK)):
            raise StoreUnavailable(f"{self.root} is missing or not writable")
        try:
            self._make_room(self.largest_frame_bytes, ask=True)
            # A file made and written, as a frame is: neither the mount's flags nor
            # os.access say that the kernel has stopped the filesystem's writes. ext4 with
            # errors=remount-ro does so after an I/O error ("emergency_ro"), its mount still
            # listed rw.
            # An unnamed file (O_TMPFILE where the filesystem has it) leaves nothing behind.
            with tempfile.TemporaryFile(dir=self.root, prefix=".probe-") as probe:
                probe.write(b"\0")
                probe.flush()
        except OSError as exc:
            if exc.errno in (errno.ENOSPC, errno.EDQUOT):
                raise DiskFull(f"{self.root}: {exc}") from exc
            raise StoreUnavailable(f"{self.root}: {exc}") from exc


def _bucket_end_of(name: str) -> datetime | None:
    """``bucket_end`` of a directory named as an hour's bucket; None for any other name."""
    try:
        return bucket_end(name)
    except ValueError:
        return None
