"""Multipart uploads take the fields they read and refuse others (422 ``unexpected_field``).

An option sent as a form field (``curl -F significance=0.01``) was silently left at its default,
and a misspelt field (``dot_file``) silently dropped: the answer looked right and was not.
"""

from __future__ import annotations

from typing import Any

import pytest
from fastapi.testclient import TestClient
from sqlalchemy import Engine

from tests.factories import make_jpeg, table_counts

CROSS = {"id": "cell", "kind": "cross", "f_px": 1000, "ax": 0.3, "ay": 0.2}


def images(field: str, n: int) -> list[tuple[str, tuple[str, bytes, str]]]:
    return [
        (field, (f"{i}.jpg", make_jpeg(64, 48, noise=3, seed=i), "image/jpeg")) for i in range(n)
    ]


@pytest.mark.parametrize(
    ("path", "files", "data", "unexpected"),
    [
        ("/panels/p/baseline", images("files", 5), {"significance": "0.01"}, "significance"),
        (
            "/panels/evaluate",
            images("clean", 5) + images("dirty", 2),
            {"shrinkage": "1"},
            "shrinkage",
        ),
        (
            "/air/calibration",
            images("files", 2),
            {"levels": ["3", "7"], "method": "regression"},
            "method",
        ),
        (
            "/air/calibration",
            images("files", 2) + images("file", 1),
            {"levels": ["3", "7"]},
            "file",
        ),
        ("/fleet/model", images("files", 2), {"label": ["clean", "dirty"]}, "label"),
        ("/calibrations", images("files", 3), {"pattern_col": "7"}, "pattern_col"),
        ("/calibrations/stereo", images("left", 1) + images("rigth", 1), {}, "rigth"),
        ("/rigs/cell/laser/dot", images("files", 4), {"origin": "[]"}, "origin"),
        ("/rigs/cell/laser/grid", images("files", 4) + images("dot_file", 4), {}, "dot_file"),
        ("/vision/outline", images("file", 1), {"threshold": "3"}, "threshold"),
    ],
)
def test_a_field_the_upload_does_not_take_is_refused(
    client: TestClient,
    admin: dict[str, str],
    engine: Engine,
    path: str,
    files: Any,
    data: dict[str, Any],
    unexpected: str,
) -> None:
    assert client.post("/panels", json={"id": "p"}, headers=admin).status_code == 201
    assert client.post("/rigs", json=CROSS, headers=admin).status_code == 201
    before = table_counts(engine)
    r = client.post(path, files=files, data=data, headers=admin)
    assert r.status_code == 422, r.text
    assert r.headers["content-type"] == "application/problem+json"
    assert r.json()["code"] == "unexpected_field"
    assert repr(unexpected) in r.json()["detail"]
    assert "query string" in r.json()["detail"]
    assert table_counts(engine) == before


def test_an_option_in_the_form_is_not_left_at_its_default(
    client: TestClient, admin: dict[str, str]
) -> None:
    """Six clean panel photos and ``-F significance=0.01``: before, 201 with the default 0.05.
    In the query, the option is taken."""
    from tests.factories.solar import CLEAN_RGB, panel_jpeg

    client.post("/panels", json={"id": "p"}, headers=admin)
    photos = [
        ("files", (f"{k}.jpg", panel_jpeg(CLEAN_RGB, seed=k), "image/jpeg")) for k in range(6)
    ]
    r = client.post(
        "/panels/p/baseline", files=photos, data={"significance": "0.01"}, headers=admin
    )
    assert r.status_code == 422, r.text
    assert "'significance'" in r.json()["detail"]
    assert client.get("/panels/p/baseline", headers=admin).status_code == 404
    r = client.post(
        "/panels/p/baseline", files=photos, params={"significance": "0.01"}, headers=admin
    )
    assert r.status_code == 201, r.text
    assert r.json()["significance"] == 0.01


def test_a_calibration_takes_its_pattern_from_the_form(
    client: TestClient, admin: dict[str, str]
) -> None:
    """Pattern fields are the one option a calibration takes either way: in the form they are
    read, not refused (no board in these images: 422 for that, not for the fields)."""
    r = client.post(
        "/calibrations",
        files=images("files", 3),
        data={"pattern_cols": "7", "pattern_rows": "5", "square_size": "25"},
        headers=admin,
    )
    assert r.status_code == 422, r.text
    assert r.json().get("code") != "unexpected_field"
