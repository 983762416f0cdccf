"""Content-hash cache for stage results.

A stage's key hashes its upstream key (ultimately the input file's bytes), the stage's name and
version, and the options it reads; a re-run with unchanged inputs loads the result instead of
computing it. An entry, ``<folder>/<key[:2]>/<key>.entry``, is `MAGIC`, the SHA-256 of its payload
(32 bytes), then the payload: `cache_codec`'s JSON structure and raw ``.npy`` arrays, which
rebuild only sssbake's own dataclasses and never run code named by the file (a shared or
downloaded cache folder is untrusted input; pickle would run whatever an entry names). Entries are
written atomically, so an interrupted run never leaves a half-written entry; a bit flipped on disk,
a truncated copy or a payload the codec refuses is detected, reported and recomputed instead of
silently feeding a wrong value downstream. The pickles of earlier versions (``<key>.pkl``) are
never read.
"""

from __future__ import annotations

import hashlib
import json
import os
import re
import tempfile
from collections.abc import Iterator
from pathlib import Path

from .cache_codec import CacheFormatError, dumps, loads


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


def stage_key(upstream: str, stage: str, version: int, params: dict) -> str:
    """Key of a stage run: hash of upstream key, stage identity and its JSON-able parameters."""
    text = json.dumps([upstream, stage, version, params], sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()


#: Entry header: format tag, then the payload's SHA-256 (32 bytes), then the `cache_codec` payload.
MAGIC = b"sssbake-cache-2\n"
# `put`'s temporaries, ``<folder>/<key[:2]>/tmp<8 of mkstemp's characters>.tmp`` (`temporaries` finds them).
_TEMPORARY = re.compile(r"tmp[a-z0-9_]{8}\.tmp")
_SHARD = re.compile(r"[0-9a-f]{2}")


def temporaries(folder: str | os.PathLike) -> Iterator[Path]:
    """The temporary files `StageCache.put` writes under `folder` (a killed run leaves them behind).

    Only the exact names ``put`` makes, in the two-hex-digit folders directly under `folder`;
    symlinked folders are not followed.
    """
    root = Path(folder)
    if not root.is_dir():
        return
    for shard in root.iterdir():
        if _SHARD.fullmatch(shard.name) and shard.is_dir() and not shard.is_symlink():
            yield from (p for p in shard.iterdir() if _TEMPORARY.fullmatch(p.name))


class StageCache:
    """Checksummed stage results under `folder` (None: caching off), stored by `cache_codec`.

    Attributes
    ----------
    corrupt : list of str
        Keys of entries found damaged since this cache object was made (each was deleted, so
        the stage recomputes and rewrites it).
    """

    def __init__(self, folder: str | os.PathLike | None):
        self.folder = Path(folder) if folder is not None else None
        self.corrupt: list[str] = []

    def _path(self, key: str) -> Path:
        return self.folder / key[:2] / f"{key}.entry"

    def get(self, key: str):
        """The cached value, or None when absent, damaged (recorded in `corrupt`) or unreadable."""
        if self.folder is None:
            return None
        path = self._path(key)
        try:
            data = path.read_bytes()
        except OSError:
            return None
        head = len(MAGIC) + 32
        payload = memoryview(data)[head:]
        if data[:len(MAGIC)] != MAGIC or hashlib.sha256(payload).digest() != data[len(MAGIC):head]:
            self._discard(key, path)
            return None
        try:
            return loads(payload)
        except CacheFormatError:
            # intact but refused: crafted, or written by another sssbake whose classes changed
            self._discard(key, path)
            return None

    def _discard(self, key: str, path: Path) -> None:
        self.corrupt.append(key)
        path.unlink(missing_ok=True)

    def put(self, key: str, value) -> None:
        """Store `value` under `key` (TypeError, before anything is written, for a value
        `cache_codec.dumps` cannot store)."""
        if self.folder is None:
            return
        payload = dumps(value)
        path = self._path(key)
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=path.parent, prefix="tmp", suffix=".tmp")  # the shape `temporaries` finds
        try:
            digest = hashlib.sha256()
            for piece in payload:
                digest.update(piece)
            with os.fdopen(fd, "wb") as f:
                f.write(MAGIC + digest.digest())
                for piece in payload:
                    f.write(piece)
            os.replace(tmp, path)
        except BaseException:
            Path(tmp).unlink(missing_ok=True)
            raise
