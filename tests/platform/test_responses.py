"""HTTP helpers shared by the routers."""

from __future__ import annotations

from app.platform.http.responses import not_modified


def test_if_none_match() -> None:
    etag = '"abc"'
    assert not_modified('"abc"', etag)
    assert not_modified('"x", W/"abc"', etag)
    assert not_modified("*", etag)
    assert not not_modified(None, etag)
    assert not not_modified('"abcd"', etag)
    weak = 'W/"abc"'  # compared weakly, either side (RFC 9110 §13.1.2)
    assert not_modified('"abc"', weak)
    assert not_modified('W/"abc"', weak)
    assert not not_modified('W/"ab"', weak)
