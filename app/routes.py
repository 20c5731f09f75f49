"""The service's operations as its OpenAPI document lists them, matched against request paths."""

from __future__ import annotations

import re
from collections.abc import Iterator
from typing import Any


def path_pattern(path: str) -> re.Pattern[str]:
    """An OpenAPI path (``/cameras/{camera_id}``) as a pattern matching the request paths it
    serves: a parameter stands for one segment."""
    return re.compile("^" + re.sub(r"\\\{[^/]+?\\\}", "[^/]+", re.escape(path)) + "$")


def operations(document: dict[str, Any]) -> Iterator[tuple[re.Pattern[str], str, dict[str, Any]]]:
    """Each operation of the OpenAPI ``document``: its path's pattern, its method (upper
    case) and the operation object."""
    for path, by_method in document.get("paths", {}).items():
        pattern = path_pattern(path)
        for method, operation in by_method.items():
            yield pattern, method.upper(), operation


def route_of(app: Any, path: str) -> str | None:
    """The OpenAPI path (``/cameras/{camera_id}``) serving ``path``, or None: for requests that
    reached no route (answered before routing, as a refused query, or run as another method,
    as HEAD). A literal segment wins over a parameter (``/panels/evaluate``)."""
    templates: list[tuple[re.Pattern[str], str]] | None = getattr(
        app.state, "route_templates", None
    )
    if templates is None:
        paths = sorted(app.openapi().get("paths", {}), key=lambda p: p.count("{"))
        templates = [(path_pattern(p), p) for p in paths]
        app.state.route_templates = templates
    return next((t for pattern, t in templates if pattern.match(path)), None)
