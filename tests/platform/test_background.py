"""Background sweeps in worker threads: a shutdown waits for the one under way, so no thread
still holds a connection when the engine is disposed."""

from __future__ import annotations

import asyncio
import json
import threading
import time
from datetime import timedelta
from typing import Any

import pytest
from fastapi.testclient import TestClient
from sqlalchemy import Engine, select, text
from sqlalchemy.orm import Session, sessionmaker

from app.air.models import AirAlert
from app.air.services import webhook as alert_webhook
from app.main import create_app
from app.platform import webhooks
from app.platform.background import in_thread
from app.platform.db.session import make_engine, make_sessionmaker
from app.platform.settings import Settings
from app.platform.timing import Timing
from tests.factories.air import T0, seed_alerts


def test_a_cancelled_wait_still_waits_for_the_thread() -> None:
    finished: list[float] = []

    def work() -> None:
        time.sleep(0.3)
        finished.append(time.monotonic())

    async def main() -> float:
        task = asyncio.ensure_future(in_thread(work))
        await asyncio.sleep(0.05)
        task.cancel()
        with pytest.raises(asyncio.CancelledError):
            await task
        return time.monotonic()

    returned = asyncio.run(main())
    assert len(finished) == 1  # the thread ran to its end
    assert finished[0] <= returned  # before the cancelled wait returned


def test_the_result_and_errors_come_through() -> None:
    def fail() -> None:
        raise ValueError("boom")

    assert asyncio.run(in_thread(lambda a, b: a + b, 2, 3)) == 5
    with pytest.raises(ValueError, match="boom"):
        asyncio.run(in_thread(fail))


def test_shutdown_waits_for_a_webhook_sweep_holding_a_connection(
    settings: Settings, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The sweep is inside a transaction when the app stops: the engine is disposed only after
    the sweep's connection went back to the pool."""
    started = threading.Event()
    events: list[str] = []

    def slow_sweep(sessions: sessionmaker[Session], url: str, timing: Any, **_: Any) -> int:
        with sessions() as session:
            session.execute(text("SELECT 1"))
            started.set()
            time.sleep(0.5)
        events.append("sweep done")
        return 0

    monkeypatch.setattr(alert_webhook, "sweep", slow_sweep)
    app = create_app(settings.model_copy(update={"alert_webhook_url": "http://127.0.0.1:9/x"}))
    engine = app.state.engine
    dispose = engine.dispose

    def dispose_spy(*args: Any, **kwargs: Any) -> None:
        events.append(f"dispose with {engine.pool.checkedout()} checked out")
        dispose(*args, **kwargs)

    monkeypatch.setattr(engine, "dispose", dispose_spy)
    with TestClient(app):
        assert started.wait(10)
    assert events == ["sweep done", "dispose with 0 checked out"]


def test_a_cancelled_wait_asks_the_work_to_stop_early() -> None:
    stop = threading.Event()
    rounds: list[int] = []

    def work() -> None:
        for n in range(100):  # 10 s unless asked to stop
            if stop.is_set():
                return
            rounds.append(n)
            time.sleep(0.1)

    async def main() -> None:
        task = asyncio.ensure_future(in_thread(work, on_cancel=stop.set))
        while not rounds:  # under way
            await asyncio.sleep(0.01)
        task.cancel()
        with pytest.raises(asyncio.CancelledError):
            await task

    asyncio.run(main())
    assert stop.is_set()
    assert 0 < len(rounds) < 100  # stopped at its next step, not run to its end


def test_a_stopping_webhook_sweep_leaves_the_untried_alerts_for_the_next(
    database_url: str, engine: Engine, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A shutdown waits for the alert being posted, not for every due one (each post may take
    its whole timeout when the receiver does not answer)."""
    seed_alerts(engine, 3)
    t0 = T0
    stopping = threading.Event()
    posted: list[str] = []

    def post(url: str, body: bytes, headers: dict[str, str]) -> None:
        posted.append(json.loads(body)["alert_id"])
        stopping.set()  # the shutdown comes while the first alert is being posted

    monkeypatch.setattr(webhooks, "post", post)
    app_engine = make_engine(database_url)
    try:
        sessions = make_sessionmaker(app_engine)
        timing = Timing(clock=lambda: t0 + timedelta(minutes=1))
        assert alert_webhook.sweep(sessions, "http://hook", timing, stopping=stopping) == 1
    finally:
        app_engine.dispose()
    assert posted == ["a0"]
    with Session(engine) as s:
        kept = {a.id: (a.attempts, a.delivered) for a in s.scalars(select(AirAlert))}
    assert kept == {"a0": (1, True), "a1": (0, False), "a2": (0, False)}
