"""A process refuses to start on a database its migrations have not all reached, and starts,
with a warning, on one migrated past what it knows (a rolling deploy)."""

from __future__ import annotations

import logging
from pathlib import Path

import pytest
from fastapi.testclient import TestClient
from sqlalchemy import create_engine, text

from app.main import create_app
from app.platform.db.schema import SchemaBehind, _scripts
from app.platform.settings import Settings
from tests.factories import migrate


def _previous_revision() -> str:
    scripts = _scripts()
    assert scripts is not None
    (head,) = scripts.get_heads()
    down = scripts.get_revision(head).down_revision
    assert isinstance(down, str)
    return down


def test_a_schema_behind_the_code_is_refused_at_start(settings: Settings, tmp_path: Path) -> None:
    """One migration short: /health had said "ok" and the rigs' endpoints failed (their
    newest column missing) with 500s."""
    url = f"sqlite:///{tmp_path / 'behind.db'}"
    previous = _previous_revision()
    migrate(url, previous)
    with (
        pytest.raises(SchemaBehind, match=rf"at {previous}.*alembic upgrade head"),
        TestClient(create_app(settings.model_copy(update={"database_url": url}))),
    ):
        pass
    migrate(url)  # what the message says to do
    with TestClient(create_app(settings.model_copy(update={"database_url": url}))) as client:
        assert client.get("/health").status_code == 200


def test_an_empty_database_is_refused_at_start(settings: Settings, tmp_path: Path) -> None:
    url = f"sqlite:///{tmp_path / 'empty.db'}"
    with (
        pytest.raises(SchemaBehind, match="no revision"),
        TestClient(create_app(settings.model_copy(update={"database_url": url}))),
    ):
        pass


def test_a_schema_past_the_code_is_served_with_a_warning(
    settings: Settings, tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    url = f"sqlite:///{tmp_path / 'ahead.db'}"
    migrate(url)
    engine = create_engine(url)
    with engine.begin() as conn:  # as the next version's migration leaves it
        conn.execute(text("UPDATE alembic_version SET version_num = 'a0a0a0a0a0a0'"))
    engine.dispose()
    app = create_app(
        settings.model_copy(update={"database_url": url})
    )  # its logging replaces the logger's handlers
    service = logging.getLogger("vantage")
    service.addHandler(caplog.handler)
    try:
        with TestClient(app) as client:
            assert client.get("/health").status_code == 200
    finally:
        service.removeHandler(caplog.handler)
    assert any("newer than this version" in r.getMessage() for r in caplog.records)
