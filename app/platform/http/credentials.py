"""What an Authorization header carries: a Bearer token, or HTTP Basic's user and password."""

from __future__ import annotations

import base64
import binascii

from app.platform.http.errors import Unauthorized


def credentials_of(header: str) -> tuple[str, str | None]:
    """(token, Basic user name or None) from an Authorization header; Unauthorized when it is
    neither a Bearer token nor well-formed Basic credentials."""
    scheme, _, value = header.strip().partition(" ")
    value = value.strip()
    if scheme.lower() == "bearer" and value:
        return value, None
    if scheme.lower() == "basic" and value:
        try:
            user, sep, password = base64.b64decode(value, validate=True).decode().partition(":")
        except (binascii.Error, UnicodeDecodeError):
            raise Unauthorized("malformed Basic credentials") from None
        if sep and password:
            return password, user
        raise Unauthorized("malformed Basic credentials")
    raise Unauthorized("expected 'Authorization: Bearer <token>' or Basic credentials")
