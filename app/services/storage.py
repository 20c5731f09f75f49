"""Content-addressed frame store on local disk (a directory that several processes may share)."""

from __future__ import annotations

import hashlib
import os
import uuid
from pathlib import Path


class FrameStore:
    """JPEG bytes kept under ``root/ab/cd/<sha256>.jpg``; identical frames share one file."""

    def __init__(self, root: Path, *, fsync: bool = False) -> None:
        self.root = root
        self.fsync = fsync

    @staticmethod
    def digest(data: bytes) -> str:
        return hashlib.sha256(data).hexdigest()

    @staticmethod
    def relative_path(sha256: str) -> str:
        return f"frames/{sha256[:2]}/{sha256[2:4]}/{sha256}.jpg"

    def path(self, relative: str) -> Path:
        return self.root / relative

    def put(self, data: bytes, sha256: str) -> tuple[str, bool]:
        """Write the bytes atomically (temp file, rename); return (path, created).

        The rename makes a file appear whole or not at all, which is what a process crash needs;
        ``fsync`` (off by default: it costs more than decoding the frame) adds power-loss safety.
        """
        relative = self.relative_path(sha256)
        target = self.path(relative)
        if target.exists():
            return relative, False
        target.parent.mkdir(parents=True, exist_ok=True)
        tmp = target.with_name(f".{target.name}.{uuid.uuid4().hex}.tmp")
        with open(tmp, "wb") as f:
            f.write(data)
            if self.fsync:
                f.flush()
                os.fsync(f.fileno())
        os.replace(tmp, target)
        return relative, True

    def delete(self, relative: str) -> None:
        self.path(relative).unlink(missing_ok=True)

    def files(self) -> list[str]:
        """Every stored frame, as relative paths."""
        base = self.root / "frames"
        if not base.exists():
            return []
        return sorted(str(p.relative_to(self.root)) for p in base.glob("*/*/*.jpg"))
