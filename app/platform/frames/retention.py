"""Frame retention: old frames go (rows and bytes); frames something still needs stay.

Rows and images may have retentions of their own: with ``history_days`` longer than ``days``,
a frame's image goes after ``days`` (its row then says it has none) and its row, with the
verdict and reading, after ``history_days``: a city keeps a year of trends without a year of
photos.

Kept whatever their age: frames a baseline or an air calibration was trained from, and frames
an alert points at. On disk, frames live in packs, one per process and hour of reception
(``storage``): once an hour has expired, the kept frames among its packs are
copied into a current pack and the packs deleted, taking with them the frames whose rows went
and any bytes a killed process wrote without committing their row. A frame stored as a file or
object of its own goes when no frame row refers to it any more (identical frames share one).
At start-up, files that no row refers to are swept too, once they are old enough not to be in
flight, and so are packs that no row refers to and no live process holds open.
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Callable, Collection, Generator, Iterable, Iterator
from contextlib import closing
from dataclasses import dataclass
from datetime import datetime, timedelta
from itertools import islice

from sqlalchemy import ColumnElement, delete, select, update
from sqlalchemy.orm import Session, sessionmaker

from app.platform import outbox
from app.platform.background import in_thread
from app.platform.db.models import Frame, Verdict
from app.platform.frames.kinds import KINDS
from app.platform.frames.storage import FrameStore, pack_of
from app.platform.timing import Timing

log = logging.getLogger("vantage.retention")

BATCH = 2000


@dataclass(frozen=True, slots=True)
class Swept:
    frames: int
    """Frames deleted, rows and images."""
    files: int
    """Frames' files or objects deleted, and packs."""
    images: int = 0
    """Frames whose image was deleted and row kept (``history_days``)."""


def _kept(session: Session) -> set[str]:
    """Frames some kind still needs (``KindHandler.kept_frames``)."""
    keep: set[str] = set()
    for handler in KINDS.handlers.values():
        keep.update(handler.kept_frames(session))
    return keep


def kept_days(days: float, history_days: float | None) -> float:
    """How long frames' rows are kept [d]: ``history_days`` when set, never less than ``days``
    (the images')."""
    return max(days, history_days or days)


def sweep(
    sessions: sessionmaker[Session],
    store: FrameStore,
    timing: Timing,
    days: float,
    history_days: float | None = None,
) -> Swept:
    """Delete frames received more than ``history_days`` (default ``days``) ago, their files,
    the images of those received more than ``days`` ago, the expired packs, and webhook events
    older than ``outbox.KEEP_FOR``."""
    now = timing.now()
    cutoff = now - timedelta(days=kept_days(days, history_days))
    frames, files = _in_batches(sessions, store, [Frame.received_at < cutoff], _delete_rows)
    images = 0
    cutoff = now - timedelta(days=days)
    if history_days is not None and history_days > days:
        images, dropped = _in_batches(
            sessions,
            store,
            [Frame.received_at < cutoff, Frame.stored_path.is_not(None)],
            _forget_images,
        )
        files += dropped
    if packs := store.expired_packs(cutoff):
        _move_kept(sessions, store, timing, set(packs), cutoff)
        store.delete_packs(packs)
        files += len(packs)
    outbox.forget_old(sessions, now)  # webhook events: kept 30 days, delivered or not
    return Swept(frames, files, images)


def _delete_rows(session: Session, ids: list[str]) -> None:
    for handler in KINDS.handlers.values():  # the kinds' own verdict tables first
        if (table := handler.verdict_table) is not None:
            session.execute(delete(table).where(table.frame_id.in_(ids)))
    session.execute(delete(Verdict).where(Verdict.frame_id.in_(ids)))
    session.execute(delete(Frame).where(Frame.id.in_(ids)))


def _forget_images(session: Session, ids: list[str]) -> None:
    """The rows stay, saying the frame has no image any more."""
    session.execute(update(Frame).where(Frame.id.in_(ids)).values(stored_path=None))


def _in_batches(
    sessions: sessionmaker[Session],
    store: FrameStore,
    where: list[ColumnElement[bool]],
    act: Callable[[Session, list[str]], None],
) -> tuple[int, int]:
    """``act`` on the frames matching ``where`` that nothing keeps, ``BATCH`` at a time, each
    batch committed before the files of their own that no row refers to any more are deleted
    (which identical frames may share; a frame in a pack goes with its pack). Returns (frames,
    files)."""
    frames = files = 0
    while True:
        with sessions() as session:
            keep = _kept(session)
            rows = session.execute(
                select(Frame.id, Frame.stored_path)
                .where(*where)
                .order_by(Frame.received_at)
                .limit(BATCH + len(keep))
            ).all()
            doomed = [r for r in rows if r[0] not in keep][:BATCH]
            if not doomed:
                return frames, files
            act(session, [r[0] for r in doomed])
            paths = {r[1] for r in doomed if r[1] is not None and pack_of(r[1]) is None}
            still = _referenced(session, paths)
            session.commit()
        gone = sorted(paths - still)
        store.delete(gone)
        files += len(gone)
        frames += len(doomed)


def _move_kept(
    sessions: sessionmaker[Session],
    store: FrameStore,
    timing: Timing,
    packs: set[str],
    cutoff: datetime,
) -> None:
    """Copy the frames still referred to out of ``packs`` (their hours expired) into a current
    pack, and point their rows there. Every frame in such a pack was received before
    ``cutoff``, so after the sweep of rows only kept frames are left to look at."""
    with sessions() as session:
        rows = session.execute(
            select(Frame.id, Frame.stored_path, Frame.sha256).where(
                Frame.received_at < cutoff, Frame.stored_path.like("packs/%")
            )
        ).all()
    moves = []
    now = timing.now()
    for frame_id, path, sha256 in rows:
        if path is None or pack_of(path) not in packs:
            continue
        data = store.read(path)
        if data is None:  # another process moved it and deleted the pack meanwhile
            continue
        moves.append((frame_id, path, store.put(data, sha256, now)))
    with sessions() as session:
        for frame_id, old, new in moves:
            # unless another process's sweep moved it first
            session.execute(
                update(Frame)
                .where(Frame.id == frame_id, Frame.stored_path == old)
                .values(stored_path=new)
            )
        session.commit()
    if moves:
        log.info("kept frames moved out of expired packs", extra={"frames": len(moves)})


def sweep_orphans(
    sessions: sessionmaker[Session], store: FrameStore, *, min_age_s: float = 600
) -> int:
    """Delete stored files no frame row refers to, if older than ``min_age_s``: files and
    objects of their own, and packs that no live process writes to and none of whose frames
    has a row (a process killed before the first commit into a new pack)."""
    removed = 0
    for chunk in _chunks(store.older_than(min_age_s), FILE_CHUNK):
        with sessions() as session:
            used = _referenced(session, chunk)
        unused = [p for p in chunk if p not in used]
        store.delete(unused)
        removed += len(unused)
    packs = [
        pack
        for pack in store.idle_packs(min_age_s)
        if not _any_referenced(sessions, store.pack_locators(pack))
    ]
    store.delete_packs(packs)
    removed += len(packs)
    if removed:
        log.warning("removed %d frame files or packs that no row referred to", removed)
    return removed


FILE_CHUNK = 1000
"""Files of their own are looked up this many at a time."""

PACK_CHUNK = 100
"""A pack's frames are looked up this many at a time. Its first frames nearly always have
rows, so most packs are answered by their first headers, not read through (a full pack holds
thousands of frames, and the sweep runs at every start)."""


def _chunks(items: Iterable[str], size: int) -> Iterator[list[str]]:
    it = iter(items)
    while chunk := list(islice(it, size)):
        yield chunk


def _referenced(session: Session, locators: Collection[str]) -> set[str]:
    """Those of ``locators`` some frame row refers to (``ix_frames_stored_path``)."""
    if not locators:
        return set()
    return set(session.scalars(select(Frame.stored_path).where(Frame.stored_path.in_(locators))))


def _any_referenced(sessions: sessionmaker[Session], locators: Generator[str, None, None]) -> bool:
    with closing(locators), sessions() as session:
        return any(_referenced(session, chunk) for chunk in _chunks(locators, PACK_CHUNK))


async def run(
    sessions: sessionmaker[Session],
    store: FrameStore,
    timing: Timing,
    days: float,
    every: float,
    history_days: float | None = None,
) -> None:
    """The retention sweep every ``every`` seconds (the first after one interval)."""
    while True:
        await asyncio.sleep(every)
        try:
            swept = await in_thread(sweep, sessions, store, timing, days, history_days)
            if swept.frames or swept.images:
                log.info(
                    "retention sweep",
                    extra={"frames": swept.frames, "files": swept.files, "images": swept.images},
                )
        except Exception:
            log.exception("retention sweep failed")
