"""The service's operations as its OpenAPI document lists them, matched against request paths."""

from __future__ import annotations

import re
from collections.abc import Iterator
from typing import Any


def path_pattern(path: str) -> re.Pattern[str]:
    """An OpenAPI path (``/cameras/{camera_id}``) as a pattern matching the request paths it
    serves: a parameter stands for one segment."""
    return re.compile("^" + re.sub(r"\\\{[^/]+?\\\}", "[^/]+", re.escape(path)) + "$")


def operations(
    document: dict[str, Any],
) -> Iterator[tuple[re.Pattern[str], str, str, dict[str, Any]]]:
    """Each operation of the OpenAPI ``document``: its path's pattern, the path, its method
    (upper case) and the operation object."""
    for path, by_method in document.get("paths", {}).items():
        pattern = path_pattern(path)
        for method, operation in by_method.items():
            yield pattern, path, method.upper(), operation


def operations_of(app: Any) -> list[tuple[re.Pattern[str], str, str]]:
    """``app``'s operations as (path pattern, OpenAPI path, method), read from its OpenAPI
    document once and kept in ``app.state``."""
    table: list[tuple[re.Pattern[str], str, str]] | None = getattr(app.state, "operations", None)
    if table is None:
        table = [(pattern, path, method) for pattern, path, method, _ in operations(app.openapi())]
        app.state.operations = table
    return table


def route_of(app: Any, path: str) -> str | None:
    """The OpenAPI path (``/cameras/{camera_id}``) serving ``path``, or None: for requests that
    reached no route (answered before routing, as a refused query, or run as another method,
    as HEAD). A literal segment wins over a parameter (``/panels/evaluate``)."""
    matches = {p for pattern, p, _ in operations_of(app) if pattern.match(path)}
    return min(matches, key=lambda p: p.count("{")) if matches else None
