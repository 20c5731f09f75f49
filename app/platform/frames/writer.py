"""Group commit for the ingest path: one thread writes, many requests wait.

Every frame needs a short write transaction. Run from many request threads at once, those
transactions queue for the database's write lock (SQLite has one writer; PostgreSQL pays an
fsync per commit), and each one's few statements wait behind the CPU-bound decoding of other
frames, so the lock is held for far longer than the work takes. Here a single thread owns the
writes instead: it takes every job that is waiting, runs them in one transaction and commits
once for the whole batch. When a job raises, the batch is rolled back and its jobs are run again
one transaction each, so only the failing job fails; jobs must therefore depend on nothing but
the database they see. A caller's result (its 201) comes only after the commit holding its rows.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import queue
import threading
import time
from collections.abc import Callable, Sequence
from concurrent.futures import Future
from dataclasses import dataclass
from typing import Any, Literal, TypeVar

from sqlalchemy import Connection, Engine
from sqlalchemy.exc import DBAPIError, IntegrityError
from sqlalchemy.orm import Session, sessionmaker

from app.platform.db.rows import deferred_inserts
from app.platform.http.errors import Unauthorized, database_unavailable
from app.platform.observability import WRITER_BATCH_FRAMES

log = logging.getLogger("vantage.writer")

T = TypeVar("T")

GATHER_S = 0.020
"""How long a batch waits for the jobs of preparations still under way [s]: a batch costs the
writer a fixed part whatever its size (bench/writer_batches.py), so fuller batches cost less
CPU a frame. Never waited for when no preparation is under way (a lone upload): the wait adds
at most this much to an upload's answer, and only while others are being prepared."""

PREPARERS = 32
"""Frames decoding and storing at once, per process, unless told (``submit_after``; the wait for
the commit takes no thread). The service sets it from ``Settings.effective_ingest_threads``."""


Credential = tuple[str, str | None, str | None]
"""(camera id, token hash, view): the camera token a job's request was accepted with, and the
camera's panel and region its frame was measured by (``CameraInfo.credential``); None: not
checked."""

Refusal = Literal["revoked", "changed"]

Check = Callable[[Session, set[Credential]], dict[Credential, Refusal]]
"""Which of the credentials no longer hold, and how (``cameras.refusals``)."""


class CameraChanged(Exception):
    """The camera watches another panel or measures another region since the frame was
    measured (a change made through another process, whose cached camera this process had):
    nothing was stored; measure the frame again with the camera as it is now."""


@dataclass(slots=True)
class _Job:
    fn: Callable[..., Any]
    """Called as fn(session), or fn(session, retry=True) when run again after a conflict."""
    future: Future[Any] | asyncio.Future[Any]
    loop: asyncio.AbstractEventLoop | None = None
    """The event loop an asyncio ``future`` belongs to; None for a thread's future."""
    credential: Credential | None = None
    """Checked again inside the job's batch (``GroupCommitWriter``'s ``check``)."""
    frame: bool = False
    """An upload's job (``submit_after``): counted by ``vantage_writer_batch_frames``."""


Outcome = tuple[Any, BaseException | None]

TRANSACTION_ROLLBACK = "40"
"""PostgreSQL's class of errors that roll a transaction back for having lost a race with
another (40P01 deadlock detected, 40001 serialization failure); run again, it passes."""


def _lost_a_race(exc: BaseException) -> bool:
    """Whether the batch failed for having lost a race with another process's transaction: a
    deadlock (two processes' batches locking the same cameras or panels in opposite orders).
    Its jobs are run again one transaction each (each locks one camera or panel, and so takes
    no part in a deadlock), rather than all failing as when the database is down."""
    sqlstate = getattr(getattr(exc, "orig", None), "sqlstate", None) or ""
    return isinstance(exc, DBAPIError) and sqlstate.startswith(TRANSACTION_ROLLBACK)


def _refused(refusal: Refusal) -> BaseException:
    if refusal == "revoked":
        return Unauthorized("unknown token: it was replaced, or its camera retired")
    return CameraChanged()


def _settle(future: Future[Any] | asyncio.Future[Any], outcome: Outcome) -> None:
    result, error = outcome
    if future.done():  # an asyncio future whose request was cancelled: nobody waits
        return
    if error is not None:
        future.set_exception(error)
    else:
        future.set_result(result)


def _settle_all(settled: Sequence[tuple[asyncio.Future[Any], Outcome]]) -> None:
    for future, outcome in settled:
        _settle(future, outcome)


class _Preparers:
    """The preparing threads: daemons fed from one queue. A frame's write into a store that
    stopped answering (a hard network mount) never returns, and a ``ThreadPoolExecutor``'s
    threads are joined at the interpreter's exit: the process, told to stop, waited for that
    write for ever and needed SIGKILL. Daemon threads let it go once ``shutdown`` has waited
    its bound."""

    def __init__(self, size: int, name: str) -> None:
        self._work: queue.SimpleQueue[Callable[[], None] | None] = queue.SimpleQueue()
        self._threads = [
            threading.Thread(target=self._run, name=f"{name}_{i}", daemon=True) for i in range(size)
        ]
        for thread in self._threads:
            thread.start()

    def _run(self) -> None:
        while (work := self._work.get()) is not None:
            try:
                work()
            except Exception:  # the thread must outlive any one piece of work
                log.exception("a preparation failed outside its request")

    def submit(self, work: Callable[[], None]) -> None:
        self._work.put(work)

    def shutdown(self, timeout: float) -> int:
        """Let the work queued so far run; wait for it at most ``timeout`` seconds. Returns how
        many threads are still busy (hung) then."""
        for _ in self._threads:
            self._work.put(None)
        deadline = time.monotonic() + timeout
        for thread in self._threads:
            thread.join(max(0.0, deadline - time.monotonic()))
        return sum(thread.is_alive() for thread in self._threads)


class GroupCommitWriter:
    """Runs write jobs ``fn(session)`` on one thread, committing each batch once."""

    def __init__(
        self,
        sessions: sessionmaker[Session],
        *,
        max_batch: int = 64,
        gather_s: float = GATHER_S,
        preparers: int = PREPARERS,
        check: Check | None = None,
    ) -> None:
        self._sessions = sessions
        self._check = check
        """Checks, once per batch and in its transaction, that the camera tokens its jobs were
        accepted with still hold, and that their cameras still watch the panel and measure the
        region their frames were measured by. Processes keep the cameras they have seen for
        seconds (the token cache), so without it a token replaced or a camera retired through
        another process would go on storing frames here until then (with it those jobs get
        401), and a camera moved to another panel would go on judging the old one (those jobs
        get ``CameraChanged``, and are measured again)."""
        self._max_batch = max_batch
        self._gather_s = gather_s
        self._preparing = 0
        """Preparations submitted and not yet over (queued for a preparing thread or running):
        their jobs are on their way to the writer."""
        self._preparing_lock = threading.Lock()
        self._quiet = threading.Event()
        """Set when the last preparation under way is over: a batch gathering wakes then, or
        when its time is up, and not at each job queued (``_take_batch``)."""
        self._preparers = preparers
        self._pool: _Preparers | None = None
        """Threads that run ``submit_after``'s preparation (decoding, the file write)."""
        engine: Engine = sessions.kw["bind"]
        # The writer keeps one connection checked out from batch to batch, where a checkout per
        # batch would ping the server first (pool_pre_ping): a round trip and ~80 µs of CPU
        # (checkout and return: 86 µs with the ping, 8 without), at two or three frames a
        # batch under load. After any failure the connection goes back and the
        # next batch checks out a pinged one; a batch that failed because the kept connection
        # was lost (a restart, an idle timeout) is run once more. Not on SQLite, whose pool
        # has the one connection every request shares.
        self._engine = engine if engine.dialect.name != "sqlite" else None
        self._held: Connection | None = None
        self._holding = False
        """Set while the writer's thread runs its loop, which releases the connection at exit."""
        self._queue: queue.SimpleQueue[_Job | None] = queue.SimpleQueue()
        self._thread: threading.Thread | None = None
        self._lock = threading.Lock()

    @property
    def preparers(self) -> int:
        """How many preparations run at once (the size of the preparing pool)."""
        return self._preparers

    def start(self) -> None:
        with self._lock:
            if self._thread is None or not self._thread.is_alive():
                self._thread = threading.Thread(
                    target=self._run, name="vantage-writer", daemon=True
                )
                self._thread.start()
            if self._pool is None:
                self._pool = _Preparers(self._preparers, "vantage-prepare")

    def stop(self, timeout: float = 10.0) -> None:
        """Finish the preparations under way (at most ``timeout`` seconds: one hung in the frame
        store is left behind, its request answered long ago) and the batches queued."""
        with self._lock:
            thread, self._thread = self._thread, None
            pool, self._pool = self._pool, None
        if pool is not None:  # first: a preparation that finishes still queues its job
            if hung := pool.shutdown(timeout):
                log.error(
                    "%d preparation(s) still running after %g s (the frame store hung?): "
                    "stopping without them",
                    hung,
                    timeout,
                )
        if thread is not None:
            self._queue.put(None)
            thread.join(timeout=30)

    def run(self, fn: Callable[[Session], T], *, credential: Credential | None = None) -> T:
        """Run ``fn(session)`` in the next batch; return its result once the batch committed.

        Called from a thread, which it blocks (never the event loop; the ingest path uses
        ``submit_after``). ``fn`` must also accept ``retry=True``: it is run once more that
        way, alone, when its batch hit a unique-constraint conflict.
        """
        if self._thread is None:
            self.start()
        future: Future[T] = Future()
        self._queue.put(_Job(fn, future, credential=credential))
        return future.result()

    def submit_after(
        self,
        prepare: Callable[[], Callable[[Session], T]],
        *,
        credential: Credential | None = None,
    ) -> asyncio.Future[T]:
        """Run ``prepare()`` on one of the writer's preparing threads (at most ``preparers`` at
        once, the rest queue), then the job it returns in the next batch; await the returned
        future for the job's result once its batch committed. No thread waits for the commit.

        The preparing thread queues the job itself, and each batch's results reach an event
        loop in one call, so a frame wakes the loop once. When ``prepare`` raises, the future
        gets its exception. A request cancelled before its preparation ends queues no job.
        Must be called on the loop. With ``credential``, the job runs only if that camera token
        still holds in its batch (else the future gets ``Unauthorized``), and its camera's view
        is the one the frame was measured by (else ``CameraChanged``).
        """
        pool = self._pool
        if pool is None:
            self.start()
            pool = self._pool
            assert pool is not None
        loop = asyncio.get_running_loop()
        future: asyncio.Future[T] = loop.create_future()
        # emptied once the request has its answer or gave up (its deadline): a preparation
        # not yet started then never starts, and the upload's body, which ``prepare`` holds,
        # is let go at once rather than when a thread takes it. With the frame store hung,
        # every thread stuck in it, uploads that had their 503 long ago stayed queued: 1500
        # frames of 735 kB held 1.1 GB, and once the store answered again all were decoded
        # and written for nobody.
        waiting = [prepare]
        future.add_done_callback(lambda _: waiting.clear())

        def work() -> None:
            try:
                preparation = waiting.pop()
            except IndexError:  # the request has its answer already
                self._prepared()
                return
            try:
                try:
                    job = preparation()
                except Exception as exc:
                    outcome: Outcome = (None, exc)
                    with contextlib.suppress(RuntimeError):  # the loop has closed: nobody waits
                        loop.call_soon_threadsafe(_settle, future, outcome)
                    return
                if not future.done():  # a read only: the loop alone settles or cancels it
                    self._queue.put(_Job(job, future, loop, credential, frame=True))
            finally:  # after the job is queued: a batch waiting for the last one wakes now
                self._prepared()

        with self._preparing_lock:
            self._preparing += 1
        pool.submit(work)
        return future

    def _prepared(self) -> None:
        with self._preparing_lock:
            self._preparing -= 1
            if self._preparing <= 0:
                self._quiet.set()

    def _take_batch(self) -> list[_Job] | None:
        """The next jobs, at most ``max_batch``, leaving out those whose request gave up
        waiting (its future cancelled: an upload past its deadline got its 503, and nothing
        is stored behind its back). None once stopped."""
        batch: list[_Job] = []
        while not batch:
            first = self._queue.get()
            if first is None:
                return None
            batch = [first] if not first.future.cancelled() else []
            until = time.monotonic() + self._gather_s
            while len(batch) < self._max_batch:
                try:
                    job = self._queue.get_nowait()
                except queue.Empty:
                    # the jobs of preparations under way, for a moment (``GATHER_S``)
                    self._quiet.clear()
                    wait = until - time.monotonic()
                    if not batch or self._preparing <= 0 or wait <= 0:
                        break
                    self._quiet.wait(wait)
                    continue
                if job is None:
                    self._queue.put(None)  # stop after this batch
                    break
                if not job.future.cancelled():  # a read only, as in ``work``
                    batch.append(job)
        return batch

    def _session(self) -> Session:
        if self._engine is None or not self._holding:
            return self._sessions()
        if self._held is None:
            self._held = self._engine.connect()
        return self._sessions(bind=self._held)

    def _release(self) -> None:
        """Give the kept connection back to the pool (which drops it if it was lost)."""
        held, self._held = self._held, None
        if held is not None:
            try:
                held.close()
            except Exception:  # a dead connection: the pool has it invalidated already
                log.warning("closing the writer's connection failed", exc_info=True)

    def _run(self) -> None:
        self._holding = True
        try:
            self._loop()
        finally:
            self._holding = False
            self._release()

    def _loop(self) -> None:
        while (batch := self._take_batch()) is not None:
            if frames := sum(job.frame for job in batch):
                WRITER_BATCH_FRAMES.observe(frames)
            outcomes = self._write(batch)
            to_loops: dict[asyncio.AbstractEventLoop, list[tuple[asyncio.Future[Any], Outcome]]]
            to_loops = {}
            for job, outcome in zip(batch, outcomes, strict=True):
                if job.loop is None:
                    _settle(job.future, outcome)
                else:
                    to_loops.setdefault(job.loop, []).append((job.future, outcome))  # type: ignore[arg-type]
            for loop, settled in to_loops.items():
                try:
                    loop.call_soon_threadsafe(_settle_all, settled)
                except RuntimeError:  # the loop has closed: nobody waits for these
                    log.warning("%d results for a closed event loop dropped", len(settled))

    def _once(self, job: _Job, first: Exception) -> Outcome:
        try:
            with self._session() as session:
                refused = self._refused_in(session, [job])  # checked again, as in any batch
                if job.credential in refused:
                    return (None, _refused(refused[job.credential]))
                result = job.fn(session, retry=True)
                session.commit()
            return (result, None)
        except Exception:
            self._release()
            return (None, first)

    def _refused_in(self, session: Session, batch: list[_Job]) -> dict[Credential, Refusal]:
        """The batch's credentials that no longer hold: one query for the whole batch."""
        if self._check is None:
            return {}
        credentials = {job.credential for job in batch if job.credential is not None}
        return self._check(session, credentials) if credentials else {}

    def _write(self, batch: list[_Job], *, again: bool = True) -> list[Outcome]:
        try:
            with self._session() as session:
                refused = self._refused_in(session, batch)
                with deferred_inserts(session):  # one INSERT per table for the batch
                    outcomes: list[Outcome] = [
                        (None, _refused(refused[job.credential]))
                        if job.credential in refused
                        else (job.fn(session), None)
                        for job in batch
                    ]
                session.commit()
            return outcomes
        except Exception as exc:
            held = self._held is not None
            self._release()  # the next attempt checks out a pinged connection
            lost = isinstance(exc, DBAPIError) and exc.connection_invalidated
            if again and held and lost:
                return self._write(batch, again=False)  # the kept connection was lost
            raced = _lost_a_race(exc)
            if len(batch) == 1 and (isinstance(exc, IntegrityError) or raced):
                # another process stored the same frame meanwhile: once more, the job now sees
                # it (an idempotent replay) or fails for good; or the job lost a deadlock
                return [self._once(batch[0], exc)]
            if len(batch) == 1 or (database_unavailable(exc) and not raced):
                # the database down fails every job alike: trying each alone would wait out
                # the connect timeout once per job (64 × 5 s) before the next batch
                return [(None, exc)] * len(batch)
        # isolate the failure: one transaction per job
        return [outcome for job in batch for outcome in self._write([job])]
