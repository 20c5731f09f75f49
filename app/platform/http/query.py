"""Query strings: a request names only parameters its endpoint takes, and gives one value to
each that takes one.

Starlette and FastAPI let both go without a word, and the answer was a confident one to another
question:
- a parameter the endpoint does not take was ignored: ``GET /air/readings?camera=c1`` (for
  ``camera_id``) answered with every camera's readings, ``GET /panels?status=needs_cleaning``
  (for ``state``) listed every panel, and an upload's misspelt ``captured_at`` stored the frame
  as taken when it arrived. Such a request gets 422 ``unknown_parameter``, naming what the
  endpoint takes. Names beginning with ``_`` or ``utm_`` pass: the cache-busters and trackers
  that pages and dashboard libraries add (``?_=1700000000``) ask for nothing;
- the last of a repeated parameter was taken: ``?camera_id=a&camera_id=b`` on an endpoint that
  takes one camera answered for camera b alone, and ``?kind=raised&kind=cleared`` listed the
  cleared alerts alone. Such a request gets 422 ``repeated_parameter``; parameters declared as
  lists (``camera_id`` of ``GET /air/readings``) still take many.
Paths outside the OpenAPI document (``/metrics``, ``/docs``) are not checked.

A time's UTC offset sent with its "+" as it is (``?captured_at=2026-06-01T08:00:00+02:00``,
as cameras' URL templates and hand-typed curl commands send it) is read as that offset: a
query's "+" is a space, so the time arrived as ``…08:00:00 02:00`` and every such upload got
422. Only a "+" between a time of day and an offset ending the value is read so.
"""

from __future__ import annotations

import difflib
import re
from dataclasses import dataclass
from typing import Any
from urllib.parse import parse_qsl

from fastapi import FastAPI
from fastapi.responses import JSONResponse
from starlette.types import ASGIApp, Receive, Scope, Send

from app.platform.http.errors import FRAMES_ROUTE, problem
from app.platform.observability import FRAMES_REJECTED
from app.platform.routes import operations, path_pattern

_UPLOAD = path_pattern(FRAMES_ROUTE)

PASSING_PREFIXES = ("_", "utm_")
"""Query parameters no endpoint declares that pass unchecked: cache-busters and trackers."""


@dataclass(frozen=True, slots=True)
class Rule:
    """An operation's path as a pattern, and its query parameters."""

    pattern: re.Pattern[str]
    known: frozenset[str]
    """Every query parameter the operation takes."""
    single: frozenset[str]
    """Those that take one value (every one not declared an array)."""


def _takes_many(schema: dict[str, Any]) -> bool:
    if schema.get("type") == "array":
        return True
    return any(_takes_many(s) for s in schema.get("anyOf", ()))


def rules(document: dict[str, Any]) -> dict[str, list[Rule]]:
    """Per HTTP method, each path of the OpenAPI ``document`` with its query parameters."""
    out: dict[str, list[Rule]] = {}
    for pattern, _, method, operation in operations(document):
        query = [p for p in operation.get("parameters", ()) if p.get("in") == "query"]
        known = frozenset(p["name"] for p in query)
        single = frozenset(p["name"] for p in query if not _takes_many(p.get("schema", {})))
        out.setdefault(method, []).append(Rule(pattern, known, single))
    return out


def counted(query_string: bytes) -> dict[str, int]:
    """Each parameter named, with how many times."""
    counts: dict[str, int] = {}
    for key, _ in parse_qsl(query_string.decode("latin-1"), keep_blank_values=True):
        counts[key] = counts.get(key, 0) + 1
    return counts


def _unknown(name: str, rule: Rule, where: str) -> str:
    takes = ", ".join(sorted(rule.known)) if rule.known else "no query parameters"
    close = difflib.get_close_matches(name, rule.known, n=1)
    hint = f"; did you mean {close[0]}?" if close else ""
    return f"{name} is not a parameter of {where}{hint} (it takes {takes})"


_PLUS_OFFSET = re.compile(rb"(\d\d:\d\d(?::\d\d(?:\.\d+)?)?)\+(\d\d(?::?\d\d)?)(?=&|$)")
"""A time of day, "+", and a UTC offset ending a query value (``08:00:00+02:00``)."""


def plus_offsets(scope: Scope) -> Scope:
    """``scope`` with each offset's "+" in its query string percent-encoded, as the sender
    meant it (a copy; ``scope`` itself when there is none)."""
    query: bytes = scope["query_string"]
    fixed = _PLUS_OFFSET.sub(rb"\1%2B\2", query)
    return scope if fixed == query else {**scope, "query_string": fixed}


class CheckedQuery:
    """Refuse (422) a request naming a query parameter its endpoint does not take, or repeating
    one it takes once.

    A request without a query string (most frame uploads) costs nothing here; one with a query
    string costs a scan of it and a look-up of its endpoint (the upload's path is the first
    tried). The rules are read from the OpenAPI document once.
    """

    def __init__(self, app: ASGIApp, *, service: FastAPI) -> None:
        self.app = app
        self.service = service
        self._rules: dict[str, list[Rule]] | None = None

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] == "http" and scope["query_string"]:
            if b"+" in scope["query_string"]:
                scope = plus_offsets(scope)
            rule = self._rule(scope["method"], scope["path"])
            response = None if rule is None else self._refusal(rule, scope)
            if response is not None:
                await response(scope, receive, send)
                return
        await self.app(scope, receive, send)

    def _refusal(self, rule: Rule, scope: Scope) -> JSONResponse | None:
        """The 422 for the request, counted as a refused frame for an upload; None when its
        query string is fine."""
        counts = counted(scope["query_string"])
        where = f"{scope['method']} {scope['path']}"
        unknown = sorted(
            name
            for name in counts
            if name not in rule.known and not name.startswith(PASSING_PREFIXES)
        )
        twice = sorted(name for name in rule.single if counts.get(name, 0) > 1)
        if unknown:
            code = "unknown_parameter"
            response = problem(
                422,
                "Unprocessable content",
                _unknown(unknown[0], rule, where),
                code=code,
                parameters=unknown,
                accepted=sorted(rule.known),
            )
        elif twice:
            code = "repeated_parameter"
            response = problem(
                422,
                "Unprocessable content",
                f"{twice[0]} is given {counts[twice[0]]} times; {where} takes one value of it",
                code=code,
                parameters=twice,
            )
        else:
            return None
        if rule.pattern == _UPLOAD and scope["method"] == "POST":
            # counted as the other refused uploads are, under no camera: nothing has
            # authenticated the request (an id from the path is not a bounded label)
            FRAMES_REJECTED.labels("unknown", code).inc()
        return response

    def _rule(self, method: str, path: str) -> Rule | None:
        if self._rules is None:
            self._rules = rules(self.service.openapi())
        for rule in self._rules.get(method, ()):
            if rule.pattern.match(path):
                return rule
        return None
