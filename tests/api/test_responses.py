"""HTTP helpers shared by the routers."""

from __future__ import annotations

from app.routers.responses import not_modified


def test_if_none_match() -> None:
    etag = '"abc"'
    assert not_modified('"abc"', etag)
    assert not_modified('"x", W/"abc"', etag)
    assert not_modified("*", etag)
    assert not not_modified(None, etag)
    assert not not_modified('"abcd"', etag)
