"""``python -m app.platform.backup``: a consistent copy of a running service's data that
restores into a service serving the same frames."""

from __future__ import annotations

import hashlib
import os
import threading
from pathlib import Path
from typing import Any

import pytest
from fastapi.testclient import TestClient
from sqlalchemy import Engine

from app.main import create_app
from app.platform.auth import ADMIN_TOKEN_FILE, admin_token_hash
from app.platform.backup import BackupError, backup, main
from app.platform.settings import Settings
from tests.factories import make_jpeg, table_counts

ON_SQLITE = not os.environ.get("VANTAGE_TEST_DATABASE_URL", "").startswith("postgresql")


def _camera(client: TestClient, admin: dict[str, str]) -> dict[str, str]:
    r = client.post("/cameras", json={"id": "cam-1", "kind": "rig"}, headers=admin)
    assert r.status_code == 201, r.text
    return {"Authorization": f"Bearer {r.json()['token']}", "Content-Type": "image/jpeg"}


def _post(client: TestClient, headers: dict[str, str], seed: int) -> str:
    r = client.post(
        "/cameras/cam-1/frames", content=make_jpeg(160, 120, noise=20, seed=seed), headers=headers
    )
    assert r.status_code == 201, r.text
    return str(r.json()["frame_id"])


@pytest.mark.skipif(not ON_SQLITE, reason="the SQLite snapshot; PostgreSQL is pg_dump's")
def test_a_backup_taken_during_uploads_restores(
    client: TestClient, settings: Settings, engine: Engine, admin: dict[str, str], tmp_path: Path
) -> None:
    headers = _camera(client, admin)
    # a generated admin token, as a service started without VANTAGE_ADMIN_TOKEN keeps one
    admin_token_hash(settings.model_copy(update={"admin_token": None}))
    generated = (settings.data_dir / ADMIN_TOKEN_FILE).read_text().strip()
    before = [_post(client, headers, seed) for seed in range(5)]
    during: list[str] = []
    stop = threading.Event()

    def camera() -> None:  # uploads go on while the backup is taken
        seed = 100
        while not stop.is_set():
            during.append(_post(client, headers, seed))
            seed += 1

    uploading = threading.Thread(target=camera)
    uploading.start()
    try:
        while len(during) < 3:
            threading.Event().wait(0.01)
        report = backup(settings, tmp_path / "backup")
    finally:
        stop.set()
        uploading.join()
    after = _post(client, headers, seed=999)

    assert report.missing == []
    assert report.files > 0
    assert report.bytes > 0
    assert report.frames >= len(before) + 3
    assert report.frames <= len(before) + len(during)
    assert backup(settings, tmp_path / "verified", verify=True).missing == []

    # restored: a service on the copy, its admin token the copied one, serves every frame of
    # the snapshot, byte for byte
    restored = Settings(
        env="test",
        data_dir=tmp_path / "backup",
        database_url=f"sqlite:///{tmp_path / 'backup' / 'vantage.db'}",
        rate_limit_per_minute=0,
    )
    admin = {"Authorization": f"Bearer {generated}"}
    with TestClient(create_app(restored), raise_server_exceptions=False) as copy:
        listed = copy.get("/cameras/cam-1/frames", headers=admin, params={"limit": 1000}).json()
        ids = {f["frame_id"] for f in listed}
        assert len(ids) == report.frames
        assert set(before) <= ids
        assert after not in ids  # posted after the backup
        for frame in listed:
            image = copy.get(f"/frames/{frame['frame_id']}/image", headers=admin)
            assert image.status_code == 200
            assert hashlib.sha256(image.content).hexdigest() == frame["sha256"]
        assert _post(copy, headers, seed=1000)  # and takes new frames
    assert table_counts(engine)["frames"] == len(before) + len(during) + 1  # the source intact


def test_a_backup_goes_only_into_a_new_or_empty_directory(
    client: TestClient, settings: Settings, tmp_path: Path
) -> None:
    used = tmp_path / "used"
    used.mkdir()
    (used / "vantage.db").write_bytes(b"an earlier backup")
    with pytest.raises(BackupError, match="not empty"):
        backup(settings, used)
    assert (used / "vantage.db").read_bytes() == b"an earlier backup"
    gone = settings.model_copy(update={"database_url": f"sqlite:///{tmp_path}/none.db"})
    with pytest.raises(BackupError, match="no database"):  # and a failed one leaves nothing
        backup(gone, tmp_path / "new")
    assert list((tmp_path / "new").iterdir()) == []


@pytest.mark.skipif(ON_SQLITE, reason="PostgreSQL")
def test_on_postgresql_the_database_is_left_to_pg_dump(
    client: TestClient, settings: Settings, admin: dict[str, str], tmp_path: Path
) -> None:
    headers = _camera(client, admin)
    _post(client, headers, seed=1)
    report = backup(settings, tmp_path / "backup")
    assert report.database == "not copied"
    assert any("pg_dump" in note for note in report.notes)
    assert report.files >= 1  # the frame store is copied still


def test_the_command_reports_as_json(
    client: TestClient,
    settings: Settings,
    admin: dict[str, str],
    monkeypatch: Any,
    tmp_path: Path,
    capsys: Any,
) -> None:
    _post(client, _camera(client, admin), seed=1)
    monkeypatch.setattr("app.platform.backup.get_settings", lambda: settings)
    assert main([str(tmp_path / "backup")]) == 0
    assert '"missing": []' in capsys.readouterr().out
    assert main([str(tmp_path / "backup")]) == 1  # not empty now
    assert "not empty" in capsys.readouterr().err
