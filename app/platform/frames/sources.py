"""Cameras the service pulls frames from (``POST/PATCH /cameras`` with a ``source``).

Every process runs a ``Puller``. A source due is taken by one process through a lease in the
database (``FOR UPDATE SKIP LOCKED`` on PostgreSQL, so processes never wait on each other's
rows; SQLite serves one process), pulled in a worker thread (``grab``), and its frame goes
through the ingest path of a posted frame (the writer, the store, the kind's verdict). A
process that dies holding leases loses them when they expire, and another takes its sources
over. The next frame is due ``every_seconds`` after the one before (not after the pull ended),
so a source is pulled once per interval; a failing one backs off, doubling, to at most
``MAX_BACKOFF``, and recovers by itself."""

from __future__ import annotations

import asyncio
import contextlib
import logging
import uuid
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from datetime import datetime, timedelta
from functools import partial
from typing import Any

from sqlalchemy import or_, select
from sqlalchemy.orm import Session, sessionmaker

from app.platform.db.models import Camera, CameraSource
from app.platform.frames import addresses, ingest
from app.platform.frames.camera_info import CameraInfo
from app.platform.frames.grab import GrabError, grab, masked
from app.platform.frames.storage import FrameStore
from app.platform.frames.writer import GroupCommitWriter
from app.platform.http.errors import Unprocessable, VantageError
from app.platform.observability import FRAMES_RECEIVED
from app.platform.schemas import SourceIn, SourceOut
from app.platform.timing import Timing

log = logging.getLogger("vantage.sources")

MAX_BACKOFF = timedelta(minutes=5)
"""The longest wait before a failing source is tried again."""


def check_address(source: SourceIn | None, allowed: Sequence[str]) -> None:
    """Refuse (422 naming the rule) a source whose host resolves to an address sources may
    not reach, or to none (``addresses``). Blocking (DNS): routes call it from a thread."""
    if source is None:
        return
    try:
        addresses.resolve_url(source.url, addresses.networks(allowed))
    except addresses.AddressRefused as exc:
        raise Unprocessable(str(exc), code="source_address_refused") from None


def set_source(session: Session, camera_id: str, source: SourceIn | None, now: datetime) -> None:
    """Give the camera ``source`` (replacing any, credentials included), or none; the first
    pull is due at once."""
    row = session.get(CameraSource, camera_id)
    if source is None:
        if row is not None:
            session.delete(row)
        return
    if row is None:
        row = CameraSource(camera_id=camera_id)
        session.add(row)
    row.url, row.every_seconds = source.url, source.every_seconds
    row.username, row.password = source.username, source.password
    row.state, row.failures, row.next_due_at = "connecting", 0, now
    row.last_error = row.last_error_at = row.lease_owner = row.lease_expires_at = None


def source_out(row: CameraSource | None) -> SourceOut | None:
    if row is None:
        return None
    return SourceOut(
        url=masked(row.url),
        every_seconds=row.every_seconds,
        username=row.username,
        has_password=row.password is not None,
        state=row.state,
        last_error=row.last_error,
        last_error_at=row.last_error_at,
        last_frame_at=row.last_frame_at,
        last_frame_id=row.last_frame_id,
        next_due_at=row.next_due_at,
    )


def sources_of(session: Session, camera_ids: list[str]) -> dict[str, CameraSource]:
    rows = session.scalars(select(CameraSource).where(CameraSource.camera_id.in_(camera_ids)))
    return {r.camera_id: r for r in rows}


@dataclass(frozen=True, slots=True)
class Lease:
    """A source taken for one pull."""

    camera: CameraInfo
    url: str
    username: str | None
    password: str | None
    every: timedelta
    due: datetime
    failures: int


def claim(
    session: Session, owner: str, now: datetime, *, limit: int, lease: timedelta
) -> list[Lease]:
    """Take up to ``limit`` sources due by ``now`` that no live lease holds (cameras in
    service), leased to ``owner`` until ``now + lease``. Commits."""
    rows = session.execute(
        select(CameraSource, Camera)
        .join(Camera, Camera.id == CameraSource.camera_id)
        .where(
            Camera.retired_at.is_(None),
            CameraSource.next_due_at <= now,
            or_(CameraSource.lease_owner.is_(None), CameraSource.lease_expires_at < now),
        )
        .order_by(CameraSource.next_due_at)
        .limit(limit)
        .with_for_update(skip_locked=True, of=CameraSource)
    ).all()
    taken = []
    for source, camera in rows:
        source.lease_owner, source.lease_expires_at = owner, now + lease
        taken.append(
            Lease(
                CameraInfo.of(camera),
                source.url,
                source.username,
                source.password,
                timedelta(seconds=source.every_seconds),
                source.next_due_at,
                source.failures,
            )
        )
    session.commit()
    return taken


def finish(
    session: Session,
    owner: str,
    lease: Lease,
    now: datetime,
    *,
    frame: tuple[str, datetime] | None,
    error: tuple[str, str] | None,
) -> None:
    """Record a pull (its frame's id and capture time, or its error state and detail, or
    neither: skipped, the camera's rate limit spent) and release the lease, unless another
    process has taken the source since (the lease ran out). The next frame is due an interval
    after this one was; a failure backs off. Commits."""
    row = session.get(CameraSource, lease.camera.id, with_for_update=True)
    if row is None or row.lease_owner != owner:
        session.rollback()
        return
    if frame is None and error is None:
        due = lease.due + lease.every
        row.next_due_at = due if due > now else now + lease.every
    elif frame is not None:
        row.state, row.failures = "ok", 0
        row.last_frame_id, row.last_frame_at = frame
        due = lease.due + lease.every
        row.next_due_at = due if due > now else now + lease.every
    elif error is not None:
        row.state, row.last_error = error[0], error[1][:500]
        row.last_error_at, row.failures = now, lease.failures + 1
        wait = min(lease.every * 2 ** min(row.failures - 1, 16), MAX_BACKOFF)
        row.next_due_at = now + max(wait, lease.every)
    row.lease_owner = row.lease_expires_at = None
    session.commit()


class Puller:
    """This process's share of the sources: claims what is due every ``tick`` seconds and
    pulls up to ``threads`` at once."""

    def __init__(
        self,
        sessions: sessionmaker[Session],
        writer: GroupCommitWriter,
        store: Callable[[], FrameStore | None],
        timing: Callable[[], Timing],
        *,
        threads: int,
        timeout: float,
        max_pixels: int,
        rate_limit: Callable[[str], bool] | None = None,
        allowed_networks: Sequence[str] = (),
        tick: float = 0.5,
    ) -> None:
        """``rate_limit(camera_id)``: whether the camera may store one more frame this minute
        (the budget its posted frames spend too); None: no limit. ``allowed_networks``: CIDRs
        sources may reach although the address rule refuses them (``addresses``)."""
        self.allowed = addresses.networks(allowed_networks)
        self.sessions, self.writer, self.store, self.timing = sessions, writer, store, timing
        self.rate_limit = rate_limit
        self.owner = uuid.uuid4().hex
        self.threads, self.timeout, self.max_pixels, self.tick = threads, timeout, max_pixels, tick
        self.lease = timedelta(seconds=max(30.0, 4 * timeout))
        self.pool = ThreadPoolExecutor(threads, "pull")
        self.db_pool = ThreadPoolExecutor(2, "pull-db")
        """The puller's database work: shut down (waiting for what runs) when it stops, so
        that no claim or record holds a connection of an engine being disposed. A cancelled
        await does not stop its thread, so awaiting the asyncio futures would not do."""
        self.running: set[asyncio.Task[None]] = set()

    def _db(self, fn: Callable[..., Any], *args: Any) -> asyncio.Future[Any]:
        return asyncio.get_running_loop().run_in_executor(self.db_pool, fn, *args)

    async def run(self) -> None:
        try:
            while True:
                free = self.threads - len(self.running)
                if free > 0:
                    try:
                        leases = await self._db(self._claim, free)
                    except Exception as exc:  # the database away: try again next tick
                        log.warning("sources not claimed: %s", str(exc).splitlines()[0])
                        leases = []
                    for lease in leases:
                        task = asyncio.create_task(self._pull(lease))
                        self.running.add(task)
                        task.add_done_callback(self.running.discard)
                await asyncio.sleep(self.tick)
        finally:
            for task in list(self.running):
                task.cancel()
                with contextlib.suppress(asyncio.CancelledError):
                    await task
            self.pool.shutdown(wait=False, cancel_futures=True)
            await asyncio.to_thread(self.db_pool.shutdown, wait=True, cancel_futures=True)

    def _claim(self, limit: int) -> list[Lease]:
        with self.sessions() as session:
            return claim(session, self.owner, self.timing().now(), limit=limit, lease=self.lease)

    async def _pull(self, lease: Lease) -> None:
        loop = asyncio.get_running_loop()
        frame: tuple[str, datetime] | None = None
        error: tuple[str, str] | None = None
        try:
            if self.rate_limit is not None and not await self._db(self.rate_limit, lease.camera.id):
                log.info("source of camera %s skipped: its rate limit is spent", lease.camera.id)
                await self._db(self._finish, lease, None, None)
                return
            data = await loop.run_in_executor(
                self.pool,
                partial(
                    grab,
                    lease.url,
                    username=lease.username,
                    password=lease.password,
                    timeout=self.timeout,
                    allowed=self.allowed,
                ),
            )
            frame = await self._store(lease, data)
        except GrabError as exc:
            error = (exc.state, exc.detail)
        except VantageError as exc:  # not a frame the ingest takes: nothing stored
            error = ("bad_stream", f"{exc.detail}")
        except Exception as exc:  # noqa: BLE001 (the database or the store away: retried)
            error = ("unreachable", f"not stored: {type(exc).__name__}: {exc}")
        if error is not None:
            log.info("source of camera %s: %s", lease.camera.id, error[1])
        with contextlib.suppress(Exception):  # a failure here leaves the lease to run out
            await self._db(self._finish, lease, frame, error)

    async def _store(self, lease: Lease, data: bytes) -> tuple[str, datetime]:
        """The frame through the ingest path of a posted one; its id and capture time."""
        timing = self.timing()
        taken = timing.now()
        prepare = partial(
            ingest.recording,
            self.store(),
            lease.camera,
            data,
            captured_at=taken,
            max_pixels=self.max_pixels,
            timing=timing,
        )
        done: Any = await self.writer.submit_after(prepare, credential=lease.camera.credential)
        FRAMES_RECEIVED.labels(lease.camera.id).inc()
        return str(done.frame.id), taken

    def _finish(
        self, lease: Lease, frame: tuple[str, datetime] | None, error: tuple[str, str] | None
    ) -> None:
        with self.sessions() as session:
            finish(session, self.owner, lease, self.timing().now(), frame=frame, error=error)
