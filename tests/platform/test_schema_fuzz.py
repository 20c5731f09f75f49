"""Schemathesis against the service's own OpenAPI schema: no 5xx, errors are problem+json, and
every response is one the schema documents (its status code, content type and body).

Examples are bounded (``MAX_EXAMPLES`` per operation) so the run stays within a few minutes.
"""

from __future__ import annotations

import json
import os
from typing import Any

import pytest
import schemathesis
from hypothesis import HealthCheck, given, settings
from schemathesis.specs.openapi.checks import (
    content_type_conformance,
    response_schema_conformance,
    status_code_conformance,
)

from tests.factories import ADMIN_TOKEN

MAX_EXAMPLES = int(os.environ.get("VANTAGE_FUZZ_EXAMPLES", "40"))
"""Examples per operation; more with VANTAGE_FUZZ_EXAMPLES for a longer search."""
DERANDOMIZE = os.environ.get("VANTAGE_FUZZ_RANDOM") is None
"""Deterministic examples in CI; set VANTAGE_FUZZ_RANDOM to explore new ones."""
ADMIN = {"Authorization": f"Bearer {ADMIN_TOKEN}"}
CONFORMANCE = [status_code_conformance, content_type_conformance, response_schema_conformance]


@pytest.mark.slow
def test_no_server_errors(app: Any, client: Any) -> None:
    client.post("/panels", json={"id": "p1"}, headers=ADMIN)
    schema = schemathesis.openapi.from_asgi("/openapi.json", app)
    failures: list[str] = []
    for result in schema.get_all_operations():
        operation = result.ok()

        @given(case=operation.as_strategy())
        @settings(
            max_examples=MAX_EXAMPLES,
            deadline=None,
            database=None,
            derandomize=DERANDOMIZE,
            suppress_health_check=list(HealthCheck),
        )
        def check(case: Any) -> None:
            response = case.call(headers=ADMIN)
            if response.status_code >= 500:
                failures.append(
                    f"{case.method} {case.formatted_path}: {response.status_code} "
                    f"{response.text[:200]}"
                )
            elif response.status_code >= 400:
                ctype = response.headers.get("content-type", "")
                ctype = ctype[0] if isinstance(ctype, list) else ctype
                if not ctype.startswith("application/problem+json"):
                    failures.append(
                        f"{case.method} {case.formatted_path}: {response.status_code} as {ctype}"
                    )
                else:
                    body = json.loads(response.text)
                    if not {"title", "status", "detail"} <= set(body):
                        failures.append(f"{case.method} {case.formatted_path}: {body}")
            try:
                case.validate_response(response, checks=CONFORMANCE)
            except Exception as exc:  # schemathesis reports its findings as an exception group
                failures.append(f"{case.method} {case.path}: {str(exc)[:300]}")

        check()
    assert failures == [], "\n".join(sorted(set(failures))[:20])
