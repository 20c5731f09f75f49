"""One frame from a camera that serves them: an RTSP stream (H.264, MPEG-4), an MJPEG stream over
HTTP, or a snapshot URL answering one JPEG. Streams are decoded by OpenCV's FFmpeg backend
(opencv-python-headless), with FFmpeg's own open and read timeouts: a hung stream is cut, never
waited on. Credentials go to the camera only: errors never carry them, nor what the other side
said (an error says what failed).

Every connection goes to an address the source rule allows (``addresses``): the host is
resolved and checked before each pull; an HTTP connection checks the address it reached
(a name that resolves anew between the check and the connection is caught there), and an
RTSP URL is given to FFmpeg with the checked address in place of the name. No redirect is
followed: a camera's snapshot answers where it is, and a redirect would take its credentials
to another host or scheme. No proxy from the environment is used."""

from __future__ import annotations

import base64
import http.client
import ipaddress
import os
import socket
import ssl
import urllib.error
import urllib.request
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Literal
from urllib.parse import quote, urlsplit, urlunsplit

from app.platform.frames.addresses import AddressRefused, IPNetwork, check, resolve_url

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


QUERY_SECRETS = frozenset(
    {
        "password",
        "pass",
        "passwd",
        "pwd",
        "token",
        "key",
        "apikey",
        "api_key",
        "secret",
        "auth",
        "sig",
        "signature",
        "access_token",
        "credentials",
    }
)
"""Query parameters that carry credentials: their values are never shown or logged."""


def masked(url: str) -> str:
    """``url`` with the values of its credential-like query parameters replaced by ``***``
    (what an answer or a log may show of a source's URL)."""
    parts = urlsplit(url)
    if not parts.query:
        return url
    pairs = []
    for pair in parts.query.split("&"):
        name, sep, _value = pair.partition("=")
        hidden = sep and name.lower() in QUERY_SECRETS
        pairs.append(f"{name}=***" if hidden else pair)
    return urlunsplit(parts._replace(query="&".join(pairs)))


def grab(
    url: str,
    *,
    username: str | None,
    password: str | None,
    timeout: float,
    allowed: Sequence[IPNetwork] = (),
) -> bytes:
    """One frame of the source as JPEG bytes. Raises GrabError: ``unreachable`` (an address
    the rule refuses, no answer, refused, timed out, an HTTP error or a redirect) or
    ``bad_stream`` (an answer that is not a JPEG, an MJPEG stream or a decodable video)."""
    try:
        found = resolve_url(url, allowed)
    except AddressRefused as exc:
        raise GrabError("unreachable", str(exc)) from None
    if urlsplit(url).scheme.lower() in ("http", "https"):
        return _http(url, username, password, timeout, allowed)
    pinned = _with_address(url, found[0])  # FFmpeg connects to the address checked
    return _video(url, with_credentials(pinned, username, password), timeout)


def _with_address(url: str, address: ipaddress.IPv4Address | ipaddress.IPv6Address) -> str:
    parts = urlsplit(url)
    host = f"[{address}]" if address.version == 6 else str(address)
    netloc = host + (f":{parts.port}" if parts.port is not None else "")
    return urlunsplit(parts._replace(netloc=netloc))


def _checked_peer(sock: socket.socket, allowed: Sequence[IPNetwork]) -> None:
    """Refuse a connection that reached an address the rule refuses (closing it)."""
    address = ipaddress.ip_address(str(sock.getpeername()[0]).split("%")[0])
    try:
        check(address, allowed)
    except AddressRefused:
        sock.close()
        raise


class _CheckedHTTP(http.client.HTTPConnection):
    allowed: Sequence[IPNetwork] = ()

    def connect(self) -> None:
        super().connect()
        _checked_peer(self.sock, self.allowed)


class _CheckedHTTPS(http.client.HTTPSConnection):
    allowed: Sequence[IPNetwork] = ()

    def connect(self) -> None:
        super().connect()
        _checked_peer(self.sock, self.allowed)


class _Handler(urllib.request.HTTPHandler, urllib.request.HTTPSHandler):
    """Opens http and https through the connections above."""

    def __init__(self, allowed: Sequence[IPNetwork]) -> None:
        urllib.request.HTTPHandler.__init__(self)
        urllib.request.HTTPSHandler.__init__(self)
        self.allowed = allowed

    def _connection(self, kind: type[http.client.HTTPConnection]) -> Any:
        def make(host: str, **kwargs: Any) -> http.client.HTTPConnection:
            connection = kind(host, **kwargs)
            connection.allowed = self.allowed  # type: ignore[attr-defined]
            return connection

        return make

    def http_open(self, req: urllib.request.Request) -> Any:
        return self.do_open(self._connection(_CheckedHTTP), req)

    def https_open(self, req: urllib.request.Request) -> Any:
        return self.do_open(self._connection(_CheckedHTTPS), req)


class _NoRedirect(urllib.request.HTTPRedirectHandler):
    def redirect_request(self, *args: Any, **kwargs: Any) -> None:
        return None  # urllib then raises the 3xx as an HTTPError


def _opener(allowed: Sequence[IPNetwork]) -> urllib.request.OpenerDirector:
    return urllib.request.build_opener(
        urllib.request.ProxyHandler({}), _NoRedirect(), _Handler(allowed)
    )


def _failure(exc: BaseException) -> str:
    """What failed, in the service's words, for an error of the connection."""
    reason = getattr(exc, "reason", exc)
    if isinstance(reason, AddressRefused):
        return str(reason)
    if isinstance(reason, ConnectionRefusedError):
        return "no answer: the connection was refused"
    if isinstance(reason, TimeoutError | socket.timeout):
        return "no answer: timed out"
    if isinstance(reason, socket.gaierror):
        return "no answer: the host name does not resolve"
    if isinstance(reason, ssl.SSLError):
        return "no answer: the TLS handshake failed"
    return "no answer: the connection failed"


def _http(
    url: str,
    username: str | None,
    password: str | None,
    timeout: float,
    allowed: Sequence[IPNetwork],
) -> bytes:
    headers = {"User-Agent": "vantage"}
    if username:
        pair = f"{username}:{password or ''}".encode()
        headers["Authorization"] = "Basic " + base64.b64encode(pair).decode()
    request = urllib.request.Request(url, headers=headers)
    try:
        response = _opener(allowed).open(request, timeout=timeout)
    except urllib.error.HTTPError as exc:
        exc.close()
        if 300 <= exc.code < 400:
            detail = "redirected elsewhere; redirects are not followed: give the final URL"
        elif exc.code in (401, 403):
            detail = f"HTTP {exc.code}: the camera refused the credentials"
        else:
            detail = f"HTTP {exc.code}: the camera answered with an error"
        raise GrabError("unreachable", detail) from None
    except AddressRefused as exc:
        raise GrabError("unreachable", str(exc)) from None
    except (urllib.error.URLError, OSError, ValueError) as exc:
        raise GrabError("unreachable", _failure(exc)) from None
    with response:
        kind = response.headers.get_content_type()
        if kind.startswith("multipart/"):  # MJPEG: FFmpeg reads the stream itself
            pass
        elif kind in ("image/jpeg", "image/jpg"):
            try:
                data: bytes = response.read(MAX_SNAPSHOT_BYTES + 1)
            except OSError:
                raise GrabError("unreachable", "the snapshot stopped before its end") from None
            if len(data) > MAX_SNAPSHOT_BYTES:
                raise GrabError("bad_stream", f"a snapshot over {MAX_SNAPSHOT_BYTES} bytes")
            if not data.startswith(b"\xff\xd8"):
                raise GrabError("bad_stream", "the snapshot is not a JPEG (no FF D8 start)")
            return data
        else:
            raise GrabError(
                "bad_stream",
                "the answer is not a JPEG snapshot (image/jpeg) or an MJPEG stream (multipart)",
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
            raise GrabError("unreachable", f"the stream {masked(url)} could not be opened (FFmpeg)")
        ok, frame = capture.read()
    finally:
        capture.release()
    if not ok or frame is None:
        raise GrabError("bad_stream", "the stream gave no frame that FFmpeg could decode")
    ok, buf = cv2.imencode(".jpg", frame, [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])
    if not ok:
        raise GrabError("bad_stream", "the decoded frame could not be encoded as JPEG")
    return bytes(buf.tobytes())
