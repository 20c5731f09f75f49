"""The frame store the settings name: the directory (``storage.DiskFrameStore``) or an
S3-compatible bucket (``VANTAGE_FRAME_STORE=s3``), with bounded waits on a bucket that never
answers."""

from __future__ import annotations

import time
from collections.abc import Generator, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from datetime import datetime
from typing import Any

from app.platform.frames.storage import (
    DiskFrameStore,
    FrameStore,
    StoreUnavailable,
    relative_path,
)
from app.platform.settings import Settings


@dataclass(frozen=True)
class S3Timeouts:
    """How long a request to the bucket may wait to connect and for each answer [s], and how
    many times it is tried. botocore's defaults (60 s, 60 s, 3 tries) made a store that
    accepted connections and never answered cost 3 minutes a frame, each holding an ingest
    thread long after its upload had got its 503, and 3 minutes a /health; at most
    2 × (3 + 10) s = 26 s now, within the upload's 30 s deadline."""

    connect: float = 3.0
    read: float = 10.0
    attempts: int = 2


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
        timeouts: S3Timeouts | None = None,
    ) -> None:
        self.bucket = bucket
        self.prefix = prefix
        if client is None:
            import boto3  # only deployments that use S3 need it (the `s3` extra)
            from botocore.config import Config

            t = timeouts or S3Timeouts()
            client = boto3.client(
                "s3",
                endpoint_url=endpoint_url,
                region_name=region,
                # one client serves every worker thread (boto3 clients are thread-safe)
                config=Config(
                    max_pool_connections=50,
                    connect_timeout=t.connect,
                    read_timeout=t.read,
                    retries={"mode": "standard", "total_max_attempts": t.attempts},
                ),
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

    def put(self, data: bytes, sha256: str, received_at: datetime) -> str:
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

    def expired_packs(self, cutoff: datetime) -> list[str]:
        return []  # an object per frame: retention deletes each

    def delete_packs(self, packs: list[str]) -> None:
        assert not packs, "an S3 store has no packs"

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

    def idle_packs(self, seconds: float) -> list[str]:
        return []  # an object per frame: ``older_than`` finds the orphans

    def pack_locators(self, pack: str) -> Generator[str, None, None]:
        yield from ()

    def check(self) -> None:
        with self._answering("reaching the bucket"):
            self._s3.head_bucket(Bucket=self.bucket)

    def close(self) -> None:
        pass  # nothing held open


def frame_store(settings: Settings) -> FrameStore:
    """The store the settings name."""
    if settings.frame_store == "s3":
        assert settings.s3_bucket is not None  # the settings' validator makes sure
        return S3FrameStore(
            settings.s3_bucket,
            prefix=settings.s3_prefix,
            endpoint_url=settings.s3_endpoint_url,
            region=settings.s3_region,
        )
    return DiskFrameStore(
        settings.data_dir,
        fsync=settings.fsync_frames,
        keep_free_bytes=round(settings.keep_free_disk_mb * 2**20),
        largest_frame_bytes=settings.max_body_bytes,
    )
