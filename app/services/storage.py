"""Content-addressed frame store on local disk (a directory that several processes may share)."""

from __future__ import annotations

import hashlib
import os
import uuid
from pathlib import Path


class FrameStore:
    """JPEG bytes kept under ``root/frames/ab/<sha256>.jpg``; identical frames share one file.

    One level of 256 directories: a second level would mean a new directory for most of the
    first 65,536 frames, which costs more than writing the frame.
    """

    def __init__(self, root: Path, *, fsync: bool = False) -> None:
        self.root = root
        self.fsync = fsync
        self._made: set[Path] = set()  # directories known to exist

    @staticmethod
    def digest(data: bytes) -> str:
        return hashlib.sha256(data).hexdigest()

    @staticmethod
    def relative_path(sha256: str) -> str:
        return f"frames/{sha256[:2]}/{sha256}.jpg"

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
        if target.parent not in self._made:
            target.parent.mkdir(parents=True, exist_ok=True)
            self._made.add(target.parent)
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
        return sorted(str(p.relative_to(self.root)) for p in base.glob("*/*.jpg"))
