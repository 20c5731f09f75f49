"""What every ``vantage`` command shares: the service it calls, the user's errors, the CSV
and image folders it reads, how it says its result."""

from __future__ import annotations

import argparse
import csv
import json
from pathlib import Path
from typing import Any

import httpx2 as httpx
from rich.console import Console

IMAGE_SUFFIXES = (".jpg", ".jpeg", ".png", ".tif", ".tiff")
err = Console(stderr=True)


class Failed(Exception):
    """What the service or the input refused, as the user is told it."""


class Service:
    """The running service: its URL and a token."""

    def __init__(self, url: str, token: str | None, timeout: float = 300.0) -> None:
        token = token and token.strip()  # as read from a file or a CSV cell: no token has spaces
        headers = {"Authorization": f"Bearer {token}"} if token else {}
        self.http = httpx.Client(base_url=url.rstrip("/"), headers=headers, timeout=timeout)
        self.url = url

    def close(self) -> None:
        self.http.close()

    def call(self, method: str, path: str, **kw: Any) -> httpx.Response:
        try:
            r = self.http.request(method, path, **kw)
        except httpx.TransportError as exc:
            raise Failed(f"cannot reach the service at {self.url}: {exc}") from None
        if r.status_code >= 400:
            raise Failed(f"{method} {path}: {r.status_code} {reason(r)}")
        return r


def reason(r: httpx.Response) -> str:
    """The problem's detail (RFC 9457), else the body's start."""
    try:
        body = r.json()
    except ValueError:
        return r.text[:300]
    if isinstance(body, dict):
        return str(body.get("detail") or body.get("title") or body)[:1000]
    return str(body)[:300]


def rows(path: Path) -> list[dict[str, str]]:
    try:
        with path.open(newline="", encoding="utf-8-sig") as f:
            return [
                {k.strip(): (v or "").strip() for k, v in row.items() if k}
                for row in csv.DictReader(f)
            ]
    except OSError as exc:
        raise Failed(f"cannot read {path}: {exc.strerror}") from None


def images(folder: Path) -> list[Path]:
    if not folder.is_dir():
        raise Failed(f"{folder} is not a folder")
    found = sorted(p for p in folder.rglob("*") if p.suffix.lower() in IMAGE_SUFFIXES)
    if not found:
        raise Failed(f"no images ({', '.join(IMAGE_SUFFIXES)}) in {folder}")
    return found


def say(args: argparse.Namespace, summary: str, body: Any) -> None:
    """The command's result on standard output: a line a person reads, or with ``--json``
    the service's whole answer."""
    print(json.dumps(body, indent=2) if args.json else summary)


def warn(body: dict[str, Any]) -> None:
    for w in body.get("warnings") or []:
        err.print(f"[yellow]warning:[/] {w}")


def number(value: str, name: str, row: int) -> float | None:
    if value == "":
        return None
    try:
        return float(value)
    except ValueError:
        raise Failed(f"row {row}: {name} {value!r} is not a number") from None
