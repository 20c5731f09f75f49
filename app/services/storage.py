"""Where frame bytes live: a directory that several processes may share, or an S3-compatible
object store (AWS S3, MinIO, Ceph …) that several machines share. Both behind one interface.

Frames are content-addressed (``frames/ab/<sha256>.jpg``): identical frames share one object,
and writing the same frame twice is harmless. The database keeps the metadata and the relative
path; nothing else refers to a stored frame.
"""

from __future__ import annotations

import hashlib
import os
import time
from collections.abc import Iterator
from contextlib import contextmanager, suppress
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol

from app.errors import ServiceUnavailable

if TYPE_CHECKING:
    from app.settings import Settings


class StoreUnavailable(ServiceUnavailable):
    """The frame store cannot be reached or written: 503, try again shortly."""

    def __init__(self, detail: str) -> None:
        super().__init__(detail, headers={"Retry-After": "5"}, code="store_unavailable")


def digest(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def relative_path(sha256: str) -> str:
    return f"frames/{sha256[:2]}/{sha256}.jpg"


class FrameStore(Protocol):
    """Frame bytes by their relative path (``relative_path``)."""

    def put(self, data: bytes, sha256: str) -> str:
        """Store the bytes whole (a reader never sees part of them); return the relative path."""
        ...

    def read(self, relative: str) -> bytes | None:
        """The stored bytes, or None when they are not (or no longer) kept."""
        ...

    def delete(self, relatives: list[str]) -> None:
        """Remove these frames' bytes; those already gone are skipped."""
        ...

    def older_than(self, seconds: float) -> list[str]:
        """Every stored frame written at least ``seconds`` ago, as relative paths."""
        ...

    def check(self) -> None:
        """Raise StoreUnavailable unless the store answers."""
        ...


class DiskFrameStore:
    """JPEG bytes kept under ``root/frames/ab/<sha256>.jpg``.

    One level of 256 directories: a second level would mean a new directory for most of the
    first 65,536 frames, which costs more than writing the frame.
    """

    def __init__(self, root: Path, *, fsync: bool = False) -> None:
        self.root = root
        self.fsync = fsync

    def path(self, relative: str) -> Path:
        return self.root / relative

    def put(self, data: bytes, sha256: str) -> str:
        """Write the bytes atomically (temp file, rename).

        The rename makes a file appear whole or not at all, which is what a process crash needs;
        ``fsync`` (off by default: it costs more than decoding the frame) adds power-loss safety.
        A frame already stored is written again, which is harmless (the same bytes replace
        them) and rare (a retried upload), where looking first would cost every frame a lookup.
        """
        relative = relative_path(sha256)
        subdirectory, _, name = relative.rpartition("/")
        directory = f"{self.root}/{subdirectory}"
        try:
            try:
                self._write(directory, name, data)
            except FileNotFoundError:  # its directory is new, or went (emptied by hand)
                os.makedirs(directory, exist_ok=True)
                self._write(directory, name, data)
        except OSError as exc:  # full, read-only, gone: the client should retry later
            raise StoreUnavailable(f"{self.root}: storing the frame failed: {exc}") from exc
        return relative

    def _write(self, directory: str, name: str, data: bytes) -> None:
        # os-level calls, not open(): a buffered file object costs three more system calls
        # (fstat, ioctl, lseek) and, with pathlib, as much CPU again as the write itself
        tmp = f"{directory}/.{name}.{os.urandom(6).hex()}.tmp"
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_CLOEXEC, 0o644)
        try:
            try:
                view = memoryview(data)
                while view:
                    view = view[os.write(fd, view) :]
                if self.fsync:
                    os.fsync(fd)
            finally:
                os.close(fd)
            os.replace(tmp, f"{directory}/{name}")
        except BaseException:
            with suppress(OSError):
                os.unlink(tmp)
            raise

    def read(self, relative: str) -> bytes | None:
        try:
            return self.path(relative).read_bytes()
        except FileNotFoundError:
            return None
        except OSError as exc:  # unreadable: a failing disk, a lost mount
            raise StoreUnavailable(f"{self.root}: reading the frame failed: {exc}") from exc

    def delete(self, relatives: list[str]) -> None:
        for relative in relatives:
            self.path(relative).unlink(missing_ok=True)

    def files(self) -> list[str]:
        """Every stored frame, as relative paths."""
        base = self.root / "frames"
        if not base.exists():
            return []
        return sorted(str(p.relative_to(self.root)) for p in base.glob("*/*.jpg"))

    def older_than(self, seconds: float) -> list[str]:
        now = time.time()
        old = []
        for relative in self.files():
            try:
                if now - self.path(relative).stat().st_mtime >= seconds:
                    old.append(relative)
            except FileNotFoundError:  # deleted meanwhile by another process
                continue
        return old

    def check(self) -> None:
        if not (self.root.is_dir() and os.access(self.root, os.W_OK)):
            raise StoreUnavailable(f"{self.root} is missing or not writable")


class S3FrameStore:
    """Frames as objects ``<prefix>frames/ab/<sha256>.jpg`` in one bucket of an S3-compatible
    store. An S3 PUT is atomic (the object appears whole or not at all), so no temporary object
    is needed. Credentials come from boto3's usual chain (``AWS_ACCESS_KEY_ID`` …, a profile,
    an instance role)."""

    def __init__(
        self,
        bucket: str,
        *,
        prefix: str = "",
        endpoint_url: str | None = None,
        region: str | None = None,
        client: Any = None,
    ) -> None:
        self.bucket = bucket
        self.prefix = prefix
        if client is None:
            import boto3  # only deployments that use S3 need it (the `s3` extra)
            from botocore.config import Config

            client = boto3.client(
                "s3",
                endpoint_url=endpoint_url,
                region_name=region,
                # one client serves every worker thread (boto3 clients are thread-safe)
                config=Config(max_pool_connections=50, retries={"mode": "standard"}),
            )
        self._s3 = client

    def _key(self, relative: str) -> str:
        return self.prefix + relative

    @contextmanager
    def _answering(self, doing: str) -> Iterator[None]:
        """botocore's errors (refused connections, timeouts, access denied …) as one."""
        from botocore.exceptions import BotoCoreError, ClientError

        try:
            yield
        except (BotoCoreError, ClientError) as exc:
            raise StoreUnavailable(f"s3://{self.bucket}: {doing} failed: {exc}") from exc

    def put(self, data: bytes, sha256: str) -> str:
        relative = relative_path(sha256)
        with self._answering("storing the frame"):
            self._s3.put_object(
                Bucket=self.bucket, Key=self._key(relative), Body=data, ContentType="image/jpeg"
            )
        return relative

    def read(self, relative: str) -> bytes | None:
        with self._answering("reading the frame"):
            try:
                response = self._s3.get_object(Bucket=self.bucket, Key=self._key(relative))
            except self._s3.exceptions.NoSuchKey:
                return None
            data: bytes = response["Body"].read()
        return data

    def delete(self, relatives: list[str]) -> None:
        """Up to 1,000 objects a request (S3's DeleteObjects): retention deletes in bulk."""
        for start in range(0, len(relatives), 1000):
            keys = [{"Key": self._key(r)} for r in relatives[start : start + 1000]]
            with self._answering("deleting frames"):
                response = self._s3.delete_objects(
                    Bucket=self.bucket, Delete={"Objects": keys, "Quiet": True}
                )
            if errors := response.get("Errors"):
                first = errors[0]
                raise StoreUnavailable(
                    f"s3://{self.bucket}: {len(errors)} frames not deleted, e.g. "
                    f"{first.get('Key')}: {first.get('Code')} {first.get('Message')}"
                )

    def older_than(self, seconds: float) -> list[str]:
        now = time.time()
        old = []
        with self._answering("listing frames"):
            pages = self._s3.get_paginator("list_objects_v2").paginate(
                Bucket=self.bucket, Prefix=self._key("frames/")
            )
            for page in pages:
                for obj in page.get("Contents", []):
                    if now - obj["LastModified"].timestamp() >= seconds:
                        old.append(obj["Key"][len(self.prefix) :])
        return sorted(old)

    def check(self) -> None:
        with self._answering("reaching the bucket"):
            self._s3.head_bucket(Bucket=self.bucket)


def frame_store(settings: Settings) -> DiskFrameStore | S3FrameStore:
    """The store the settings name."""
    if settings.frame_store == "s3":
        assert settings.s3_bucket is not None  # the settings' validator makes sure
        return S3FrameStore(
            settings.s3_bucket,
            prefix=settings.s3_prefix,
            endpoint_url=settings.s3_endpoint_url,
            region=settings.s3_region,
        )
    return DiskFrameStore(settings.data_dir, fsync=settings.fsync_frames)
