"""Reading upload bodies over HTTP: size-capped while streaming, raw JPEG or multipart."""

from __future__ import annotations

import csv
import io
import re
from collections.abc import AsyncGenerator, Collection
from dataclasses import dataclass
from typing import TypeVar

from fastapi import Request
from pydantic import BaseModel, ValidationError
from starlette.datastructures import UploadFile
from starlette.formparsers import MultiPartException, MultiPartParser
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from app.platform.http.errors import PayloadTooLarge, Unprocessable, UnsupportedMediaType, problem

SELF_CAPPED = re.compile(
    r"^/(?:cameras/[^/]+/frames|panels/[^/]+/baseline|panels/evaluate|air/calibration"
    r"|calibrations(?:/stereo)?|fleet/model|rigs/[^/]+/laser/(?:dot|grid)|vision/[^/]+)$"
)
"""Routes that read their body themselves through ``read_capped``, after authenticating: the
frame upload, and the multipart uploads of many images."""
BULK = re.compile(r"^/rigs/[^/]+/triangulate$")
"""JSON routes that take many points in one request: capped at ``max_upload_bytes``."""


class BodyLimitMiddleware:
    """Refuse (413) a JSON body over its route's cap before FastAPI buffers it.

    FastAPI reads and parses a route's whole body before any dependency runs, even before the
    token is checked; without this one request could make the process hold gigabytes. A
    declared Content-Length over the cap is refused without reading a byte; a body without one
    (chunked) is read here up to the cap and handed on, or refused as soon as it passes it.
    """

    def __init__(self, app: ASGIApp, *, body: int, bulk: int) -> None:
        self.app = app
        self.body = body
        self.bulk = bulk

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http" or SELF_CAPPED.match(scope["path"]):
            await self.app(scope, receive, send)
            return
        limit = self.bulk if BULK.match(scope["path"]) else self.body
        declared = next((v for k, v in scope["headers"] if k == b"content-length"), None)
        if declared is not None:
            if declared.isdigit() and int(declared) > limit:
                await _too_large(f"body of {int(declared)} bytes", limit)(scope, receive, send)
            else:  # the server delivers no more than declared
                await self.app(scope, receive, send)
            return
        chunks: list[bytes] = []
        size = 0
        while True:
            message = await receive()
            if message["type"] != "http.request":
                return  # the client went away
            chunk = message.get("body", b"")
            size += len(chunk)
            if size > limit:
                await _too_large("body", limit)(scope, receive, send)
                return
            chunks.append(chunk)
            if not message.get("more_body", False):
                break
        replay: list[Message] = [{"type": "http.request", "body": b"".join(chunks)}]

        async def replayed() -> Message:
            return replay.pop() if replay else await receive()

        await self.app(scope, replayed, send)


def _too_large(what: str, limit: int) -> ASGIApp:
    return problem(
        413, "Payload too large", f"{what} exceeds the limit of {limit} bytes", code="too_large"
    )


async def read_capped(request: Request, limit: int) -> bytes:
    """The whole body, refusing (413) as soon as it is known to exceed ``limit`` bytes.

    A declared Content-Length over the limit is refused before a byte is read; a chunked or
    lying body is cut off when the running count passes the limit.
    """
    coding = request.headers.get("content-encoding", "identity").strip().lower()
    if coding != "identity":  # RFC 9110 §15.5.16
        raise UnsupportedMediaType(
            f"Content-Encoding {coding!r} is not accepted: send the body as it is (a JPEG is "
            "compressed already)",
            code="content_encoding",
            headers={"Accept-Encoding": "identity"},
        )
    declared = request.headers.get("content-length")
    if declared is not None:
        try:
            size = int(declared)
        except ValueError:
            raise Unprocessable("Content-Length is not a number") from None
        if size > limit:
            raise PayloadTooLarge(
                f"body of {size} bytes exceeds the limit of {limit}", code="too_large"
            )
    body = bytearray()
    async for chunk in request.stream():
        body += chunk
        if len(body) > limit:
            raise PayloadTooLarge(f"body exceeds the limit of {limit} bytes", code="too_large")
    return bytes(body)


async def _once(data: bytes) -> AsyncGenerator[bytes, None]:
    yield data


@dataclass(frozen=True, slots=True)
class Form:
    files: list[tuple[str, str | None, bytes]]
    """(field, filename, bytes) in the order sent."""
    fields: dict[str, list[str]]
    """Text fields, each with its values in the order sent."""

    def files_of(self, field: str) -> list[tuple[str | None, bytes]]:
        return [(name, data) for f, name, data in self.files if f == field]

    def required_files(self, field: str) -> list[tuple[str | None, bytes]]:
        """``files_of(field)``; Unprocessable (``no_file``) when there is none."""
        files = self.files_of(field)
        if not files:
            raise Unprocessable(f"multipart body has no file in field {field!r}", code="no_file")
        return files

    def groups_of(self, files: int) -> list[str] | None:
        """The optional ``groups`` field: one name per file (a photo's day or panel), stripped
        as cut from a CSV; None when not sent. A count that differs from ``files`` or an empty
        name: Unprocessable."""
        groups = self.fields.get("groups")
        if not groups:
            return None
        if len(groups) != files:
            raise Unprocessable(
                f"{files} files but {len(groups)} groups; give one group each, or none",
                code="groups_mismatch",
            )
        names = [g.strip() for g in groups]
        if not all(names):
            raise Unprocessable("a group is empty: name each file's group", code="empty_group")
        return names


async def read_form(
    request: Request, limit: int, *, max_files: int, parts: Collection[str] | None
) -> Form:
    """A multipart body of at most ``limit`` bytes, parsed. With ``parts`` (the fields the
    route reads, files or text), any other field is refused (422): an option sent as a form
    field instead of in the query (``-F significance=0.01``) was silently left at its default,
    a misspelt field (``dot_file``) silently dropped."""
    media_type = request.headers.get("content-type", "")
    if not media_type.lower().startswith("multipart/form-data"):
        raise UnsupportedMediaType(
            "the body must be multipart/form-data (curl -F file=@photo.jpg); it came as "
            f"{media_type.split(';')[0] or 'no Content-Type'}",
            code="not_multipart",
        )
    body = await read_capped(request, limit)
    parser = MultiPartParser(
        request.headers, _once(body), max_files=max_files, max_fields=10_000, max_part_size=limit
    )
    try:
        form = await parser.parse()
    except MultiPartException as exc:
        raise Unprocessable(
            f"malformed multipart body: {exc.message}", code="bad_multipart"
        ) from None
    try:
        files: list[tuple[str, str | None, bytes]] = []
        fields: dict[str, list[str]] = {}
        for key, item in form.multi_items():
            if isinstance(item, UploadFile):
                files.append((key, item.filename, await item.read()))
            else:
                fields.setdefault(key, []).append(item)
    finally:
        await form.close()
    if parts is not None:
        unexpected = sorted(({f for f, _, _ in files} | fields.keys()) - set(parts))
        if unexpected:
            raise Unprocessable(
                f"unexpected form field(s) {', '.join(map(repr, unexpected))}: this upload "
                f"takes {', '.join(map(repr, parts))}; its options go in the query string "
                "(see /docs)",
                code="unexpected_field",
            )
    return Form(files, fields)


async def read_files(
    request: Request, field: str, limit: int, *, max_files: int = 1
) -> list[tuple[str | None, bytes]]:
    """The files of a multipart body's (repeated) ``field``: [(filename, bytes), ...]."""
    form = await read_form(request, limit, max_files=max_files, parts=(field,))
    return form.required_files(field)


RAW_JPEG_TYPES = frozenset({"image/jpeg", "image/jpg", "image/pjpeg", "application/octet-stream"})
"""Content types a raw frame upload may carry. ``image/pjpeg`` (a "progressive JPEG" type of
old browsers, sent by older camera firmware for any JPEG) got 415 as a raw body, though the
same file in a multipart form, whose part types are not read, was taken."""


@dataclass(frozen=True, slots=True)
class FrameUpload:
    data: bytes
    """The JPEG."""
    captured_at: str | None = None
    """A multipart upload's text field ``captured_at``, as sent (IP cameras that post a form
    send their fields with the file)."""


async def read_jpeg(request: Request, limit: int) -> FrameUpload:
    """The JPEG of a frame upload: a raw ``image/jpeg`` body (or ``application/octet-stream``,
    as many cameras and scripts label any bytes, or ``image/pjpeg``, which older camera
    firmware sends for its JPEGs: the JPEG is checked either way) or multipart field
    ``file``."""
    content_type = request.headers.get("content-type", "").split(";")[0].strip().lower()
    if content_type in RAW_JPEG_TYPES:
        return FrameUpload(await read_capped(request, limit))
    if content_type == "multipart/form-data":
        # lenient: a camera's form may carry fields of its own
        form = await read_form(request, limit, max_files=1, parts=None)
        files = form.files_of("file")
        if not files:
            elsewhere = [f for f, _, _ in form.files]
            raise Unprocessable(
                "multipart body has no file in field 'file'"
                + (
                    f" (its file is in {elsewhere[0]!r}: name that field 'file')"
                    if elsewhere
                    else ""
                ),
                code="no_file",
            )
        when = form.fields.get("captured_at", [])
        if len(when) > 1:
            raise Unprocessable("captured_at is given more than once", code="bad_time")
        return FrameUpload(files[0][1], when[0] if when else None)
    raise UnsupportedMediaType(
        "expected Content-Type image/jpeg (or application/octet-stream) or multipart/form-data;"
        f" got {content_type or 'none'!r}",
        code="not_jpeg",
    )


M = TypeVar("M", bound=BaseModel)


async def read_json(request: Request, model: type[M], limit: int) -> M:
    """A JSON body of at most ``limit`` bytes, validated as ``model`` (422 when it is not)."""
    body = await read_capped(request, limit)
    try:
        return model.model_validate_json(body)
    except ValidationError as exc:
        where, message = first_error(exc)
        raise Unprocessable(f"{where}: {message}" if where else message) from None


def first_error(exc: ValidationError) -> tuple[str, str]:
    """Where the first of pydantic's errors is (its location, dotted) and what it says."""
    first = exc.errors()[0]
    return ".".join(str(p) for p in first["loc"]), first["msg"]


def item_error(exc: ValidationError, items: str) -> str:
    """The first of pydantic's errors over a list named ``items``, located as a client writes
    it (``days[3].kwh``), and what it says."""
    first = exc.errors()[0]
    at, *inside = first["loc"] or ("",)
    return f"{items}[{at}]" + "".join(f".{p}" for p in inside) + f": {first['msg']}"


def csv_models(
    text: str,
    model: type[M],
    *,
    required: Collection[str],
    columns: Collection[str],
    code: str,
    limit: int,
) -> list[tuple[int, M]]:
    """The rows of a CSV as ``model``, each with its line number: the header must name every
    ``required`` column; of each row the ``columns`` it fills are validated (an empty cell is
    left out, other columns ignored); 422 ``code`` naming the first bad line and field. At most
    ``limit`` + 1 rows are read: the caller refuses more."""
    rows = csv.DictReader(io.StringIO(text.lstrip("\ufeff")))
    missing = set(required) - set(rows.fieldnames or ())
    if missing:
        raise Unprocessable(
            f"the CSV's header must name {' and '.join(required)}; missing "
            f"{', '.join(sorted(missing))}",
            code=code,
        )
    out: list[tuple[int, M]] = []
    for line, row in enumerate(rows, start=2):
        given = {k: v.strip() for k in columns if (v := row.get(k)) is not None and v.strip()}
        try:
            out.append((line, model.model_validate(given)))
        except ValidationError as exc:
            where, message = first_error(exc)
            raise Unprocessable(f"line {line}, {where}: {message}", code=code) from None
        if len(out) > limit:
            break
    return out


def content_type(request: Request) -> str:
    return request.headers.get("content-type", "").split(";")[0].strip().lower()


async def images_or_frames(
    request: Request,
    frames: type[M],
    *,
    upload_limit: int,
    body_limit: int,
    max_files: int,
    parts: Collection[str],
    expected: str,
) -> Form | M:
    """What a model is trained from: uploaded images (a multipart form of ``parts``, at most
    ``upload_limit`` bytes and ``max_files`` files) or stored frames named in a JSON body
    (``frames``, at most ``body_limit`` bytes). Any other body: 415 naming what is
    ``expected``. One reading for every "train from images or stored frames" route."""
    kind = content_type(request)
    if kind == "multipart/form-data":
        return await read_form(request, upload_limit, max_files=max_files, parts=parts)
    if kind == "application/json":
        return await read_json(request, frames, body_limit)
    raise UnsupportedMediaType(f"send {expected}")
