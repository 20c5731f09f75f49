"""The farm teaches the fleet model: the frames it doubted, listed for an operator, and the
labels the farm gives frames (``FrameLabel``)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from datetime import datetime

from sqlalchemy import func, select
from sqlalchemy.orm import Session

from app.platform.db.models import Camera, CameraKind, Frame
from app.platform.frames.camera_info import CameraInfo, parse_region
from app.platform.http.errors import NotFound, Unprocessable
from app.solar.models import FrameLabel, PanelVerdict

LABELS = ("clean", "dust", "bird_drop", "snow")
"""What the farm may say a panel frame shows (the fleet model's labels)."""


@dataclass(frozen=True, slots=True)
class Doubted:
    """A frame the fleet model would not judge, and the farm's label for it if any."""

    frame_id: str
    camera_id: str
    panel_id: str | None
    captured_at: datetime
    p_dirty: float | None
    reason: str | None
    label: str | None


def doubted(session: Session, *, unlabelled: bool, limit: int, offset: int) -> list[Doubted]:
    """Frames the fleet model doubted (it answered neither clean nor dirty, and saw no snow),
    newest first; with ``unlabelled``, only those the farm has not labelled yet."""
    query = (
        select(Frame, PanelVerdict, FrameLabel.label)
        .join(PanelVerdict, PanelVerdict.frame_id == Frame.id)
        .outerjoin(FrameLabel, FrameLabel.frame_id == Frame.id)
        .where(
            PanelVerdict.method == "fleet",
            PanelVerdict.clean.is_(None),
            PanelVerdict.condition.is_(None),
            Frame.stored_path.is_not(None),
        )
        .order_by(Frame.captured_at.desc(), Frame.id.desc())
        .limit(limit)
        .offset(offset)
    )
    if unlabelled:
        query = query.where(FrameLabel.frame_id.is_(None))
    return [
        Doubted(
            frame.id,
            frame.camera_id,
            verdict.panel_id,
            frame.captured_at,
            verdict.p_dirty,
            verdict.reason,
            label,
        )
        for frame, verdict, label in session.execute(query)
    ]


def set_label(
    session: Session, frame_id: str, label: str, *, source: str, now: datetime
) -> FrameLabel:
    """Label a panel camera's stored frame (replacing any label it had). 422 naming the frame
    when there is no such frame, it is not a panel camera's, or its image is no longer kept
    (nothing to learn from); 422 naming the label outside the set."""
    if label not in LABELS:
        raise Unprocessable(f"label {label!r} is not one of {', '.join(LABELS)}", code="bad_label")
    row = session.execute(
        select(Frame, Camera.kind)
        .join(Camera, Camera.id == Frame.camera_id)
        .where(Frame.id == frame_id)
    ).first()
    if row is None:
        raise Unprocessable(f"there is no frame {frame_id!r} to label", code="unknown_frame")
    frame, kind = row
    if kind != CameraKind.panel:
        raise Unprocessable(
            f"frame {frame_id!r} is a {kind.value} camera's, not a panel's", code="not_a_panel"
        )
    if frame.stored_path is None:
        raise Unprocessable(
            f"frame {frame_id!r} was not kept: there is no image to learn from",
            code="frame_not_kept",
        )
    found = session.get(FrameLabel, frame_id)
    if found is None:
        found = FrameLabel(frame_id=frame_id)
        session.add(found)
    found.label, found.source, found.labelled_at = label, source, now
    session.flush()
    return found


def remove_label(session: Session, frame_id: str) -> None:
    found = session.get(FrameLabel, frame_id)
    if found is None:
        raise NotFound(f"frame {frame_id!r} has no label")
    session.delete(found)


def counts(session: Session) -> dict[str, int]:
    """How many frames the farm has labelled, by label (every label, zeros included)."""
    rows = session.execute(select(FrameLabel.label, func.count()).group_by(FrameLabel.label))
    found = {label: int(n) for label, n in rows}
    return {label: found.get(label, 0) for label in LABELS}


def labelled_frames(session: Session) -> list[str]:
    """Every labelled frame's id: retention keeps their images."""
    return list(session.scalars(select(FrameLabel.frame_id)))


@dataclass(frozen=True, slots=True)
class Stored:
    """A labelled stored frame to learn from: where its image is and how it was measured."""

    frame_id: str
    stored_path: str
    camera: CameraInfo
    label: str
    group: str
    """Its panel (or camera): the folds keep a panel's frames together."""


def stored_to_learn(session: Session, frame_ids: Sequence[str]) -> list[Stored]:
    """The labelled panel frames ``frame_ids``, in that order, each with the region its
    camera measured it in. 422 naming those that are unknown, unlabelled or no longer kept."""
    rows = session.execute(
        select(Frame, PanelVerdict, FrameLabel.label)
        .join(PanelVerdict, PanelVerdict.frame_id == Frame.id)
        .join(FrameLabel, FrameLabel.frame_id == Frame.id)
        .where(Frame.id.in_(frame_ids), Frame.stored_path.is_not(None))
    ).all()
    found = {frame.id: (frame, verdict, label) for frame, verdict, label in rows}
    missing = [f for f in frame_ids if f not in found]
    if missing:
        raise Unprocessable(
            f"frame(s) {', '.join(missing[:10])} are not labelled panel frames whose image is "
            "kept: label them first (PUT /fleet/labels/{frame_id})",
            code="unlabelled_frames",
        )
    out = []
    for frame_id in frame_ids:
        frame, verdict, label = found[frame_id]
        roi, polygon = parse_region(verdict.roi)
        camera = CameraInfo(
            frame.camera_id, CameraKind.panel, verdict.panel_id, roi, False, polygon
        )
        group = verdict.panel_id or frame.camera_id
        out.append(Stored(frame_id, str(frame.stored_path), camera, label, group))
    return out


def learn_from_cleaning(
    session: Session, panel_id: str, completed_at: datetime, after: Frame, now: datetime
) -> None:
    """A robot's cleaning confirmed by ``after`` (the frame that found the panel clean): it is
    labelled clean, and the panel's last frame judged dirty before the cleaning dust. Frames
    without a kept image, and those an operator labelled, are left as they are."""
    before = session.scalar(
        select(Frame)
        .join(PanelVerdict, PanelVerdict.frame_id == Frame.id)
        .where(
            PanelVerdict.panel_id == panel_id,
            PanelVerdict.clean.is_(False),
            Frame.captured_at < completed_at,
        )
        .order_by(Frame.captured_at.desc())
        .limit(1)
    )
    for frame, label in ((before, "dust"), (after, "clean")):
        if frame is None or frame.stored_path is None:
            continue
        found = session.get(FrameLabel, frame.id)
        if found is not None and found.source == "operator":
            continue
        if found is None:
            found = FrameLabel(frame_id=frame.id)
            session.add(found)
        found.label, found.source, found.labelled_at = label, "robot", now
