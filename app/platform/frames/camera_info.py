"""An immutable snapshot of a camera's configuration, as the ingest path needs it."""

from __future__ import annotations

import json
import threading
import time
from collections.abc import Sequence
from dataclasses import dataclass, field

from app.platform.db.models import Camera, CameraKind
from app.platform.frames.stats import Polygon, Roi

Region = list[int] | list[list[int]] | None
"""A region of interest as cameras store it: [x, y, w, h], [[x, y], ...], or None (whole)."""


@dataclass(frozen=True, slots=True)
class CameraInfo:
    id: str
    kind: CameraKind
    panel_id: str | None
    roi: Roi | None
    has_reference: bool = False
    """The camera's view (region) has a reference of its own (a panel's baseline), so the
    features of a fallback model need not be computed (``KindHandler.features``). Possibly
    stale, false only (a reference made through another process since): that costs a little
    work, never a wrong verdict. A view moved through another process is caught by the
    writer's check of ``view``, and the frame measured again."""

    polygon: Polygon | None = None
    """The region as a polygon instead of ``roi``'s rectangle."""

    token_hash: str | None = None
    """The hash of the camera's own token this snapshot was found by (None when it was looked
    up for the admin token): the writer checks it still holds before storing a frame."""

    view: str | None = None
    """What the camera measured with when this snapshot was taken, its kind, panel and region
    as stored (``view_of``): the writer checks it is still so before storing a frame measured by
    it. None: not checked (a snapshot built by hand)."""

    region: Region = field(init=False, compare=False)
    """The region as the camera's ``roi`` stores it: [x, y, w, h], [[x, y], ...] or None. Built
    once per snapshot (the token cache keeps one per camera) rather than once per frame: it is
    both stored with each verdict and compared with a panel baseline's. Read it, never change it."""

    def __post_init__(self) -> None:
        region: Region = None
        if self.polygon is not None:
            region = [[x, y] for x, y in self.polygon]
        elif self.roi is not None:
            region = list(self.roi)
        object.__setattr__(self, "region", region)

    @classmethod
    def of(cls, camera: Camera, *, has_reference: bool = False) -> CameraInfo:
        roi, polygon = parse_region(camera.roi)
        view = view_of(camera.kind, camera.panel_id, camera.roi)
        return cls(camera.id, camera.kind, camera.panel_id, roi, has_reference, polygon, view=view)

    @property
    def credential(self) -> tuple[str, str | None, str | None] | None:
        """What the writer checks again in the batch that stores a frame measured by this
        snapshot: (camera id, token hash, view); None when there is nothing to check."""
        if self.token_hash is None and self.view is None:
            return None
        return (self.id, self.token_hash, self.view)


def view_of(kind: CameraKind | str, panel_id: str | None, roi: Region | str) -> str:
    """A camera's kind, panel and region as one comparable string; ``roi`` as the ORM gives
    it, or as JSON text (the driver's answer on SQLite)."""
    region = json.loads(roi) if isinstance(roi, str) else roi
    name = kind.value if isinstance(kind, CameraKind) else kind
    return json.dumps([name, panel_id, region], separators=(",", ":"))


def parse_region(r: Region) -> tuple[Roi | None, Polygon | None]:
    """A region as stored (JSON): its rectangle, or its polygon, or neither (the whole frame)."""
    if r and isinstance(r[0], list):
        return None, tuple((int(p[0]), int(p[1])) for p in r if isinstance(p, list))
    if r:
        x, y, w, h = (int(v) for v in r if isinstance(v, int))
        return (x, y, w, h), None
    return None, None


def region_now(camera: Camera) -> Region:
    """The region ``camera`` measures now, as verdicts and models record theirs."""
    return CameraInfo.of(camera).region


def describe_region(region: Region) -> str:
    """A region in a few words, for reasons and errors."""
    if region is None:
        return "the whole frame"
    if region and isinstance(region[0], list):
        xs, ys = [p[0] for p in region], [p[1] for p in region]
        box = [min(xs), min(ys), max(xs) - min(xs), max(ys) - min(ys)]
        return f"a {len(region)}-vertex polygon roi within {box}"
    return f"roi {region}"


def one_view(cameras: Sequence[Camera]) -> Camera | None:
    """The first camera when every one measures the same region (their uploads are measured
    there, as their frames are), else None (uploads are measured whole)."""
    if cameras and all(c.roi == cameras[0].roi for c in cameras):
        return cameras[0]
    return None


def uploads_in(camera: Camera | None, kind: CameraKind, panel_id: str | None = None) -> CameraInfo:
    """How uploaded training images are measured: in ``camera``'s region, else whole."""
    if camera is not None:
        return CameraInfo.of(camera)
    return CameraInfo(id="upload", kind=kind, panel_id=panel_id, roi=None)


class TokenCache:
    """Camera token hash → CameraInfo for a few seconds, saving a database round trip per frame.

    Only positive answers are kept, so a new camera is usable at once; a camera's configuration
    reaches every process within ``ttl`` seconds.
    """

    def __init__(self, ttl: float = 10.0, max_entries: int = 100_000) -> None:
        self.ttl = ttl
        self.max_entries = max_entries
        self._items: dict[str, tuple[float, CameraInfo]] = {}
        self._lock = threading.Lock()

    def get(self, digest: str) -> CameraInfo | None:
        item = self._items.get(digest)
        if item is None or item[0] < time.monotonic():
            return None
        return item[1]

    def put(self, digest: str, info: CameraInfo) -> None:
        if self.ttl <= 0:  # keeping nothing: every frame looks its camera up
            return
        with self._lock:
            if len(self._items) >= self.max_entries:
                self._items.clear()
            self._items[digest] = (time.monotonic() + self.ttl, info)

    def forget(self, camera_id: str) -> None:
        """Drop what is kept for this camera (its configuration or token changed)."""
        with self._lock:
            stale = [d for d, (_, info) in self._items.items() if info.id == camera_id]
            for digest in stale:
                del self._items[digest]
