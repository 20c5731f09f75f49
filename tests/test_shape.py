"""The code keeps one shape: outside the pure ``core/`` packages, no module over 600 lines and
no function over 80, so that a handler stays a handler and a service reads in one sitting."""

from __future__ import annotations

import ast

from tests.factories import ROOT

MAX_MODULE_LINES = 600
MAX_FUNCTION_LINES = 80


def _outside_core() -> list[str]:
    return sorted(
        str(p.relative_to(ROOT))
        for p in (ROOT / "app").rglob("*.py")
        if "core" not in p.relative_to(ROOT).parts
    )


def test_modules_and_functions_stay_short() -> None:
    too_long = []
    for name in _outside_core():
        source = (ROOT / name).read_text()
        if (lines := source.count("\n")) > MAX_MODULE_LINES:
            too_long.append(f"{name}: {lines} lines")
        for node in ast.walk(ast.parse(source)):
            if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
                length = (node.end_lineno or node.lineno) - node.lineno + 1
                if length > MAX_FUNCTION_LINES:
                    too_long.append(f"{name}:{node.lineno} {node.name}: {length} lines")
    assert not too_long, "\n".join(too_long)


def test_every_room_has_the_same_shape() -> None:
    for room in ("solar", "air", "cells"):
        for part in ("routers", "services", "core"):
            assert (ROOT / "app" / room / part / "__init__.py").is_file(), f"{room}/{part}"
