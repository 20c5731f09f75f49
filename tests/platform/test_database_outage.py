"""The database down or locked (a failover, a restart, SQLite locked past its busy timeout):
every endpoint answers 503 problem+json with Retry-After, which cameras, robots and
dashboards retry, not 500 "the service failed"; and the service serves again as soon as the
database is back, without a restart."""

from __future__ import annotations

import asyncio
import collections
import logging
import os
import threading
import time
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import httpx2 as httpx
import pytest
from fastapi.testclient import TestClient
from sqlalchemy import Engine, create_engine, make_url, text
from sqlalchemy.exc import IntegrityError, InterfaceError, OperationalError
from sqlalchemy.exc import TimeoutError as PoolTimeout

from app.main import create_app
from app.platform.http.errors import database_unavailable
from app.platform.settings import Settings
from tests.factories import (
    ADMIN_TOKEN,
    empty_tables,
    make_jpeg,
    migrate,
    postgres_database,
    stalled_writer,
    table_counts,
)
from tests.servers import free_port, server_env, start_server

PG_URL = os.environ.get("VANTAGE_TEST_DATABASE_URL", "")
ADMIN = {"Authorization": f"Bearer {ADMIN_TOKEN}"}


@dataclass
class Refused:
    """How many statements ``database_down`` refused."""

    statements: int = 0


@contextmanager
def database_down(app: Any) -> Iterator[Refused]:
    """Every statement of the app's engines fails as the driver fails when its server is
    gone (PostgreSQL) or its file locked (SQLite): the driver's own OperationalError."""
    engines = {id(e): e for e in (app.state.engine, app.state.read_sessionmaker.kw["bind"])}
    patched = []
    refused = Refused()
    for engine in engines.values():
        dialect = engine.dialect
        error = dialect.loaded_dbapi.OperationalError

        def fail(
            *_: Any,
            error: type[Exception] = error,
            sqlite: bool = dialect.name == "sqlite",
            **__: Any,
        ) -> None:
            refused.statements += 1
            exc = error("database is locked / server closed the connection unexpectedly")
            if sqlite:  # as sqlite3 names a lock held past the busy timeout
                exc.sqlite_errorname = "SQLITE_BUSY"  # type: ignore[attr-defined]
            raise exc

        for name in ("do_execute", "do_executemany", "do_execute_no_params"):
            patched.append((dialect, name))
            setattr(dialect, name, fail)
    try:
        yield refused
    finally:
        for dialect, name in patched:
            delattr(dialect, name)  # the class's method again


@pytest.fixture
def camera(client: TestClient, admin: dict[str, str]) -> dict[str, str]:
    r = client.post(
        "/cameras", json={"id": "sky-1", "kind": "sky", "lat": 45.5, "lon": 9.2}, headers=admin
    )
    assert r.status_code == 201, r.text
    return {"Authorization": f"Bearer {r.json()['token']}", "Content-Type": "image/jpeg"}


def test_an_outage_is_a_503_to_retry_and_passes(
    client: TestClient,
    app: Any,
    engine: Engine,
    camera: dict[str, str],
    admin: dict[str, str],
    caplog: pytest.LogCaptureFixture,
) -> None:
    before = table_counts(engine)
    with database_down(app), caplog.at_level(logging.WARNING, "vantage"):
        answers = {
            "upload": client.post(
                "/cameras/sky-1/frames", content=make_jpeg(seed=1, noise=5), headers=camera
            ),
            "registry": client.get("/cameras", headers=admin),
            "dashboard": client.get("/air/latest"),
            "readings": client.get("/air/readings", params={"camera_id": "sky-1"}),
            "register": client.post("/panels", json={"id": "p-1"}, headers=admin),
        }
        health = client.get("/health")
    for name, r in answers.items():
        assert r.status_code == 503, (name, r.status_code, r.text)  # it had been 500
        assert r.headers["content-type"] == "application/problem+json", name
        assert r.headers["retry-after"] == "5", name
        assert r.json()["code"] == "database_unavailable", name
    assert health.status_code == 503
    assert health.json()["database"] == "unreachable"
    # one line per request in the log, not a traceback each
    outage = [rec for rec in caplog.records if "database unavailable" in rec.getMessage()]
    assert len(outage) == len(answers)
    assert not any(rec.exc_info for rec in caplog.records)
    assert table_counts(engine) == before

    # the database back: the same process serves again, the refused upload is taken
    r = client.post("/cameras/sky-1/frames", content=make_jpeg(seed=1, noise=5), headers=camera)
    assert r.status_code == 201, r.text
    assert client.get("/health").status_code == 200
    assert client.post("/panels", json={"id": "p-1"}, headers=admin).status_code == 201
    metrics = client.get("/metrics", headers=admin).text
    assert 'vantage_frames_rejected_total{camera_id="sky-1",reason="database_unavailable"} 1.0' in (
        metrics
    )


class _Driver(Exception):
    def __init__(self, sqlstate: str | None) -> None:
        super().__init__("driver error")
        self.sqlstate = sqlstate


@pytest.mark.parametrize(
    ("error", "unavailable"),
    [
        # PostgreSQL: admin shutdown (a restart), cannot connect, too many connections,
        # a serialization failure: the same request succeeds later
        (OperationalError("SELECT 1", None, _Driver("57P01")), True),
        (OperationalError("SELECT 1", None, _Driver("08006")), True),
        (OperationalError("SELECT 1", None, _Driver("53300")), True),
        (OperationalError("SELECT 1", None, _Driver("40001")), True),
        # SQLite: "database is locked" past the busy timeout (no SQLSTATE)
        (OperationalError("SELECT 1", None, _Driver(None)), True),
        # a connection lost under any error class
        (InterfaceError("SELECT 1", None, _Driver(None), connection_invalidated=True), True),
        # a statement over a program limit fails again when retried; a conflict is no outage
        (OperationalError("SELECT 1", None, _Driver("54000")), False),
        (IntegrityError("INSERT", None, _Driver("23505")), False),
        (InterfaceError("SELECT 1", None, _Driver(None)), False),
        # the pool's connections all taken for its timeout
        (PoolTimeout("QueuePool limit of size 10 overflow 20 reached"), True),
        (ValueError("not the database's"), False),
    ],
)
def test_what_counts_as_an_outage(error: Exception, unavailable: bool) -> None:
    assert database_unavailable(error) is unavailable


class _Proxy:
    """A TCP relay to the database server that can be cut (every connection dropped, new ones
    refused) and restored, as a failover or a restart looks to the service."""

    def __init__(self, host: str, port: int) -> None:
        self.target = (host, port)
        self.port = free_port()
        self.loop = asyncio.new_event_loop()
        self.thread = threading.Thread(target=self.loop.run_forever, daemon=True)
        self.thread.start()
        self.server: asyncio.Server | None = None
        self.writers: list[asyncio.StreamWriter] = []
        self.silent = False

    def _run(self, coro: Any) -> Any:
        return asyncio.run_coroutine_threadsafe(coro, self.loop).result(10)

    async def _relay(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        if self.silent:  # accepted and never answered
            self.writers.append(writer)
            await asyncio.Event().wait()
        try:
            up_reader, up_writer = await asyncio.open_connection(*self.target)
        except OSError:
            writer.close()
            return
        if self.server is None or not self.server.is_serving():  # cut while connecting
            writer.transport.abort()
            up_writer.transport.abort()
            return
        self.writers += [writer, up_writer]

        async def pipe(a: asyncio.StreamReader, b: asyncio.StreamWriter) -> None:
            try:
                while data := await a.read(65536):
                    b.write(data)
                    await b.drain()
            except OSError:
                pass
            finally:
                b.close()

        await asyncio.gather(pipe(reader, up_writer), pipe(up_reader, writer))

    async def _up(self) -> None:
        self.server = await asyncio.start_server(self._relay, "127.0.0.1", self.port)

    async def _down(self) -> None:
        assert self.server is not None
        self.server.close()
        for w in self.writers:
            w.transport.abort()
        self.writers = []
        await self.server.wait_closed()

    async def _silence(self) -> None:
        self.silent = True
        for w in self.writers:
            w.transport.abort()
        self.writers = []

    def up(self) -> None:
        self._run(self._up())

    def silence(self) -> None:
        """Connections dropped, and new ones accepted but never answered: the database's
        address taken by a host that does not answer (a failover under way) or a server
        that hangs."""
        self._run(self._silence())

    def answer(self) -> None:
        self.silent = False

    def down(self) -> None:
        self._run(self._down())

    def close(self) -> None:
        if self.server is not None and self.server.is_serving():
            self.down()
        self._run(self._settle())
        self.loop.call_soon_threadsafe(self.loop.stop)
        self.thread.join(10)
        self.loop.close()

    async def _settle(self) -> None:
        relays = [t for t in asyncio.all_tasks() if t is not asyncio.current_task()]
        for t in relays:
            t.cancel()
        await asyncio.gather(*relays, return_exceptions=True)


@dataclass
class Proxied:
    proxy: _Proxy
    base: str
    camera: dict[str, str]
    """Headers of an upload by camera ``c`` (a sky camera)."""


@pytest.fixture
def proxied(engine: Engine, database_url: str, tmp_path: Path) -> Iterator[Proxied]:
    """A server process reaching PostgreSQL through a ``_Proxy``, with one camera."""
    empty_tables(engine)
    url = make_url(database_url)
    proxy = _Proxy(url.host or "127.0.0.1", url.port or 5432)
    proxy.up()
    port = free_port()
    proc = start_server(
        server_env(
            url.set(port=proxy.port).render_as_string(False),
            tmp_path,
            VANTAGE_LOG_LEVEL="ERROR",  # not a line for each of an outage's 503s
        ),
        port,
    )
    base = f"http://127.0.0.1:{port}"
    try:
        r = httpx.post(f"{base}/cameras", json={"id": "c", "kind": "sky"}, headers=ADMIN)
        headers = {"Authorization": f"Bearer {r.json()['token']}", "Content-Type": "image/jpeg"}
        yield Proxied(proxy, base, headers)
    finally:
        proc.terminate()
        proc.wait(30)
        proxy.close()


@pytest.mark.slow
@pytest.mark.postgres
@pytest.mark.skipif(not PG_URL.startswith("postgresql"), reason="needs PostgreSQL")
def test_a_real_postgresql_outage(engine: Engine, proxied: Proxied) -> None:
    """A server process whose PostgreSQL goes away mid-stream and comes back: 16 cameras
    uploading all along get 201 or 503, never a 500; every 201 is stored with its verdict;
    uploads are taken again within a second of the database's return."""
    base, headers, proxy = proxied.base, proxied.camera, proxied.proxy
    phase = ["before"]
    answers: collections.Counter[tuple[str, int]] = collections.Counter()
    acknowledged: list[str] = []
    stop = threading.Event()

    def camera(k: int) -> None:
        n = 0
        with httpx.Client(base_url=base, timeout=30) as c:
            while not stop.is_set():
                n += 1
                body = make_jpeg(160, 120, noise=20, seed=k * 100_000 + n)
                r = c.post("/cameras/c/frames", content=body, headers=headers)
                answers[(phase[0], r.status_code)] += 1
                if r.status_code == 201:
                    acknowledged.append(r.json()["frame_id"])

    threads = [threading.Thread(target=camera, args=(k,)) for k in range(16)]
    for t in threads:
        t.start()
    time.sleep(1.5)
    proxy.down()
    phase[0] = "down"
    time.sleep(1.5)
    proxy.up()
    phase[0] = "returning"  # a second for the pool's dropped connections to be replaced
    time.sleep(1.0)
    phase[0] = "back"
    time.sleep(1.5)
    stop.set()
    for t in threads:
        t.join()
    assert {status for _, status in answers} <= {201, 503}, answers
    assert answers[("before", 201)] > 0
    assert answers[("down", 503)] > 0
    assert answers[("down", 201)] <= 16  # at most what was in flight as the cut came
    assert answers[("back", 201)] > 0
    assert answers[("back", 503)] == 0, answers
    with engine.connect() as conn:
        frames = set(map(str, conn.execute(text("SELECT id FROM frames")).scalars()))
        judged = set(map(str, conn.execute(text("SELECT frame_id FROM verdicts")).scalars()))
    assert set(acknowledged) <= frames
    assert frames == judged


@pytest.mark.slow
@pytest.mark.postgres
@pytest.mark.skipif(not PG_URL.startswith("postgresql"), reason="needs PostgreSQL")
def test_a_database_that_does_not_answer(proxied: Proxied) -> None:
    """The database's address accepts connections and never answers: every request gets its
    503 within the connect timeout (5 s), well before a client's 30 s timeout; psycopg's own
    default is 130 s, each wait holding a worker thread. Uploads are taken again as soon as the
    database answers."""
    base, headers, proxy = proxied.base, proxied.camera, proxied.proxy
    requests = {
        "upload": ("POST", "/cameras/c/frames", headers, make_jpeg(noise=5, seed=1)),
        "registry": ("GET", "/cameras", ADMIN, None),
        "dashboard": ("GET", "/air/latest", {}, None),
        "health": ("GET", "/health", {}, None),
    }
    proxy.silence()

    def send(method: str, path: str, h: dict[str, str], body: bytes | None) -> int:
        with httpx.Client(base_url=base, timeout=30) as c:
            return c.request(method, path, headers=h, content=body).status_code

    with ThreadPoolExecutor(len(requests)) as pool:
        answers = {k: pool.submit(send, *v) for k, v in requests.items()}
        statuses = {k: f.result() for k, f in answers.items()}  # a hang: ReadTimeout
    assert statuses == dict.fromkeys(requests, 503)
    proxy.answer()
    for _ in range(3):  # the pool's dropped connections replaced
        r = httpx.post(
            f"{base}/cameras/c/frames", content=make_jpeg(noise=5, seed=2), headers=headers
        )
        if r.status_code == 201:
            break
    assert r.status_code == 201, r.text


@pytest.mark.slow
@pytest.mark.postgres
@pytest.mark.skipif(not PG_URL.startswith("postgresql"), reason="needs PostgreSQL")
def test_tables_locked_past_the_statement_timeout(
    engine: Engine, database_url: str, tmp_path: Path
) -> None:
    """PostgreSQL answers but the frames table is locked (``VACUUM FULL``, an ``ALTER
    TABLE``, a migration queued for its lock): each request on it gets its 503 after the
    statement timeout (1 s here, 30 s by default) instead of waiting for the lock with no
    bound (measured: every one still waiting after 12 s, /health "ok"); as soon as the
    lock goes, they are served again."""
    empty_tables(engine)
    port = free_port()
    env = server_env(
        database_url,
        tmp_path,
        VANTAGE_LOG_LEVEL="ERROR",
        VANTAGE_DATABASE_STATEMENT_TIMEOUT_SECONDS="1",
    )
    proc = start_server(env, port)
    base = f"http://127.0.0.1:{port}"
    try:
        r = httpx.post(f"{base}/cameras", json={"id": "c", "kind": "sky"}, headers=ADMIN)
        camera = {"Authorization": f"Bearer {r.json()['token']}", "Content-Type": "image/jpeg"}
        requests = {
            "upload": ("POST", "/cameras/c/frames", camera, make_jpeg(noise=5, seed=1)),
            "registry": ("GET", "/cameras", ADMIN, None),
            "dashboard": ("GET", "/air/latest", {}, None),
            "readings": ("GET", "/air/readings", {}, None),
        }

        def send(method: str, path: str, h: dict[str, str], body: bytes | None) -> Any:
            with httpx.Client(base_url=base, timeout=20) as c:
                began = time.monotonic()
                r = c.request(method, path, headers=h, content=body)
                return r.status_code, time.monotonic() - began, r.headers.get("retry-after")

        with engine.connect() as locker:
            lock = locker.begin()
            locker.execute(text("LOCK TABLE frames IN ACCESS EXCLUSIVE MODE"))
            with ThreadPoolExecutor(len(requests)) as pool:
                answers = {k: pool.submit(send, *v) for k, v in requests.items()}
                got = {k: f.result() for k, f in answers.items()}  # a hang: ReadTimeout
            assert httpx.get(f"{base}/health").status_code == 200  # SELECT 1 is not locked
            lock.rollback()
        assert {k: (status, retry) for k, (status, _, retry) in got.items()} == dict.fromkeys(
            requests, (503, "5")
        )
        assert {k: send(*v)[0] for k, v in requests.items()} == {
            "upload": 201,
            "registry": 200,
            "dashboard": 200,
            "readings": 200,
        }
    finally:
        proc.terminate()
        proc.wait(30)


def test_the_database_urls_own_timeouts_win() -> None:
    from app.platform.db.session import _pg_timeouts

    ours = _pg_timeouts("postgresql+psycopg://u@db/v")
    assert ours["connect_timeout"] == 5
    assert ours["tcp_user_timeout"] == 15_000
    assert ours["options"] == "-c statement_timeout=30000"
    given = _pg_timeouts(
        "postgresql+psycopg://u@db/v?connect_timeout=20&keepalives=0&options=-c%20work_mem%3D64MB"
    )
    assert "connect_timeout" not in given  # the URL's 20 reaches the driver
    assert "keepalives" not in given
    assert "options" not in given  # the URL's options replace ours: a bound is theirs to set
    assert given["tcp_user_timeout"] == 15_000
    assert "options" not in _pg_timeouts("postgresql+psycopg://u@db/v", 0)  # no bound
    assert _pg_timeouts("postgresql+psycopg://u@db/v", 2.5)["options"].endswith("=2500")


@pytest.mark.skipif(not PG_URL.startswith("postgresql"), reason="a pool on PostgreSQL only")
def test_the_pool_is_sized_by_the_settings(settings: Any, engine: Engine) -> None:
    """Processes × (pool + overflow) must fit the server's max_connections: both are settings."""
    app = create_app(
        settings.model_copy(update={"database_pool_size": 3, "database_max_overflow": 2})
    )
    pool = app.state.engine.pool
    assert (pool.size(), pool._max_overflow) == (3, 2)
    app.state.engine.dispose()


def test_sqlite_errors_by_their_code(tmp_path: Path) -> None:
    """SQLite raises OperationalError for a lock held past the busy timeout or a disk gone
    read-only (an outage: 503) and for a missing table or column (a schema this code does not
    match: a retry does not mend it, 500)."""
    import sqlite3

    with pytest.raises(sqlite3.OperationalError) as schema:
        sqlite3.connect(":memory:").execute("SELECT nope FROM nowhere")
    path = tmp_path / "locked.db"
    holder = sqlite3.connect(path, isolation_level=None)
    holder.execute("CREATE TABLE t (x)")
    holder.execute("BEGIN EXCLUSIVE")
    with pytest.raises(sqlite3.OperationalError) as locked:
        sqlite3.connect(path, timeout=0).execute("INSERT INTO t VALUES (1)")
    holder.close()
    with pytest.raises(sqlite3.OperationalError) as read_only:
        sqlite3.connect(f"file:{path}?mode=ro", uri=True).execute("INSERT INTO t VALUES (1)")
    assert read_only.value.sqlite_errorname == "SQLITE_READONLY"
    assert database_unavailable(OperationalError("INSERT", None, locked.value))
    assert database_unavailable(OperationalError("INSERT", None, read_only.value))
    assert not database_unavailable(OperationalError("SELECT", None, schema.value))


def test_every_operation_documents_its_503(client: TestClient) -> None:
    """Clients generated from the OpenAPI document learn that any operation may answer 503
    to be retried (the database unavailable), not only the upload."""
    document = client.get("/openapi.json").json()
    operations = [(p, m, op) for p, ops in document["paths"].items() for m, op in ops.items()]
    assert len(operations) > 40
    assert [(p, m) for p, m, op in operations if "503" not in op["responses"]] == []


@pytest.mark.skipif(
    PG_URL.startswith("postgresql"),
    reason="database_down patches the dialect; on PostgreSQL a batch's statements all go to the "
    "driver itself (its SELECT and COPY, db.rows; no BEGIN is sent), past the dialect. "
    "test_a_real_postgresql_outage cuts PostgreSQL itself",
)
def test_a_batch_meeting_an_outage_fails_at_once(
    settings: Settings, engine: Engine, admin: dict[str, str]
) -> None:
    """A batch of uploads that meets the database down fails whole: one attempt, not one more
    for each upload. (The writer tried each job alone to isolate a bad one; against a database
    that does not answer, each try waits the connect timeout, 5 s: a batch of 64 held the writer
    for five minutes after the database was back.)"""
    from concurrent.futures import ThreadPoolExecutor

    empty_tables(engine)
    app = create_app(settings)
    with TestClient(app, raise_server_exceptions=False) as client:
        r = client.post("/cameras", json={"id": "c", "kind": "rig"}, headers=admin)
        headers = {"Authorization": f"Bearer {r.json()['token']}", "Content-Type": "image/jpeg"}
        writer = app.state.writer

        def upload(seed: int) -> Any:
            body = make_jpeg(seed=seed, noise=5)
            return client.post("/cameras/c/frames", content=body, headers=headers)

        with stalled_writer(writer) as stall, ThreadPoolExecutor(9) as pool:
            first = pool.submit(upload, 0)
            assert stall.stuck.wait(10)
            rest = [pool.submit(upload, seed) for seed in range(1, 9)]
            for _ in range(100):  # the 8 queued behind the stalled batch
                if writer._queue.qsize() == 8:
                    break
                time.sleep(0.05)
            with database_down(app) as refused:
                stall.release.set()
                answers = [first.result(), *(u.result() for u in rest)]
    assert [a.status_code for a in answers] == [503] * 9
    assert stall.batches[:2] == [1, 8]
    assert refused.statements <= 2 * 2  # each batch once, and once more on a fresh connection


@pytest.mark.postgres
def test_a_read_only_database_is_a_503_and_health_says_so(settings: Settings) -> None:
    """PostgreSQL answering but refusing writes (a failover left the service's address on a
    standby, or an operator set it read-only, 25006): writes get 503 to retry, not 500 "the
    service failed" (measured before: uploads and registrations 500, /health "ok"); reads are
    served; /health says ``read_only``; and once writes are taken again the pool's
    connections, replaced, take them at the next try."""
    with postgres_database("read_only") as url:
        name = make_url(url).database
        migrate(url)
        app = create_app(settings.model_copy(update={"database_url": url}))

        def read_only(on: bool) -> None:
            """Every session of the database read-only (or not) from now: as after a
            failover, the sessions open are cut, and those that follow are of the new kind."""
            server = create_engine(PG_URL, isolation_level="AUTOCOMMIT")
            with server.connect() as conn:
                conn.execute(
                    text(f"ALTER DATABASE {name} SET default_transaction_read_only = {on}")
                )
                conn.execute(
                    text(
                        "SELECT pg_terminate_backend(pid) FROM pg_stat_activity "
                        "WHERE datname = :name AND pid <> pg_backend_pid()"
                    ),
                    {"name": name},
                )
            server.dispose()

        with TestClient(app) as client:
            token = client.post("/cameras", json={"id": "c", "kind": "rig"}, headers=ADMIN)
            headers = {
                "Authorization": f"Bearer {token.json()['token']}",
                "Content-Type": "image/jpeg",
            }
            read_only(True)
            for _ in range(2):  # the writer's connection, cut, replaced by a read-only one
                r = client.post("/cameras/c/frames", content=make_jpeg(seed=1), headers=headers)
                assert r.status_code == 503, r.text
            assert r.json()["code"] == "database_unavailable"
            assert "read-only" in r.json()["detail"]
            assert r.headers["retry-after"] == "5"
            robot = client.post("/robots", json={"id": "r1"}, headers=ADMIN)
            assert robot.status_code == 503, robot.text
            assert client.get("/cameras", headers=ADMIN).status_code == 200
            health = client.get("/health")
            assert health.status_code == 503
            assert health.json()["database"] == "read_only"

            read_only(False)
            statuses = []
            for k in range(2):  # a connection opened while read-only fails once, then goes
                body = make_jpeg(seed=2 + k)
                r = client.post("/cameras/c/frames", content=body, headers=headers)
                statuses.append(r.status_code)
                if r.status_code == 201:
                    break
            assert statuses in ([201], [503, 201]), statuses
            assert client.get("/health").json()["database"] == "ok"
        app.state.engine.dispose()
