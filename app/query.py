"""Query strings: a parameter that takes one value is given one.

Starlette and FastAPI read the last of a repeated parameter without a word, so
``?camera_id=a&camera_id=b`` on an endpoint that takes one camera answered for camera b alone,
and ``?kind=raised&kind=cleared`` listed the cleared alerts alone: a confident answer to
another question. Here such a request gets 422 ``repeated_parameter``; parameters declared as
lists (``camera_id`` of ``GET /air/readings``) still take many.
"""

from __future__ import annotations

import re
from typing import Any
from urllib.parse import parse_qsl

from fastapi import FastAPI
from starlette.types import ASGIApp, Receive, Scope, Send

from app.errors import problem
from app.routes import operations

Rule = tuple[re.Pattern[str], frozenset[str]]
"""A path of the OpenAPI document as a pattern, and its operation's single-valued query
parameters."""


def _takes_many(schema: dict[str, Any]) -> bool:
    if schema.get("type") == "array":
        return True
    return any(_takes_many(s) for s in schema.get("anyOf", ()))


def rules(document: dict[str, Any]) -> dict[str, list[Rule]]:
    """Per HTTP method, each path of the OpenAPI ``document`` with its query parameters that
    take one value (every one not declared an array)."""
    out: dict[str, list[Rule]] = {}
    for pattern, method, operation in operations(document):
        single = frozenset(
            p["name"]
            for p in operation.get("parameters", ())
            if p.get("in") == "query" and not _takes_many(p.get("schema", {}))
        )
        out.setdefault(method, []).append((pattern, single))
    return out


def repeated(query_string: bytes) -> dict[str, int]:
    """The parameters given more than once, with how many times."""
    counts: dict[str, int] = {}
    for key, _ in parse_qsl(query_string.decode("latin-1"), keep_blank_values=True):
        counts[key] = counts.get(key, 0) + 1
    return {key: n for key, n in counts.items() if n > 1}


class SingleValuedQuery:
    """Refuse (422) a request that repeats a query parameter its endpoint takes once.

    A request without a repeated parameter (every frame upload) costs one scan of its query
    string, if it has one; the endpoint is looked up in the OpenAPI document (read once) only
    for a request that repeats one.
    """

    def __init__(self, app: ASGIApp, *, service: FastAPI) -> None:
        self.app = app
        self.service = service
        self._rules: dict[str, list[Rule]] | None = None

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] == "http" and scope["query_string"]:
            twice = repeated(scope["query_string"])
            if twice:
                bad = self._single_valued(scope["method"], scope["path"]) & twice.keys()
                if bad:
                    name = sorted(bad)[0]
                    response = problem(
                        422,
                        "Unprocessable content",
                        f"{name} is given {twice[name]} times; {scope['method']} "
                        f"{scope['path']} takes one value of it",
                        code="repeated_parameter",
                        parameters=sorted(bad),
                    )
                    await response(scope, receive, send)
                    return
        await self.app(scope, receive, send)

    def _single_valued(self, method: str, path: str) -> frozenset[str]:
        if self._rules is None:
            self._rules = rules(self.service.openapi())
        for pattern, single in self._rules.get(method, ()):
            if pattern.match(path):
                return single
        return frozenset()
