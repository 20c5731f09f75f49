"""Shaping rows into response bodies, and the error responses routes declare in OpenAPI."""

from __future__ import annotations

from typing import Any

from pydantic import BaseModel


def _problem(description: str) -> dict[str, Any]:
    return {
        "description": description,
        "content": {
            "application/problem+json": {
                "schema": {
                    "type": "object",
                    "properties": {
                        "type": {"type": "string"},
                        "title": {"type": "string"},
                        "status": {"type": "integer"},
                        "detail": {"type": "string"},
                    },
                    "required": ["title", "status", "detail"],
                }
            }
        },
    }


Responses = dict[int | str, dict[str, Any]]

AUTH_ERRORS: Responses = {
    401: _problem("Missing or unknown token"),
    403: _problem("Valid token of the wrong role or for another camera"),
}
NOT_FOUND: Responses = {404: _problem("No such resource")}
CONFLICT: Responses = {409: _problem("The id is taken")}
CAMERA_RETIRED: Responses = {409: _problem("The camera is retired")}
CAMERA_KEEPS_KIND: Responses = {
    409: _problem("The camera is retired, or has stored frames and so keeps its kind")
}
ROBOT_RETIRED: Responses = {409: _problem("The robot is retired")}
PANEL_RETIRED: Responses = {409: _problem("The panel is retired")}
PANEL_IN_USE: Responses = {409: _problem("Cameras in service watch the panel")}
UNPROCESSABLE: Responses = {422: _problem("Invalid input")}
BODY_ERRORS: Responses = {
    413: _problem("Body over the size limit"),
    415: _problem("Not a media type the endpoint takes"),
}
DATABASE_UNAVAILABLE: Responses = {
    503: _problem(
        "The database cannot be reached, is busy, read-only or out of disk (code "
        "`database_unavailable`): try again after Retry-After"
    )
}
"""Every operation's: declared once, for the whole application."""
UPLOAD_UNAVAILABLE: Responses = {
    503: _problem(
        "Send the frame again after Retry-After: the database cannot take it (code "
        "`database_unavailable`), the frame store cannot (`store_unavailable`) or its disk is "
        "down to the space kept for the database (`disk_full`), the frame was not stored "
        "within the upload timeout (`upload_timeout`), or the camera was changed again and "
        "again while the frame was measured (`camera_changing`)"
    )
}
UPLOAD_ERRORS: Responses = {
    413: BODY_ERRORS[413],
    415: _problem("Not a JPEG"),
    422: _problem("Truncated or undecodable JPEG, over the pixel limit, or bad parameters"),
}


def multipart_body(
    *, required: bool = True, json: type[BaseModel] | None = None, **fields: str
) -> dict[str, Any]:
    """``openapi_extra`` for a multipart body read by hand: field name → ``file``, ``files``
    (repeated), ``text`` or ``texts`` (repeated); ``json``: the model of the JSON body the
    route takes instead."""
    kinds = {
        "file": {"type": "string", "format": "binary"},
        "files": {"type": "array", "items": {"type": "string", "format": "binary"}},
        "text": {"type": "string"},
        "texts": {"type": "array", "items": {"type": "string"}},
    }
    schema = {"type": "object", "properties": {name: kinds[kind] for name, kind in fields.items()}}
    content: dict[str, Any] = {"multipart/form-data": {"schema": schema}}
    if json is not None:
        content["application/json"] = {"schema": json.model_json_schema()}
    return {"requestBody": {"required": required, "content": content}}


def not_modified(if_none_match: str | None, etag: str) -> bool:
    """Whether a client's ``If-None-Match`` names this ETag (or ``*``), compared weakly as RFC
    9110 §13.1.2 asks: ``W/"a"`` and ``"a"`` match."""
    if not if_none_match:
        return False
    tags = {t.strip().removeprefix("W/") for t in if_none_match.split(",")}
    return etag.removeprefix("W/") in tags or "*" in tags
