"""SHA-256 digests of the files an asset reads (the stage cache and the dependency checks key on them)."""

from __future__ import annotations

import hashlib
import os


def file_digest(path: str | os.PathLike) -> str:
    """SHA-256 of a file's bytes."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def bytes_digest(data: bytes | memoryview) -> str:
    """SHA-256 of `data`: `file_digest` of a file holding them, without reading it again."""
    return hashlib.sha256(data).hexdigest()
