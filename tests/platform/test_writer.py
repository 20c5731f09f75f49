"""The group-commit writer and its held-back inserts, on the test database (SQLite or
PostgreSQL): rows sent together, still visible to every later statement of the batch, and a
conflicting job failing alone."""

from __future__ import annotations

import asyncio
import gc
import threading
import time
import weakref
from collections.abc import Iterator
from concurrent.futures import Future
from datetime import UTC, datetime, timedelta
from functools import partial
from typing import Any

import pytest
from sqlalchemy import Engine, event, func, inspect, select, text
from sqlalchemy.orm import Session, sessionmaker

from app.air.models import AirAlert, SkyVerdict
from app.platform.db import rows
from app.platform.db.models import Camera, CameraKind, Frame, Verdict
from app.platform.db.rows import deferred_inserts, insert_rows
from app.platform.db.session import make_engine, make_sessionmaker
from app.platform.frames import cameras as registry
from app.platform.frames.camera_info import view_of
from app.platform.frames.writer import CameraChanged, Credential, GroupCommitWriter, Refusal, _Job
from app.platform.http.errors import Unauthorized
from app.solar.models import Panel, PanelVerdict
from tests.factories import empty_tables

T0 = datetime(2026, 6, 1, 12, tzinfo=UTC)


@pytest.fixture
def sessions(database_url: str, engine: Engine) -> Iterator[sessionmaker[Session]]:
    empty_tables(engine)
    app_engine = make_engine(database_url)  # with the service's listeners
    sm = make_sessionmaker(app_engine)
    with sm() as s:
        s.add(Camera(id="cam", kind=CameraKind.rig, token_hash="h"))
        s.commit()
    yield sm
    app_engine.dispose()


def frame_and_verdict(n: int, *, key: str | None = None, stored: bool = True) -> list[Any]:
    frame = Frame(
        id=f"f{n:04d}",
        camera_id="cam",
        captured_at=T0 + timedelta(seconds=n),
        received_at=T0,
        width=64,
        height=48,
        size_bytes=100,
        sha256=f"{n:064d}",
        idempotency_key=key,
    )
    if stored:  # a frame without a stored file leaves the column unset: another column set
        frame.stored_path = f"frames/{n}.jpg"
    verdict = Verdict(
        frame_id=frame.id, camera_id="cam", mode_r=1, mode_g=2, mode_b=3,
        mean_r=1.0, mean_g=2.0, mean_b=3.0,
    )  # fmt: skip
    return [frame, verdict]


def inserts_sent(
    sm: sessionmaker[Session],
    monkeypatch: pytest.MonkeyPatch,
    copies: list[int] | None = None,
    multirow: list[int] | None = None,
) -> list[int]:
    """Records the number of rows in each INSERT the engine executes (executemany counts all),
    in each COPY (PostgreSQL; also in ``copies``) and in each multi-row INSERT sent on the
    driver's cursor (SQLite; also in ``multirow``)."""
    sent: list[int] = []
    engine = sm.kw["bind"]

    @event.listens_for(engine, "before_cursor_execute")
    def count(_c: Any, _cur: Any, statement: str, params: Any, _ctx: Any, many: bool) -> None:
        if statement.lstrip().upper().startswith("INSERT"):
            sent.append(len(params) if many else 1)

    copy, values = rows._copy, rows._values

    def count_copy(connection: Any, plan: Any, batch: list[Any]) -> None:
        sent.append(len(batch))
        if copies is not None:
            copies.append(len(batch))
        copy(connection, plan, batch)

    def count_values(connection: Any, plan: Any, batch: list[Any]) -> None:
        sent.append(len(batch))
        if multirow is not None:
            multirow.append(len(batch))
        values(connection, plan, batch)

    monkeypatch.setattr(rows, "_copy", count_copy)
    monkeypatch.setattr(rows, "_values", count_values)
    return sent


def test_held_back_inserts_go_as_one_statement_per_table_and_column_set(
    sessions: sessionmaker[Session], monkeypatch: pytest.MonkeyPatch
) -> None:
    copies: list[int] = []
    multirow: list[int] = []
    sent = inserts_sent(sessions, monkeypatch, copies, multirow)
    with sessions() as s:
        with deferred_inserts(s):
            for n in range(6):
                insert_rows(s, *frame_and_verdict(n, stored=n % 3 != 0))
            assert sent == []  # nothing sent yet
        s.commit()
    # frames without a stored path (2, the first used), frames with one (4), then the verdicts
    # (6): by table in the order first used, which keeps every verdict after its frame
    assert sent == [2, 4, 6]
    # PostgreSQL: each as one COPY; SQLite: each as one multi-row INSERT
    dialect = sessions.kw["bind"].dialect.name
    assert copies == ([2, 4, 6] if dialect == "postgresql" else [])
    assert multirow == ([2, 4, 6] if dialect == "sqlite" else [])
    with sessions() as s:
        assert s.scalar(select(func.count()).select_from(Frame)) == 6
        assert s.scalar(select(func.count()).select_from(Verdict)) == 6
        unstored = s.scalars(select(Frame.id).where(Frame.stored_path.is_(None))).all()
        assert sorted(unstored) == ["f0000", "f0003"]


def test_a_read_in_the_batch_sees_the_rows_held_back(sessions: sessionmaker[Session]) -> None:
    with sessions() as s:
        with deferred_inserts(s):
            insert_rows(s, *frame_and_verdict(1))
            assert s.scalar(select(func.count()).select_from(Frame)) == 1
            insert_rows(s, *frame_and_verdict(2))
            assert s.scalar(select(func.count()).select_from(Verdict)) == 2
        s.commit()


def test_outside_a_batch_inserts_are_sent_at_once(
    sessions: sessionmaker[Session], monkeypatch: pytest.MonkeyPatch
) -> None:
    sent = inserts_sent(sessions, monkeypatch)
    with sessions() as s:
        insert_rows(s, *frame_and_verdict(1))
        assert sent == [1, 1]
        s.rollback()


def test_a_conflicting_job_is_run_again_alone_and_the_rest_of_its_batch_is_stored(
    sessions: sessionmaker[Session],
) -> None:
    with sessions() as s:
        insert_rows(s, *frame_and_verdict(7, key="k"))
        s.commit()

    def job(n: int, key: str | None = None) -> Any:
        def fn(session: Session, retry: bool = False) -> str:
            if retry:  # run again alone after a conflict: the stored frame with this key
                original = session.scalar(select(Frame.id).where(Frame.idempotency_key == key))
                return f"replay of {original}"
            insert_rows(session, *frame_and_verdict(n, key=key))
            return "stored"

        return fn

    writer = GroupCommitWriter(sessions)
    # the middle job repeats the stored frame's idempotency key: only it conflicts, and only
    # when the held-back rows are sent at the batch's end
    batch = [_Job(job(1), Future()), _Job(job(8, key="k"), Future()), _Job(job(2), Future())]
    outcomes = writer._write(batch)
    assert outcomes == [("stored", None), ("replay of f0007", None), ("stored", None)]
    with sessions() as s:
        ids = s.scalars(select(Frame.id).order_by(Frame.id)).all()
        assert ids == ["f0001", "f0002", "f0007"]
        assert s.scalar(select(func.count()).select_from(Verdict)) == 3


def test_a_batch_checks_its_cameras_once_and_refuses_only_the_jobs_that_no_longer_hold(
    sessions: sessionmaker[Session],
) -> None:
    # "other": its token was replaced since its job was taken; "moved": it measures another
    # region now (both through another process, whose cached snapshots these jobs carry)
    with sessions() as s:
        s.add(Camera(id="other", kind=CameraKind.rig, token_hash="new"))
        s.add(Camera(id="moved", kind=CameraKind.rig, token_hash="m", roi=[0, 0, 32, 24]))
        s.commit()
    asked: list[set[Credential]] = []

    def check(session: Session, credentials: set[Credential]) -> dict[Credential, Refusal]:
        asked.append(set(credentials))
        return registry.refusals(session, credentials)

    cam = ("cam", "h", view_of("rig", None, None))
    old_view = view_of("rig", None, [0, 0, 64, 48])
    writer = GroupCommitWriter(sessions, check=check)
    batch = [
        _Job(_storing(1), Future(), credential=cam),
        _Job(_storing(2), Future(), credential=("other", "old", view_of("rig", None, None))),
        _Job(_storing(3), Future()),  # nothing to check
        _Job(_storing(4), Future(), credential=cam),
        _Job(_storing(5), Future(), credential=("moved", "m", old_view)),
        _Job(_storing(6), Future(), credential=("moved", None, old_view)),  # the admin token's
        _Job(
            _storing(7), Future(), credential=("moved", "m", view_of("rig", None, [0, 0, 32, 24]))
        ),
        # its snapshot of another kind (the camera's kind was changed through another process)
        _Job(
            _storing(8), Future(), credential=("moved", "m", view_of("sky", None, [0, 0, 32, 24]))
        ),
    ]
    outcomes = writer._write(batch)
    assert len(asked) == 1  # one query for the batch
    assert [o[0] for o in outcomes] == ["f0001", None, "f0003", "f0004", None, None, "f0007", None]
    revoked = outcomes[1][1]
    assert isinstance(revoked, Unauthorized)
    assert revoked.status == 401
    assert isinstance(outcomes[4][1], CameraChanged)
    assert isinstance(outcomes[5][1], CameraChanged)
    assert isinstance(outcomes[7][1], CameraChanged)
    with sessions() as s:
        stored = s.scalars(select(Frame.id).order_by(Frame.id)).all()
        assert stored == ["f0001", "f0003", "f0004", "f0007"]
        assert s.scalar(select(func.count()).select_from(Verdict)) == 4


def test_a_cameras_view_as_the_driver_reads_it_is_its_view_as_cached(
    sessions: sessionmaker[Session],
) -> None:
    """The check compares the view the snapshot was built from (the ORM's JSON) with the one
    the driver reads (JSON text on SQLite, parsed on PostgreSQL): equal for every kind of
    region, or every frame would be measured again."""
    from app.platform.frames.camera_info import CameraInfo

    regions: list[Any] = [None, [0, 60, 640, 300], [[0, 0], [640, 0], [640, 200], [0, 300]]]
    with sessions() as s:
        s.add(Panel(id="p1"))
        s.flush()
        for k, roi in enumerate(regions):
            s.add(
                Camera(
                    id=f"v{k}", kind=CameraKind.panel, panel_id="p1", token_hash=f"t{k}", roi=roi
                )
            )
        s.commit()
        credentials = {
            CameraInfo.of(c).credential
            for c in s.scalars(select(Camera).where(Camera.id.like("v%")))
        }
    with sessions() as s:
        credentials = {(cid, f"t{cid[1:]}", view) for cid, _, view in credentials}
        assert len(credentials) == 3
        assert registry.refusals(s, credentials) == {}


def test_a_conflicting_job_run_again_alone_is_checked_again(
    sessions: sessionmaker[Session],
) -> None:
    """The camera's token is replaced between the batch that conflicted and the job's run alone:
    the run alone checks it again (every transaction that stores a frame does)."""
    with sessions() as s:
        insert_rows(s, *frame_and_verdict(7, key="k"))
        s.commit()
    answers = iter([{}, None])

    def check(session: Session, credentials: set[Credential]) -> dict[Credential, Refusal]:
        found = next(answers)
        return found if found is not None else dict.fromkeys(credentials, "revoked")

    def fn(session: Session, retry: bool = False) -> str:
        if retry:
            return "replay"
        insert_rows(session, *frame_and_verdict(8, key="k"))
        return "stored"

    writer = GroupCommitWriter(sessions, check=check)
    outcomes = writer._write([_Job(fn, Future(), credential=("cam", "h", None))])
    assert outcomes[0][0] is None
    assert isinstance(outcomes[0][1], Unauthorized)


def test_a_select_through_the_driver_sees_the_rows_held_back_before_it(
    sessions: sessionmaker[Session],
) -> None:
    with sessions() as s, deferred_inserts(s):
        insert_rows(s, *frame_and_verdict(1))
        insert_rows(s, *frame_and_verdict(2))
        found = rows.select_rows(
            s, "SELECT id FROM frames WHERE camera_id = ? AND id IN (?, ?)", ["cam", "f0002", "x"]
        )
        assert found == [("f0002",)]


def test_jobs_posted_at_once_are_all_committed(sessions: sessionmaker[Session]) -> None:
    from concurrent.futures import ThreadPoolExecutor

    writer = GroupCommitWriter(sessions)
    writer.start()
    try:

        def post(n: int) -> str:
            def fn(session: Session, retry: bool = False) -> str:
                insert_rows(session, *frame_and_verdict(n))
                return f"f{n:04d}"

            return writer.run(fn)

        with ThreadPoolExecutor(16) as pool:
            done = list(pool.map(post, range(200)))
    finally:
        writer.stop()
    assert done == [f"f{n:04d}" for n in range(200)]
    with sessions() as s:
        assert s.scalar(select(func.count()).select_from(Frame)) == 200
        assert s.scalar(select(func.count()).select_from(Verdict)) == 200


def _storing(n: int) -> Any:
    def fn(session: Session, retry: bool = False) -> str:
        insert_rows(session, *frame_and_verdict(n))
        return f"f{n:04d}"

    return fn


def test_jobs_prepared_in_the_writers_threads_are_committed_and_answered(
    sessions: sessionmaker[Session],
) -> None:
    writer = GroupCommitWriter(sessions, preparers=4)
    prepared_in: set[str] = set()

    def prepare(n: int) -> Any:
        prepared_in.add(threading.current_thread().name)
        return _storing(n)

    async def post_all() -> list[str]:
        return await asyncio.gather(*(writer.submit_after(partial(prepare, n)) for n in range(60)))

    try:
        done = asyncio.run(post_all())
    finally:
        writer.stop()
    assert done == [f"f{n:04d}" for n in range(60)]
    assert prepared_in
    assert all(name.startswith("vantage-prepare") for name in prepared_in)
    assert len(prepared_in) <= 4
    with sessions() as s:
        assert s.scalar(select(func.count()).select_from(Frame)) == 60


def _batch_sizes(writer: GroupCommitWriter, monkeypatch: pytest.MonkeyPatch) -> list[int]:
    sizes: list[int] = []
    write = writer._write

    def counting(batch: list[_Job], **kw: Any) -> Any:
        sizes.append(len(batch))
        return write(batch, **kw)

    monkeypatch.setattr(writer, "_write", counting)
    return sizes


@pytest.mark.parametrize("gather_s", [0.0, 60.0])
def test_a_batch_waits_for_the_jobs_of_preparations_under_way(
    sessions: sessionmaker[Session], monkeypatch: pytest.MonkeyPatch, gather_s: float
) -> None:
    """A frame whose job reaches the writer while another's preparation is still running is
    committed with it, in one batch (``GATHER_S``), not in a batch of its own; a batch stops
    waiting as soon as no preparation is under way (the 60 s are never waited out: the test
    would time out)."""
    writer = GroupCommitWriter(sessions, preparers=2, gather_s=gather_s)
    sizes = _batch_sizes(writer, monkeypatch)
    first_queued = threading.Event()

    def first() -> Any:
        return _storing(1)

    def second() -> Any:
        first_queued.wait(10)
        time.sleep(0.05)  # the first job is with the writer by now
        return _storing(2)

    async def post() -> list[str]:
        a = writer.submit_after(first)
        b = writer.submit_after(second)
        loop = asyncio.get_running_loop()
        loop.call_later(0.02, first_queued.set)
        return list(await asyncio.wait_for(asyncio.gather(a, b), 30))

    try:
        done = asyncio.run(post())
    finally:
        writer.stop()
    assert done == ["f0001", "f0002"]
    assert sizes == ([2] if gather_s else [1, 1])


def test_a_lone_frame_is_not_held_for_others(
    sessions: sessionmaker[Session], monkeypatch: pytest.MonkeyPatch
) -> None:
    """With no other preparation under way, a batch waits for nothing: a lone camera's frame
    is not held back by ``GATHER_S`` (here 60 s, which the 30 s bound would catch)."""
    writer = GroupCommitWriter(sessions, preparers=2, gather_s=60.0)
    sizes = _batch_sizes(writer, monkeypatch)

    async def post(n: int) -> str:
        result: str = await asyncio.wait_for(writer.submit_after(lambda: _storing(n)), 30)
        return result

    try:
        assert asyncio.run(post(1)) == "f0001"
        assert asyncio.run(post(2)) == "f0002"
    finally:
        writer.stop()
    assert sizes == [1, 1]


def test_a_failed_preparation_reaches_its_caller_and_stores_nothing(
    sessions: sessionmaker[Session],
) -> None:
    writer = GroupCommitWriter(sessions)

    def broken() -> Any:
        raise ValueError("not a JPEG")

    async def post() -> tuple[BaseException | str, ...]:
        results = await asyncio.gather(
            writer.submit_after(broken),
            writer.submit_after(lambda: _storing(1)),
            return_exceptions=True,
        )
        return tuple(results)

    try:
        failed, stored = asyncio.run(post())
    finally:
        writer.stop()
    assert isinstance(failed, ValueError)
    assert str(failed) == "not a JPEG"
    assert stored == "f0001"
    with sessions() as s:
        assert s.scalars(select(Frame.id)).all() == ["f0001"]


def test_a_request_cancelled_while_preparing_queues_no_job(
    sessions: sessionmaker[Session],
) -> None:
    writer = GroupCommitWriter(sessions)
    release = threading.Event()

    def slow() -> Any:
        release.wait(10)
        return _storing(1)

    async def post_then_cancel() -> None:
        future = writer.submit_after(slow)
        await asyncio.sleep(0.05)
        future.cancel()
        release.set()

    try:
        asyncio.run(post_then_cancel())
    finally:
        writer.stop()  # waits for the preparation, then for the queue to drain
    with sessions() as s:
        assert s.scalar(select(func.count()).select_from(Frame)) == 0


def test_uploads_that_gave_up_behind_stuck_threads_let_go_of_their_bodies_at_once(
    sessions: sessionmaker[Session],
) -> None:
    """Every preparing thread stuck (in a frame store that hangs): the uploads queued behind
    them that give up (their deadline, a 503) let go of their bodies at once, and are never
    prepared, not even once the threads are free again. They stayed queued with their bodies
    (1500 uploads held 1.1 GB), and were all decoded and stored for nobody once the store
    answered."""
    writer = GroupCommitWriter(sessions, preparers=1)
    release = threading.Event()
    prepared: list[int] = []

    class Body:  # an upload's bytes, which its preparation holds
        pass

    def prepare(n: int, body: Body) -> Any:
        if n == 0:
            release.wait(10)  # the one thread, stuck
        prepared.append(n)
        return _storing(n)

    bodies = [Body() for _ in range(4)]
    held = [weakref.ref(b) for b in bodies]

    async def post() -> None:
        futures = [writer.submit_after(partial(prepare, n, b)) for n, b in enumerate(bodies)]
        await asyncio.sleep(0.05)
        for f in futures[1:]:
            f.cancel()  # as at the upload's deadline
        await asyncio.sleep(0)  # the futures' callbacks run
        bodies.clear()
        gc.collect()
        assert [ref() is None for ref in held] == [False, True, True, True]
        release.set()
        assert await futures[0] == "f0000"

    try:
        asyncio.run(post())
    finally:
        writer.stop()
    assert prepared == [0]
    with sessions() as s:
        assert s.scalars(select(Frame.id)).all() == ["f0000"]


def test_stop_lets_preparations_in_flight_finish_and_commits_their_jobs(
    sessions: sessionmaker[Session],
) -> None:
    writer = GroupCommitWriter(sessions)
    started = threading.Event()

    def slow() -> Any:
        started.set()
        time.sleep(0.2)
        return _storing(3)

    async def post_then_stop() -> asyncio.Future[Any]:
        future = writer.submit_after(slow)
        await asyncio.to_thread(started.wait, 10)
        await asyncio.to_thread(writer.stop)
        await asyncio.sleep(0)  # the batch's results reach the loop
        return future

    future = asyncio.run(post_then_stop())
    assert future.result() == "f0003"
    with sessions() as s:
        assert s.scalars(select(Frame.id)).all() == ["f0003"]


def test_rows_sent_together_read_back_as_rows_sent_alone(sessions: sessionmaker[Session]) -> None:
    """Every column type of the verdicts (joined tables, enum, JSON, NULLs, floats) the same
    whichever way the rows went: together (COPY on PostgreSQL, one multi-row INSERT on SQLite)
    or one INSERT each."""

    def rows_for(prefix: str) -> list[Any]:
        out: list[Any] = []
        for n in range(3):
            frame = Frame(
                id=f"{prefix}{n}", camera_id="cam", captured_at=T0 + timedelta(seconds=n),
                received_at=T0 + timedelta(microseconds=123456), width=64, height=48,
                size_bytes=2**40, sha256=f"{prefix}{n:063d}",
                stored_path=None if n == 0 else f"packs/x.pack@{n}+1",
            )  # fmt: skip
            common = dict(
                frame_id=frame.id, camera_id="cam", mode_r=n, mode_g=255, mode_b=0,
                mean_r=0.1 * n, mean_g=1e-300, mean_b=254.999,
            )  # fmt: skip
            verdict: Verdict
            if n == 0:
                verdict = PanelVerdict(
                    **common, reason="night", details={"quality": {"dark": 0.9}, "ok": None}
                )
            elif n == 1:
                verdict = PanelVerdict(
                    **common, clean=False, t2=12.5, f_stat=3.25, p_value=1e-9, state="dirty",
                    method="baseline", details=None,
                )  # fmt: skip
            else:
                verdict = SkyVerdict(
                    **common, level=7, category="Good", statistic=0.5, smoothed_level=6.75,
                    details={"features": [1.5, -2.0, 3]},
                )  # fmt: skip
            out += [frame, verdict]
        return out

    with sessions() as s:
        with deferred_inserts(s):
            insert_rows(s, *rows_for("a"))
        for obj in rows_for("b"):
            insert_rows(s, obj)
        s.commit()

    def read(prefix: str) -> list[tuple[Any, ...]]:
        with sessions() as s:
            frames = s.scalars(select(Frame).where(Frame.id.startswith(prefix)).order_by(Frame.id))
            verdicts = s.scalars(
                select(Verdict)
                .where(Verdict.frame_id.startswith(prefix))
                .order_by(Verdict.frame_id)
            )
            out = []
            for obj in [*frames, *verdicts]:
                values = {
                    c.key: getattr(obj, c.key)
                    for c in inspect(obj).mapper.column_attrs
                    if c.key not in ("id", "frame_id", "sha256")
                }
                out.append((type(obj).__name__, values))
            return out

    batched, alone = read("a"), read("b")
    assert len(batched) == 6
    assert batched == alone
    assert batched[3][1]["details"] == {"quality": {"dark": 0.9}, "ok": None}
    assert batched[0][1]["received_at"] == T0 + timedelta(microseconds=123456)


def test_a_lost_connection_costs_no_job(sessions: sessionmaker[Session]) -> None:
    """PostgreSQL: the writer keeps its connection from batch to batch; when the server drops
    it (a restart, an idle timeout), the next batch runs again on a new connection."""
    engine = sessions.kw["bind"]
    if engine.dialect.name != "postgresql":
        pytest.skip("the writer keeps a connection only on PostgreSQL")

    def backend_pid(session: Session, retry: bool = False) -> int:
        return int(session.scalar(text("SELECT pg_backend_pid()")))

    def store(n: int) -> Any:
        def fn(session: Session, retry: bool = False) -> int:
            insert_rows(session, *frame_and_verdict(n))
            return backend_pid(session)

        return fn

    writer = GroupCommitWriter(sessions, check=registry.refusals)
    writer.start()
    try:
        first = writer.run(backend_pid)
        assert writer.run(backend_pid) == first  # the same connection, kept
        with engine.connect() as other:
            assert other.scalar(text("SELECT pg_terminate_backend(:pid)"), {"pid": first})
        # the batch's first statement is the check of its camera token, sent through the
        # driver itself: the lost connection is still told apart, and the batch run once more
        second = writer.run(store(1), credential=("cam", "h", view_of("rig", None, None)))
        assert second != first
    finally:
        writer.stop()
    with sessions() as s:
        assert s.scalars(select(Frame.id)).all() == ["f0001"]


def test_rows_leaving_out_a_python_default_are_inserted_with_it(
    sessions: sessionmaker[Session], monkeypatch: pytest.MonkeyPatch
) -> None:
    """COPY and a hand-built multi-row INSERT apply only the database's own defaults: rows that
    leave out a column whose default SQLAlchemy computes go as SQLAlchemy's INSERT, which
    applies it."""
    copies: list[int] = []
    multirow: list[int] = []
    sent = inserts_sent(sessions, monkeypatch, copies, multirow)
    with sessions() as s:
        insert_rows(s, *frame_and_verdict(1))
        s.commit()
    sent.clear()
    with sessions() as s:
        with deferred_inserts(s):
            for n in range(3):  # delivered and attempts left out: defaults False and 0
                insert_rows(
                    s,
                    AirAlert(
                        id=f"a{n}", camera_id="cam", frame_id="f0001", created_at=T0,
                        smoothed_level=2.0, category="Poor",
                    ),
                )  # fmt: skip
        s.commit()
    assert sent == [3]
    assert copies == multirow == []  # SQLAlchemy's INSERT (executemany)
    with sessions() as s:
        alerts = s.scalars(select(AirAlert).order_by(AirAlert.id)).all()
        assert [(a.delivered, a.attempts) for a in alerts] == [(False, 0)] * 3


def test_more_rows_than_one_sqlite_statement_may_bind_go_in_several(
    sessions: sessionmaker[Session],
) -> None:
    """SQLite (before 3.32) binds at most 999 parameters a statement: 200 frames of 10 columns
    go as three INSERTs (99, 99 and 2 rows), and all are stored."""
    if sessions.kw["bind"].dialect.name != "sqlite":
        pytest.skip("multi-row INSERTs are SQLite's way; PostgreSQL copies")
    executed: list[str] = []
    with sessions() as s:
        dbapi = s.connection().connection.dbapi_connection
        assert dbapi is not None
        dbapi.set_trace_callback(executed.append)  # type: ignore[attr-defined]
        try:
            with deferred_inserts(s):
                for n in range(200):
                    insert_rows(s, frame_and_verdict(n)[0])
            s.commit()
        finally:
            dbapi.set_trace_callback(None)  # type: ignore[attr-defined]
    inserts = [sql for sql in executed if sql.startswith("INSERT INTO frames")]
    assert [sql.count("), (") + 1 for sql in inserts] == [99, 99, 2]
    with sessions() as s:
        assert s.scalar(select(func.count()).select_from(Frame)) == 200


def test_batches_of_two_processes_that_deadlock_store_every_job(
    sessions: sessionmaker[Session],
) -> None:
    """PostgreSQL: two processes' batches take two cameras' rows in opposite orders (as sky
    frames do, ``air._lock_camera``, and panel frames their panels). The server ends the
    deadlock by failing one batch; its jobs are then run one transaction each, and every job of
    both batches is stored, where the whole losing batch used to fail (a 503 for each frame)."""
    engine = sessions.kw["bind"]
    if engine.dialect.name != "postgresql":
        pytest.skip("SQLite has one writer: no deadlock between processes")
    with sessions() as s:
        s.add(Camera(id="cam2", kind=CameraKind.rig, token_hash="h2"))
        s.commit()
    both_hold_one = threading.Barrier(2, timeout=10)

    def lock(first: str, second: str | None, n: int) -> Any:
        calls = []

        def fn(session: Session, retry: bool = False) -> str:
            stmt = select(Camera.id).with_for_update(key_share=True)
            session.execute(stmt.where(Camera.id == first))
            calls.append(retry)
            if second is None and len(calls) == 1:  # the batch's first job, first time
                both_hold_one.wait()
            if second is not None:
                session.execute(stmt.where(Camera.id == second))
            insert_rows(session, *frame_and_verdict(n))
            return "stored"

        return fn

    def batch(one: str, other: str, n: int) -> list[_Job]:
        return [_Job(lock(one, None, n), Future()), _Job(lock(other, one, n + 1), Future())]

    writers = [GroupCommitWriter(sessions), GroupCommitWriter(sessions)]
    batches = [batch("cam", "cam2", 1), batch("cam2", "cam", 3)]
    outcomes: list[Any] = [None, None]

    def write(i: int) -> None:
        outcomes[i] = writers[i]._write(batches[i])

    threads = [threading.Thread(target=write, args=(i,)) for i in range(2)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(30)
    assert outcomes == [[("stored", None)] * 2] * 2
    with sessions() as s:
        assert s.scalars(select(Frame.id).order_by(Frame.id)).all() == [
            "f0001", "f0002", "f0003", "f0004",
        ]  # fmt: skip
