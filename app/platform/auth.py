"""Tokens: generation, hashing, and the operator (admin) token's first-start bootstrap."""

from __future__ import annotations

import hashlib
import logging
import os
import secrets
from pathlib import Path

from app.platform.settings import Settings

log = logging.getLogger("vantage.security")

ADMIN_TOKEN_FILE = "admin_token"


def new_token(prefix: str) -> str:
    """A fresh random token (256 bits) with a readable role prefix."""
    return f"{prefix}_{secrets.token_urlsafe(32)}"


def hash_token(token: str) -> str:
    """SHA-256 hex digest. Tokens carry 256 random bits, so a fast hash is enough to store them."""
    return hashlib.sha256(token.encode("utf-8", "surrogatepass")).hexdigest()


def admin_token_hash(settings: Settings) -> str:
    """The admin token's hash: from the environment, else from the data directory.

    When neither has one, generate a token and save it (mode 0600) in the data directory;
    several processes starting at once agree on the first file written.
    """
    if settings.admin_token is not None:
        return hash_token(settings.admin_token.get_secret_value())
    path = settings.data_dir / ADMIN_TOKEN_FILE
    if not path.exists():
        _create_admin_token(path)
    token = path.read_text().strip()
    if not token:
        raise RuntimeError(f"{path} is empty; delete it or set VANTAGE_ADMIN_TOKEN")
    return hash_token(token)


def _create_admin_token(path: Path) -> None:
    path.parent.mkdir(mode=0o700, parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    with os.fdopen(fd, "w") as f:
        f.write(new_token("va") + "\n")
    try:
        os.link(tmp, path)  # atomic, and fails when another process won the race
        log.warning("generated an admin token; it is in %s", path.resolve())
    except FileExistsError:
        pass
    finally:
        tmp.unlink()
