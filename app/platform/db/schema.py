"""Whether the database's schema is the one this code was written for.

A process started against a database whose migrations have not all run (new code deployed,
``alembic upgrade head`` forgotten) answered ``/health`` "ok" and then failed on whatever
touched the missing tables or columns: rigs and alerts gave 500s, the rest seemed to work.
It now refuses to start and says what to run. A database migrated beyond what this code knows
(a rolling deploy: the migrations of the next version have run, this process is of the one
before) is served with a warning: migrations add before they take away.
"""

from __future__ import annotations

import logging
from functools import lru_cache
from pathlib import Path

from alembic.config import Config
from alembic.runtime.migration import MigrationContext
from alembic.script import ScriptDirectory
from sqlalchemy import Engine

log = logging.getLogger("vantage.schema")

ALEMBIC_INI = Path(__file__).resolve().parents[3] / "alembic.ini"


class SchemaBehind(RuntimeError):
    """The database lacks migrations this code needs."""


@lru_cache(maxsize=1)
def _scripts() -> ScriptDirectory | None:
    if not ALEMBIC_INI.exists():  # installed without its migrations: nothing to compare with
        return None
    return ScriptDirectory.from_config(Config(str(ALEMBIC_INI)))


def check(engine: Engine) -> None:
    """Raise ``SchemaBehind`` unless the database is at this code's head revision or past
    it; log a warning when past it."""
    scripts = _scripts()
    if scripts is None:
        return
    heads = set(scripts.get_heads())
    with engine.connect() as conn:
        current = set(MigrationContext.configure(conn).get_current_heads())
    if current == heads:
        return
    known = {rev.revision for rev in scripts.walk_revisions()}
    if current and not current <= known:
        log.warning(
            "the database's schema (%s) is newer than this version knows (%s): "
            "run the version that migrated it",
            ", ".join(sorted(current)),
            ", ".join(sorted(heads)),
        )
        return
    raise SchemaBehind(
        f"the database's schema is at {', '.join(sorted(current)) or 'no revision'}, this "
        f"version needs {', '.join(sorted(heads))}: run `alembic upgrade head` (make migrate) "
        "first"
    )
