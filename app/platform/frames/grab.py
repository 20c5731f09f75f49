"""One frame from a camera that serves them: an RTSP stream (H.264, MPEG-4), an MJPEG stream over
HTTP, or a snapshot URL answering one JPEG. Streams are decoded by OpenCV's FFmpeg backend
(opencv-python-headless), with FFmpeg's own open and read timeouts: a hung stream is cut, never
waited on. Credentials go to the camera only: errors never carry them."""

from __future__ import annotations

import base64
import os
import urllib.error
import urllib.request
from dataclasses import dataclass
from typing import Literal
from urllib.parse import quote, urlsplit, urlunsplit

# FFmpeg's options for OpenCV, read when a capture opens (the environment may set its own):
# RTSP over TCP (interleaved), as UDP's packets are dropped by NATs and firewalls between a
# city's cameras and the service; no probing beyond the stream's own description (the SDP
# names the codec and its parameters): a grab took 3.0 s of waiting with FFmpeg's default
# probing, 0.35 s without, for the same ~20 ms of CPU.
os.environ.setdefault(
    "OPENCV_FFMPEG_CAPTURE_OPTIONS", "rtsp_transport;tcp|analyzeduration;0|probesize;32768"
)

import cv2  # noqa: E402  (after the FFmpeg options above)

MAX_SNAPSHOT_BYTES = 50 * 2**20
"""A snapshot larger than this is refused (bad_stream)."""
JPEG_QUALITY = 92
"""Quality of the JPEG a decoded stream frame is stored as."""


@dataclass
class GrabError(Exception):
    state: Literal["unreachable", "bad_stream"]
    detail: str

    def __str__(self) -> str:
        return self.detail


def with_credentials(url: str, username: str | None, password: str | None) -> str:
    """``url`` with user:password@ in its authority (for FFmpeg), percent-encoded."""
    if not username:
        return url
    parts = urlsplit(url)
    auth = quote(username, safe="") + (":" + quote(password, safe="") if password else "")
    return urlunsplit(parts._replace(netloc=f"{auth}@{parts.netloc}"))


def grab(url: str, *, username: str | None, password: str | None, timeout: float) -> bytes:
    """One frame of the source as JPEG bytes. Raises GrabError: ``unreachable`` (no answer,
    refused, timed out, an HTTP error) or ``bad_stream`` (an answer that is not a JPEG, an
    MJPEG stream or a decodable video)."""
    if urlsplit(url).scheme in ("http", "https"):
        return _http(url, username, password, timeout)
    return _video(url, with_credentials(url, username, password), timeout)


def _http(url: str, username: str | None, password: str | None, timeout: float) -> bytes:
    headers = {"User-Agent": "vantage"}
    if username:
        pair = f"{username}:{password or ''}".encode()
        headers["Authorization"] = "Basic " + base64.b64encode(pair).decode()
    request = urllib.request.Request(url, headers=headers)
    try:
        response = urllib.request.urlopen(request, timeout=timeout)  # noqa: S310 (http/s only)
    except urllib.error.HTTPError as exc:
        raise GrabError("unreachable", f"HTTP {exc.code} {exc.reason}") from None
    except (urllib.error.URLError, OSError, ValueError) as exc:
        reason = getattr(exc, "reason", exc)
        raise GrabError("unreachable", f"no answer: {reason}") from None
    with response:
        kind = response.headers.get_content_type()
        if kind.startswith("multipart/"):  # MJPEG: FFmpeg reads the stream itself
            pass
        elif kind in ("image/jpeg", "image/jpg"):
            try:
                data: bytes = response.read(MAX_SNAPSHOT_BYTES + 1)
            except OSError as exc:
                raise GrabError("unreachable", f"the snapshot stopped: {exc}") from None
            if len(data) > MAX_SNAPSHOT_BYTES:
                raise GrabError("bad_stream", f"a snapshot over {MAX_SNAPSHOT_BYTES} bytes")
            if not data.startswith(b"\xff\xd8"):
                raise GrabError("bad_stream", "the snapshot is not a JPEG (no FF D8 start)")
            return data
        else:
            raise GrabError(
                "bad_stream",
                f"answered {kind}, not a JPEG snapshot or an MJPEG stream (multipart)",
            )
    return _video(url, with_credentials(url, username, password), timeout)


def _video(url: str, address: str, timeout: float) -> bytes:
    """The first frame FFmpeg decodes from the stream, as JPEG. ``address`` carries the
    credentials; only ``url`` may appear in an error."""
    ms = max(1, int(timeout * 1000))
    capture = cv2.VideoCapture(
        address,
        cv2.CAP_FFMPEG,
        [cv2.CAP_PROP_OPEN_TIMEOUT_MSEC, ms, cv2.CAP_PROP_READ_TIMEOUT_MSEC, ms],
    )
    try:
        if not capture.isOpened():
            raise GrabError("unreachable", f"the stream {url} could not be opened (FFmpeg)")
        ok, frame = capture.read()
    finally:
        capture.release()
    if not ok or frame is None:
        raise GrabError("bad_stream", "the stream gave no frame that FFmpeg could decode")
    ok, buf = cv2.imencode(".jpg", frame, [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])
    if not ok:
        raise GrabError("bad_stream", "the decoded frame could not be encoded as JPEG")
    return bytes(buf.tobytes())
