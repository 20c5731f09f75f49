"""The fleet model: judges panels that have no baseline of their own."""

from __future__ import annotations

from functools import partial
from typing import Annotated

import numpy as np
from fastapi import APIRouter, Query, Request, Response
from fastapi.concurrency import run_in_threadpool
from pydantic import Field
from sqlalchemy.orm import Session

from app.platform.db.models import CameraKind
from app.platform.frames import ingest
from app.platform.frames.camera_info import CameraInfo
from app.platform.http.deps import (
    Admin,
    Limit,
    Offset,
    Reader,
    RecordId,
    SessionDep,
    SettingsDep,
    TimingDep,
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
from app.platform.http.uploads import content_type, read_form, read_json
from app.platform.schemas import Schema
from app.platform.state import app_state
from app.platform.timing import Timing
from app.solar.schemas import DoubtOut, FleetModelOut, LabelCounts, LabelIn, LabelOut
from app.solar.services import fleet_training, panels
from app.solar.services import labels as labels_service

router = APIRouter(prefix="/fleet", tags=["panels"])

LABELS = (*fleet_training.FLEET_LABELS, "dirty")


def _train(
    session: Session,
    files: list[tuple[str | None, bytes]],
    labels: list[str],
    groups: list[str] | None,
    stored: list[tuple[labels_service.Stored, bytes]],
    max_pixels: int,
    timing: Timing,
) -> FleetModelOut:
    """The model from the uploaded photos and the farm's labelled stored frames (each measured
    in its camera's region, grouped by its panel). Mixed with stored frames, uploaded photos
    without groups are each a group of their own."""
    camera = CameraInfo(id="upload", kind=CameraKind.panel, panel_id=None, roi=None)
    decoded = ingest.decode_all(files, camera, max_pixels=max_pixels)
    rows = [d.features for d in decoded]
    for s, data in stored:
        rows.append(ingest.analyse(data, camera=s.camera, max_pixels=max_pixels).features)
    features = np.array(rows, dtype=np.float64)
    labels = [*labels, *(s.label for s, _ in stored)]
    if stored:
        named = groups or [f"upload-{i}" for i in range(len(files))]
        groups = [*named, *(s.group for s, _ in stored)]
    farm = [False] * len(files) + [True] * len(stored)
    row = fleet_training.fit_fleet(features, labels, now=timing.now(), groups=groups, farm=farm)
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
    request: Request, session: SessionDep, settings: SettingsDep, timing: TimingDep, _: Admin
) -> FleetModelOut:
    """Train the fleet model from labelled photos of many panels: ≥ 5 clean and ≥ 5 needing
    cleaning (dust or bird_drop); snow photos teach it snow (a snow-covered panel is reported
    as such and opens no brushing task), bird_drop photos droppings from dust (≥ 3 each).
    The farm's labelled frames join them: repeated ``frame_ids`` in the form, or JSON
    ``{"frame_ids": [...]}`` alone (``PUT /fleet/labels/{frame_id}`` labels them).

    Multipart: repeated ``files`` and, in the same order, ``labels`` (clean, dust, bird_drop,
    snow; dirty is read as dust), and optionally ``groups``: each photo's panel (or any name
    shared by near-duplicate photos). With groups, the choice of C and γ, the reported
    accuracy and the probabilities come from folds that keep a panel's photos together, so
    they speak of panels the model never saw; at least 5 groups of clean photos and 5 of
    photos needing cleaning.
    """
    kind = content_type(request)
    groups: list[str] | None = None
    if kind == "application/json":
        body = await read_json(request, FromFrames, settings.max_body_bytes)
        files, labels, frame_ids = [], [], body.frame_ids
    elif kind == "multipart/form-data":
        form = await read_form(
            request,
            settings.max_upload_bytes,
            max_files=5000,
            parts=("files", "labels", "groups", "frame_ids"),
        )
        files, labels = form.files_of("files"), form.fields.get("labels", [])
        frame_ids = form.fields.get("frame_ids", [])
        groups = form.groups_of(len(files))
    else:
        raise UnsupportedMediaType(
            "send multipart/form-data (files and labels, frame_ids) or application/json (frame_ids)"
        )
    if len(files) != len(labels):
        raise Unprocessable(f"{len(files)} files but {len(labels)} labels; give one label each")
    bad = sorted({label for label in labels if label not in LABELS})
    if bad:
        raise Unprocessable(
            f"labels must be {', '.join(LABELS)}; got {', '.join(bad)}", code="unknown_label"
        )
    stored = await _stored(request, session, frame_ids)
    return await image_work(
        request,
        partial(_train, session, files, labels, groups, stored, settings.max_pixels, timing),
    )


class FromFrames(Schema):
    frame_ids: Annotated[
        list[Annotated[str, Field(max_length=36)]], Field(min_length=1, max_length=5000)
    ]


async def _stored(
    request: Request, session: Session, frame_ids: list[str]
) -> list[tuple[labels_service.Stored, bytes]]:
    """The labelled stored frames and their bytes, read from the frame store."""
    if not frame_ids:
        return []
    if len(set(frame_ids)) != len(frame_ids):
        raise Unprocessable("frame_ids names a frame twice", code="duplicate_frames")
    found = await run_in_threadpool(labels_service.stored_to_learn, session, frame_ids)
    out = []
    for s in found:
        data = await app_state(request).bounded_store.read(s.stored_path)
        if data is None:
            raise Unprocessable(f"the image of frame {s.frame_id!r} is no longer kept")
        out.append((s, data))
    return out


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
    rows = labels_service.doubted(session, unlabelled=unlabelled, limit=limit, offset=offset)
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
    frame_id: RecordId, body: LabelIn, session: SessionDep, timing: TimingDep, _: Admin
) -> LabelOut:
    """What a panel frame truly shows (clean, dust, bird_drop, snow), as the operator says;
    replaces any label it had. The frame is kept past retention, to learn from."""
    row = labels_service.set_label(
        session, frame_id, body.label, source="operator", now=timing.now()
    )
    return LabelOut.model_validate(row)


@router.delete("/labels/{frame_id}", status_code=204, responses={**AUTH_ERRORS, **NOT_FOUND})
def delete_label(frame_id: RecordId, session: SessionDep, _: Admin) -> Response:
    """Take a frame's label back."""
    labels_service.remove_label(session, frame_id)
    return Response(status_code=204)


@router.get("/labels", response_model=LabelCounts, responses=AUTH_ERRORS)
def label_counts(session: SessionDep, _: Reader) -> LabelCounts:
    """How many frames the farm has labelled, by label."""
    counts = labels_service.counts(session)
    return LabelCounts(counts=counts, total=sum(counts.values()))
