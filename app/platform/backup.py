"""Back up the service's data while it runs: ``python -m app.platform.backup DEST [--verify]``.

Copying the data directory as it is does not make a backup: the SQLite database runs in WAL
mode, and a copy of ``vantage.db`` taken while frames are committed may lack what sits in
``vantage.db-wal`` or be torn between the two. This takes the database through SQLite's online
backup (one read transaction: a consistent snapshot, uploads going on meanwhile), then copies
the frame store and the generated admin token. The database comes first: every frame row in
the snapshot had its bytes written before it was committed, so the copy made after holds them;
bytes written after the snapshot are copied too and, having no row in it, are swept by the
restored service's start (``VANTAGE_ORPHAN_MIN_AGE_SECONDS``). A frame whose pack retention
deleted between the two steps (its hour had expired) has its row without its bytes until the
restored service's next retention sweep deletes the row too.

To restore: stop the service, make ``DEST`` its data directory (``VANTAGE_DATA_DIR``), start it.

With PostgreSQL the database is backed up with ``pg_dump`` (before this, for the same reason);
with the S3 frame store, by the bucket's versioning or replication. This copies what is on the
data directory either way and says what it left to those tools.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import sqlite3
import sys
from dataclasses import asdict, dataclass, field
from pathlib import Path

from sqlalchemy import make_url

from app.platform.auth import ADMIN_TOKEN_FILE
from app.platform.frames.storage import DiskFrameStore, digest, extent_of
from app.platform.settings import Settings, get_settings


class BackupError(Exception):
    """The backup cannot be made (its destination is in use, the database unreadable)."""


@dataclass
class Report:
    destination: str
    database: str
    frames: int = 0
    files: int = 0
    bytes: int = 0
    missing: list[str] = field(default_factory=list)
    """Frames of the snapshot whose bytes the copy lacks (their pack deleted meanwhile)."""
    notes: list[str] = field(default_factory=list)


def backup(settings: Settings, dest: Path, *, verify: bool = False) -> Report:
    """Snapshot the database and copy the frame store into ``dest`` (new or empty).

    ``verify`` reads every frame of the snapshot back from the copy and checks its SHA-256;
    otherwise only that its pack holds its bytes' extent."""
    if dest.exists() and any(dest.iterdir()):
        raise BackupError(f"{dest} is not empty: back up into a new directory")
    dest.mkdir(parents=True, exist_ok=True)
    try:
        return _backup(settings, dest, verify=verify)
    except BaseException:
        for entry in dest.iterdir():  # no half backup to be taken for a whole one later
            shutil.rmtree(entry) if entry.is_dir() else entry.unlink()
        raise


def _backup(settings: Settings, dest: Path, *, verify: bool) -> Report:
    url = make_url(settings.effective_database_url)
    report = Report(str(dest), database="")
    snapshot: Path | None = None
    if url.get_backend_name() == "sqlite" and url.database:
        snapshot = dest / "vantage.db"
        _sqlite_snapshot(Path(url.database), snapshot)
        report.database = str(snapshot)
    else:
        report.database = "not copied"
        report.notes.append(
            f"the database is {url.get_backend_name()}: back it up with its own tools (pg_dump)"
        )
    if settings.frame_store == "disk":
        for tree in ("packs", "frames"):
            files, size = _copy_tree(settings.data_dir / tree, dest / tree)
            report.files += files
            report.bytes += size
    else:
        report.notes.append("frames are in S3: keep them with the bucket's versioning")
    token = settings.data_dir / ADMIN_TOKEN_FILE
    if token.exists():
        shutil.copy2(token, dest / ADMIN_TOKEN_FILE)
    if snapshot is not None and settings.frame_store == "disk":
        report.frames, report.missing = _check(snapshot, DiskFrameStore(dest), verify=verify)
    return report


def _sqlite_snapshot(source: Path, target: Path) -> None:
    if not source.exists():
        raise BackupError(f"no database at {source}")
    src = sqlite3.connect(f"file:{source}?mode=ro", uri=True, timeout=30)
    dst = sqlite3.connect(target)
    try:
        src.backup(dst)  # all pages in one step: one read transaction, a consistent snapshot
        (result,) = dst.execute("PRAGMA integrity_check").fetchone()
        if result != "ok":
            raise BackupError(f"the snapshot failed its integrity check: {result}")
    except sqlite3.Error as exc:
        raise BackupError(f"backing up {source} failed: {exc}") from exc
    finally:
        dst.close()
        src.close()


def _copy_tree(source: Path, target: Path) -> tuple[int, int]:
    """Copy every file below ``source``; those deleted meanwhile (retention) are skipped."""
    files = size = 0
    for directory, _, names in os.walk(source):
        into = target / Path(directory).relative_to(source)
        into.mkdir(parents=True, exist_ok=True)
        for name in names:
            try:
                shutil.copy2(Path(directory) / name, into / name)
            except FileNotFoundError:
                continue
            files += 1
            size += (into / name).stat().st_size
    return files, size


def _check(snapshot: Path, store: DiskFrameStore, *, verify: bool) -> tuple[int, list[str]]:
    """How many frames the snapshot stores bytes for, and those the copy lacks."""
    db = sqlite3.connect(f"file:{snapshot}?mode=ro", uri=True)
    try:
        rows = db.execute(
            "SELECT stored_path, sha256 FROM frames WHERE stored_path IS NOT NULL"
        ).fetchall()
    finally:
        db.close()
    missing = []
    sizes: dict[str, int] = {}
    for locator, sha256 in rows:
        if verify:
            data = store.read(locator)
            if data is None or digest(data) != sha256:
                missing.append(locator)
            continue
        held, needed = extent_of(locator)
        if held not in sizes:
            path = store.path(held)
            sizes[held] = path.stat().st_size if path.exists() else 0
        if sizes[held] < needed:
            missing.append(locator)
    return len(rows), missing


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("destination", type=Path, help="a new or empty directory")
    parser.add_argument(
        "--verify", action="store_true", help="read every frame back and check its SHA-256"
    )
    args = parser.parse_args(argv)
    try:
        report = backup(get_settings(), args.destination, verify=args.verify)
    except BackupError as exc:
        print(f"backup failed: {exc}", file=sys.stderr)
        return 1
    print(json.dumps(asdict(report), indent=2))
    return 2 if report.missing else 0


if __name__ == "__main__":
    sys.exit(main())
