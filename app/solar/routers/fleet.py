"""The fleet model: judges panels that have no baseline of their own."""

from __future__ import annotations

from functools import partial
from typing import Annotated

import numpy as np
from fastapi import APIRouter, Query, Request, Response
from sqlalchemy.orm import Session

from app.platform.db.models import CameraKind
from app.platform.frames import ingest
from app.platform.frames.camera_info import CameraInfo
from app.platform.http.deps import (
    Admin,
    Limit,
    Offset,
    PolicyDep,
    Reader,
    RecordId,
    SessionDep,
    SettingsDep,
    image_work,
)
from app.platform.http.errors import NotFound, Unprocessable, UnsupportedMediaType
from app.platform.http.responses import (
    AUTH_ERRORS,
    BODY_ERRORS,
    NOT_FOUND,
    UNPROCESSABLE,
    multipart_body,
)
from app.platform.http.uploads import content_type, read_form
from app.platform.policy import Policy
from app.solar import labels, panels, training
from app.solar.schemas import DoubtOut, FleetModelOut, LabelCounts, LabelIn, LabelOut

router = APIRouter(prefix="/fleet", tags=["panels"])

LABELS = (*training.FLEET_LABELS, "dirty")


def _train(
    session: Session,
    files: list[tuple[str | None, bytes]],
    labels: list[str],
    groups: list[str] | None,
    max_pixels: int,
    policy: Policy,
) -> FleetModelOut:
    camera = CameraInfo(id="upload", kind=CameraKind.panel, panel_id=None, roi=None)
    decoded = ingest.decode_all(files, camera, max_pixels=max_pixels)
    features = np.array([d.features for d in decoded], dtype=np.float64)
    row = training.fit_fleet(features, labels, now=policy.now(), groups=groups)
    session.add(row)
    session.flush()
    return FleetModelOut.model_validate(row)


@router.post(
    "/model",
    status_code=201,
    response_model=FleetModelOut,
    responses={**AUTH_ERRORS, **BODY_ERRORS, **UNPROCESSABLE},
    openapi_extra=multipart_body(files="files", labels="texts", groups="texts"),
)
async def train(
    request: Request, session: SessionDep, settings: SettingsDep, policy: PolicyDep, _: Admin
) -> FleetModelOut:
    """Train the fleet model from labelled photos of many panels: ≥ 5 clean and ≥ 5 needing
    cleaning (dust or bird_drop); snow photos teach it snow (a snow-covered panel is reported
    as such and opens no brushing task), bird_drop photos droppings from dust (≥ 3 each).

    Multipart: repeated ``files`` and, in the same order, ``labels`` (clean, dust, bird_drop,
    snow; dirty is read as dust), and optionally ``groups``: each photo's panel (or any name
    shared by near-duplicate photos). With groups, the choice of C and γ, the reported
    accuracy and the probabilities come from folds that keep a panel's photos together, so
    they speak of panels the model never saw; at least 5 groups of clean photos and 5 of
    photos needing cleaning.
    """
    if content_type(request) != "multipart/form-data":
        raise UnsupportedMediaType("send multipart/form-data with files and labels")
    form = await read_form(
        request, settings.max_upload_bytes, max_files=5000, parts=("files", "labels", "groups")
    )
    files, labels = form.files_of("files"), form.fields.get("labels", [])
    if len(files) != len(labels):
        raise Unprocessable(f"{len(files)} files but {len(labels)} labels; give one label each")
    groups = form.groups_of(len(files))
    bad = sorted({label for label in labels if label not in LABELS})
    if bad:
        raise Unprocessable(
            f"labels must be {', '.join(LABELS)}; got {', '.join(bad)}", code="unknown_label"
        )
    return await image_work(
        request, partial(_train, session, files, labels, groups, settings.max_pixels, policy)
    )


@router.get("/model", response_model=FleetModelOut, responses={**AUTH_ERRORS, **NOT_FOUND})
def current(session: SessionDep, _: Reader) -> FleetModelOut:
    """The fleet model in use (the latest trained)."""
    row = panels.latest_fleet_model(session)
    if row is None:
        raise NotFound("no fleet model has been trained")
    return FleetModelOut.model_validate(row)


@router.get("/doubts", response_model=list[DoubtOut], responses=AUTH_ERRORS)
def doubts(
    session: SessionDep,
    _: Reader,
    unlabelled: Annotated[
        bool, Query(description="Only frames the farm has not labelled yet (the default).")
    ] = True,
    limit: Limit = 50,
    offset: Offset = 0,
) -> list[DoubtOut]:
    """The frames the fleet model doubted, newest first, for an operator to label: each with
    its image (the frame's region) and the model's reason."""
    rows = labels.doubted(session, unlabelled=unlabelled, limit=limit, offset=offset)
    return [
        DoubtOut(
            frame_id=d.frame_id,
            camera_id=d.camera_id,
            panel_id=d.panel_id,
            captured_at=d.captured_at,
            p_dirty=d.p_dirty,
            reason=d.reason,
            label=d.label,
            image=f"/frames/{d.frame_id}/region.jpg",
        )
        for d in rows
    ]


@router.put(
    "/labels/{frame_id}", response_model=LabelOut, responses={**AUTH_ERRORS, **UNPROCESSABLE}
)
def put_label(
    frame_id: RecordId, body: LabelIn, session: SessionDep, policy: PolicyDep, _: Admin
) -> LabelOut:
    """What a panel frame truly shows (clean, dust, bird_drop, snow), as the operator says;
    replaces any label it had. The frame is kept past retention, to learn from."""
    row = labels.set_label(session, frame_id, body.label, source="operator", now=policy.now())
    return LabelOut.model_validate(row)


@router.delete("/labels/{frame_id}", status_code=204, responses={**AUTH_ERRORS, **NOT_FOUND})
def delete_label(frame_id: RecordId, session: SessionDep, _: Admin) -> Response:
    """Take a frame's label back."""
    labels.remove_label(session, frame_id)
    return Response(status_code=204)


@router.get("/labels", response_model=LabelCounts, responses=AUTH_ERRORS)
def label_counts(session: SessionDep, _: Reader) -> LabelCounts:
    """How many frames the farm has labelled, by label."""
    counts = labels.counts(session)
    return LabelCounts(counts=counts, total=sum(counts.values()))
