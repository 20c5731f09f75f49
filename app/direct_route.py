"""A route whose parameters are read from a plan made once, not solved again per request.

FastAPI works each request's parameters out from the endpoint's signature anew: which of them
are models, which sequences, which aliases apply, for every parameter of the endpoint and of
its dependencies. For the frame upload (a path parameter, a query parameter, a header and the
camera dependency) that took about 6 times the CPU of the bare endpoint's one ``Request``
(yappi; bench/README.md, "Parameters read from a plan"). ``DirectRoute`` makes that plan when the
route is built and, per request, only looks each value up and has its own field validate it,
as FastAPI does: values, defaults, error messages and their order are FastAPI's, and the
OpenAPI document (and everything read from it, ``app.platform.http.query``'s rules) is the route's own.

It takes endpoints whose parameters are the ``Request`` and path, query and header parameters
of one value each, and dependencies (plain functions or coroutine functions) of the same kind,
returning a ``Response`` themselves; a route it cannot serve so is refused when it is built.
With ``app.dependency_overrides`` set (tests), FastAPI's own handler serves it. A dependency
used twice (which FastAPI calls once a request) is refused too.

It reads FastAPI's own fields and errors (``fastapi._compat``) and the route's inclusion context,
as FastAPI's handler does, in the pinned FastAPI version; ``tests/api/test_direct_route.py``
compares its answers with FastAPI's, so an upgrade that changes either fails there first.
"""

from __future__ import annotations

import inspect
from collections.abc import Callable, Coroutine
from copy import deepcopy
from dataclasses import dataclass
from typing import Any

from fastapi import params, routing
from fastapi._compat import ModelField, field_annotation_is_sequence, get_missing_field_error
from fastapi.concurrency import run_in_threadpool
from fastapi.dependencies.models import Dependant
from fastapi.exceptions import RequestValidationError
from fastapi.routing import APIRoute
from starlette.requests import Request
from starlette.responses import Response

_SOURCES = {
    params.ParamTypes.path: "path_params",
    params.ParamTypes.query: "query_params",
    params.ParamTypes.header: "headers",
}


@dataclass(frozen=True, slots=True)
class _Param:
    name: str
    """The argument's name."""
    key: str
    """Where its value is found: the path parameter's, query parameter's or header's name."""
    source: str
    """The request's attribute holding it: ``path_params``, ``query_params`` or ``headers``."""
    loc: tuple[str, str]
    """Where an error about it points (``("query", "captured_at")``), as FastAPI's."""
    field: ModelField


@dataclass(frozen=True, slots=True)
class _Plan:
    call: Callable[..., Any]
    is_coroutine: bool
    request_name: str | None
    params: tuple[_Param, ...]
    """In FastAPI's order: path, query, header."""
    dependencies: tuple[tuple[str, _Plan], ...]


class UnsupportedRoute(TypeError):
    """The endpoint takes something ``DirectRoute`` does not read (a body, a cookie, a
    generator dependency, a list parameter …)."""


def _param(field: ModelField) -> _Param:
    info = field.field_info
    if not isinstance(info, params.Param) or info.in_ not in _SOURCES:
        raise UnsupportedRoute(f"parameter {field.name!r} is neither path, query nor header")
    if info.validation_alias not in (None, field.alias):  # AliasChoices, AliasPath
        raise UnsupportedRoute(f"parameter {field.name!r} has aliases of its own")
    key = field.alias
    if info.in_ == params.ParamTypes.header:
        key = key.lower()
    return _Param(field.name, key, _SOURCES[info.in_], (info.in_.value, field.alias), field)


def _plan(dependant: Dependant) -> _Plan:
    if dependant.call is None:
        raise UnsupportedRoute("a dependency without a callable")
    extra = (
        dependant.body_params,
        dependant.cookie_params,
        dependant.http_connection_param_name,
        dependant.websocket_param_name,
        dependant.background_tasks_param_name,
        dependant.response_param_name,
        dependant.security_scopes_param_name,
    )
    if any(extra) or dependant.own_oauth_scopes or dependant.parent_oauth_scopes:
        raise UnsupportedRoute(f"{dependant.call!r} takes more than the request's parameters")
    call = inspect.unwrap(dependant.call)
    if inspect.isgeneratorfunction(call) or inspect.isasyncgenfunction(call):
        raise UnsupportedRoute(f"{dependant.call!r} is a generator dependency")
    if dependant.concurrency is not None:
        raise UnsupportedRoute(f"{dependant.call!r} has a concurrency limit")
    fields = (*dependant.path_params, *dependant.query_params, *dependant.header_params)
    for field in fields:
        if field_annotation_is_sequence(field.field_info.annotation):
            raise UnsupportedRoute(f"parameter {field.name!r} takes many values")
    subs = []
    for sub in dependant.dependencies:
        if sub.name is None:
            raise UnsupportedRoute(f"{sub.call!r} is a dependency without a parameter")
        subs.append((sub.name, _plan(sub)))
    return _Plan(
        dependant.call,
        inspect.iscoroutinefunction(call),
        dependant.request_param_name,
        tuple(_param(f) for f in fields),
        tuple(subs),
    )


def _dependencies(plan: _Plan) -> list[Callable[..., Any]]:
    """Every dependency's callable in ``plan``'s tree, as often as it is used."""
    return [c for _, sub in plan.dependencies for c in (sub.call, *_dependencies(sub))]


async def _solve(plan: _Plan, request: Request, errors: list[Any]) -> dict[str, Any] | None:
    """The arguments of ``plan``'s call, or None (and ``errors`` extended) when a parameter
    of it or of its dependencies is not valid. Dependencies are called first, in order, as
    FastAPI calls them: one whose own parameters fail is not called, the others are."""
    values: dict[str, Any] = {}
    failed = False
    for name, sub in plan.dependencies:
        found = await _solve(sub, request, errors)
        if found is None:
            failed = True
            continue
        if sub.is_coroutine:
            values[name] = await sub.call(**found)
        else:
            values[name] = await run_in_threadpool(sub.call, **found)
    for p in plan.params:
        value = getattr(request, p.source).get(p.key)
        if value is None:
            if p.field.field_info.is_required():
                errors.append(get_missing_field_error(loc=p.loc))
                failed = True
                continue
            value = deepcopy(p.field.default)
            if not p.field.field_info.validate_default:
                values[p.name] = value
                continue
        checked, problems = p.field.validate(value, values, loc=p.loc)
        if problems:
            errors.extend(problems)
            failed = True
        else:
            values[p.name] = checked
    if plan.request_name is not None:
        values[plan.request_name] = request
    return None if failed else values


class DirectRoute(APIRoute):
    """An ``APIRoute`` served from a plan of its parameters made once (module docstring)."""

    def get_route_handler(self) -> Callable[[Request], Coroutine[Any, Any, Response]]:
        generic = super().get_route_handler()
        # included in a router or app, the route is served as that inclusion's context (its
        # dependant holds the router's dependencies too), as ``APIRoute``'s own handler is
        route: Any = self
        context = routing._effective_route_context_var.get()  # noqa: SLF001
        if context is not None and context.original_route is self:
            route = context
        plan = _plan(route.dependant)
        if not plan.is_coroutine:
            raise UnsupportedRoute(f"{self.endpoint!r} is not a coroutine function")
        used = [inspect.unwrap(call) for call in _dependencies(plan)]
        if len(set(used)) < len(used):  # FastAPI calls it once a request and shares the value
            raise UnsupportedRoute(f"{self.endpoint!r} uses a dependency twice")
        overrides = route.dependency_overrides_provider

        async def handler(request: Request) -> Response:
            if overrides is not None and getattr(overrides, "dependency_overrides", None):
                return await generic(request)
            errors: list[Any] = []
            values = await _solve(plan, request, errors)
            if values is None:
                raise RequestValidationError(errors)
            response = await plan.call(**values)
            if not isinstance(response, Response):
                raise TypeError(f"{self.endpoint!r} must return a Response")
            return response

        return handler
