"""``docs/configuration.md``, made from ``Settings``: ``python -m app.platform.configuration
[--check] PATH`` writes the page, or with ``--check`` exits 1 when it differs from the settings
(``make check`` runs that, so the page never drifts from the code)."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

from pydantic.fields import FieldInfo
from pydantic_core import PydanticUndefined

from app.platform.settings import Settings

HEAD = """# Configuration

Environment variables (or a `.env` file in the working directory), all prefixed `VANTAGE_`.
This page is made from `app/platform/settings.py` (`make docs`); `make check` fails when it
differs. Lists are JSON (`VANTAGE_CORS_ORIGINS='["https://a.example"]'`).

| variable | default | meaning |
|---|---|---|
"""


def _default(info: FieldInfo) -> str:
    if info.default is PydanticUndefined or info.default is None:
        return "—"
    value: Any = info.default
    if hasattr(value, "get_secret_value"):
        return "(secret)"
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, list | dict):
        return f"`{json.dumps(value)}`"
    return f"`{value}`"


def _meaning(name: str, info: FieldInfo) -> str:
    text = info.description or ""
    allowed = getattr(info.annotation, "__args__", None)
    if not text and allowed and all(isinstance(a, str) for a in allowed):
        text = "One of " + ", ".join(f"`{a}`" for a in allowed) + "."
    return " ".join(text.split()).replace("|", "\\|") or name.replace("_", " ").capitalize()


def render() -> str:
    """The page: one row a setting, in the order ``Settings`` declares them."""
    rows = [
        f"| `VANTAGE_{name.upper()}` | {_default(info)} | {_meaning(name, info)} |"
        for name, info in Settings.model_fields.items()
    ]
    return HEAD + "\n".join(rows) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("path", type=Path)
    parser.add_argument("--check", action="store_true", help="compare instead of writing")
    args = parser.parse_args(argv)
    page = render()
    if args.check:
        if not args.path.exists() or args.path.read_text() != page:
            print(f"{args.path} differs from Settings: run make docs", file=sys.stderr)
            return 1
        return 0
    args.path.write_text(page)
    return 0


if __name__ == "__main__":
    sys.exit(main())
