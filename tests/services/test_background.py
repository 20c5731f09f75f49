"""Background sweeps in worker threads: a shutdown waits for the one under way, so no thread
still holds a connection when the engine is disposed."""

from __future__ import annotations

import asyncio
import threading
import time
from typing import Any

import pytest
from fastapi.testclient import TestClient
from sqlalchemy import text
from sqlalchemy.orm import Session, sessionmaker

from app.main import create_app
from app.services import webhooks
from app.services.background import in_thread
from app.settings import Settings


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

    def slow_sweep(sessions: sessionmaker[Session], url: str, policy: Any) -> int:
        with sessions() as session:
            session.execute(text("SELECT 1"))
            started.set()
            time.sleep(0.5)
        events.append("sweep done")
        return 0

    monkeypatch.setattr(webhooks, "sweep", slow_sweep)
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
