"""``DirectRoute`` answers exactly as FastAPI's own handler does, for every case its plan reads:
each request below is sent to two copies of one endpoint, one served by each, and the answers
compared whole (status, body). The frame upload's own errors are covered in test_frames.py."""

from __future__ import annotations

from collections.abc import Iterator
from datetime import datetime
from typing import Annotated

import pytest
from fastapi import Body, Depends, FastAPI, Header, Path, Query, Request
from fastapi.responses import JSONResponse, Response
from fastapi.testclient import TestClient

from app.direct_route import DirectRoute, UnsupportedRoute
from app.platform.http.errors import install_error_handlers

CALLS: list[str] = []


async def owner(
    item_id: Annotated[str, Path(pattern=r"^[a-z]{1,8}$")],
    request: Request,
    authorization: Annotated[str | None, Header()] = None,
) -> str:
    CALLS.append(item_id)
    if authorization == "refuse":
        from app.platform.http.errors import Unauthorized

        raise Unauthorized("refused")
    return f"{item_id}@{request.method}"


def counter(limit: Annotated[int, Query(ge=0, le=9)] = 3) -> int:
    return limit * 2


async def endpoint(
    request: Request,
    who: Annotated[str, Depends(owner)],
    twice: Annotated[int, Depends(counter)],
    at: Annotated[datetime | None, Query()] = None,
    key: Annotated[str | None, Header(max_length=4, alias="x-key")] = None,
    idempotency_key: Annotated[str | None, Header(max_length=5)] = None,
    size: Annotated[int, Query(gt=0)] = 7,
    needed: Annotated[str | None, Query(min_length=2)] = None,
) -> Response:
    body = {
        "who": who,
        "twice": twice,
        "at": at.isoformat() if at else None,
        "key": key,
        "idempotency_key": idempotency_key,
        "size": size,
        "needed": needed,
        "method": request.method,
    }
    return JSONResponse(body, status_code=201)


async def required_query(q: Annotated[int, Query()]) -> Response:
    return JSONResponse({"q": q})


@pytest.fixture(scope="module")
def client() -> Iterator[TestClient]:
    app = FastAPI()
    install_error_handlers(app)
    for prefix, route_class in (("/plain", None), ("/direct", DirectRoute)):
        app.router.add_api_route(
            prefix + "/{item_id}", endpoint, methods=["POST"], route_class_override=route_class
        )
        app.router.add_api_route(
            prefix + "-q", required_query, methods=["GET"], route_class_override=route_class
        )
    with TestClient(app) as c:
        yield c


CASES = [
    ("post", "/{}/abc", {}, {}),
    ("post", "/{}/abc", {"at": "2026-01-02T03:04:05+02:00", "size": "3", "limit": "4"}, {}),
    ("post", "/{}/abc", {"at": "not a time"}, {}),
    ("post", "/{}/abc", {"at": ""}, {}),
    ("post", "/{}/abc", {"size": "0", "limit": "12"}, {}),
    ("post", "/{}/abc", {"needed": "x"}, {"x-key": "toolong"}),
    ("post", "/{}/abc", {}, {"idempotency-key": "123456", "x-key": "ok"}),
    ("post", "/{}/ABC!", {"at": "nope"}, {}),  # the dependency's path parameter and another
    ("post", "/{}/ABC!", {}, {"authorization": "refuse"}),  # a failed dependency is not called
    ("post", "/{}/abc", {"at": "nope"}, {"authorization": "refuse"}),  # called first: 401
    ("post", "/{}/abc", {"limit": "x"}, {"authorization": "refuse"}),
    ("get", "/{}-q", {}, {}),
    ("get", "/{}-q", {"q": "1"}, {}),
    ("get", "/{}-q", {"q": "one"}, {}),
]


@pytest.mark.parametrize(("method", "path", "query", "headers"), CASES)
def test_answers_as_fastapi_does(
    client: TestClient, method: str, path: str, query: dict[str, str], headers: dict[str, str]
) -> None:
    answers = []
    for prefix in ("plain", "direct"):
        CALLS.clear()
        r = client.request(method, path.format(prefix), params=query, headers=headers)
        answers.append((r.status_code, r.json(), list(CALLS)))
    assert answers[0] == answers[1]


def test_the_cases_reach_every_outcome(client: TestClient) -> None:
    """The comparison above is worth something only if the cases hit success, 422 and the
    dependency's own refusal."""
    statuses = set()
    for method, path, query, headers in CASES:
        r = client.request(method, path.format("direct"), params=query, headers=headers)
        statuses.add(r.status_code)
    assert statuses == {200, 201, 401, 422}


async def with_body(item: Annotated[dict[str, int], Body()]) -> Response:
    return Response()


async def with_list(ids: Annotated[list[str], Query()]) -> Response:
    return Response()


def generator() -> Iterator[int]:
    yield 1


async def with_generator(value: Annotated[int, Depends(generator)]) -> Response:
    return Response()


def not_a_coroutine(request: Request) -> Response:
    return Response()


async def with_a_dependency_twice(
    a: Annotated[int, Depends(counter)], b: Annotated[int, Depends(counter)]
) -> Response:
    return Response()


@pytest.mark.parametrize(
    "fn", [with_body, with_list, with_generator, not_a_coroutine, with_a_dependency_twice]
)
def test_a_route_it_cannot_read_is_refused_when_built(fn: object) -> None:
    app = FastAPI()
    with pytest.raises(UnsupportedRoute):
        app.router.add_api_route("/x", fn, methods=["POST"], route_class_override=DirectRoute)  # type: ignore[arg-type]


def test_overridden_dependencies_are_honoured() -> None:
    app = FastAPI()
    install_error_handlers(app)
    app.router.add_api_route(
        "/direct/{item_id}", endpoint, methods=["POST"], route_class_override=DirectRoute
    )
    app.dependency_overrides[owner] = lambda: "stand-in"
    with TestClient(app) as c:
        r = c.post("/direct/abc")
    assert r.status_code == 201
    assert r.json()["who"] == "stand-in"
