"""Content-hash cache for stage results.

A stage's key hashes its upstream key (ultimately the input file's bytes), the stage's name and
version, and the options it reads; a re-run with unchanged inputs loads the result instead of
computing it. An entry, ``<folder>/<key[:2]>/<key>.entry``, is `MAGIC`, the SHA-256 of its payload
(32 bytes), then the payload: `cache_codec`'s JSON structure and raw ``.npy`` arrays, which
rebuild only sssbake's own dataclasses and never run code named by the file (a shared or
downloaded cache folder is untrusted input; pickle would run whatever an entry names). Entries are
written atomically, so an interrupted run never leaves a half-written entry; a bit flipped on disk,
a truncated copy, a payload the codec refuses or a value its stage could not have made (the stage's
invariants, `invariants`: anyone who may write a shared folder can rewrite an entry with a valid
checksum) is detected, reported and recomputed instead of silently feeding a wrong value downstream.
The pickles of earlier versions (``<key>.pkl``) are never read.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import re
import tempfile
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np

from sssbake.pipeline.bake.cache_codec import CacheFormatError, dumps, loads


def stage_key(upstream: str, stage: str, version: int, params) -> str:
    """Key of a stage run: hash of upstream key, stage identity and its parameters.

    `params` is the stage's typed options (a dataclass, nested ones and numpy arrays allowed), a
    JSON-able dict or None; a dataclass is keyed with its type's name and every field, floats
    exactly (`canonical`), so a stage's key follows its options without a hand-made list.
    """
    text = json.dumps([upstream, stage, version, canonical(params)], sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()


def canonical(value):
    """`value` as JSON data: a dataclass as ``{"__type__": qualified name, field: ...}``, arrays and
    tuples as lists, numpy scalars as numbers (Python's float repr round-trips exactly); TypeError
    for anything else that JSON cannot hold."""
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return {"__type__": type(value).__qualname__,
                **{f.name: canonical(getattr(value, f.name)) for f in dataclasses.fields(value)}}
    if isinstance(value, dict):
        return {str(k): canonical(v) for k, v in value.items()}
    if isinstance(value, (list, tuple, np.ndarray)):
        return [canonical(v) for v in value]
    if isinstance(value, np.generic):
        return value.item()
    if value is None or isinstance(value, (bool, int, float, str)):
        return value
    raise TypeError(f"a stage key cannot hold a {type(value).__name__}")


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
    """Checksummed stage results under `folder` (None: caching off), stored by `cache_codec`."""

    def __init__(self, folder: str | os.PathLike | None):
        self.folder = Path(folder) if folder is not None else None

    def path(self, key: str) -> Path:
        """The file of `key`'s entry."""
        return self.folder / key[:2] / f"{key}.entry"

    def get(self, key: str):
        """The cached value, or None when absent, unreadable or damaged (`lookup`)."""
        return self.lookup(key)[0]

    def lookup(self, key: str, check: Callable[[object], None] | None = None) -> tuple[object, str | None]:
        """``(value, None)`` for a sound entry, ``(None, None)`` when there is none (or caching is off,
        or it cannot be read), ``(None, what is wrong)`` for a damaged one, which is deleted.

        Damaged: its checksum fails, the codec refuses its payload, or `check(value)` raises (the
        value breaks its stage's invariants: `invariants.check_cached`). Whatever `check` raises
        counts: a crafted value can make a check trip anywhere.
        """
        if self.folder is None:
            return None, None
        path = self.path(key)
        try:
            with open(path, "rb") as f:
                # read into a writable buffer: the decoded arrays are views of it, not copies
                data = bytearray(os.fstat(f.fileno()).st_size)
                if f.readinto(data) != len(data):
                    data = data[:0]  # changed while read: damaged below
        except OSError:
            return None, None
        head = len(MAGIC) + 32
        payload = memoryview(data)[head:]
        if data[:len(MAGIC)] != MAGIC or hashlib.sha256(payload).digest() != data[len(MAGIC):head]:
            return None, self._discard(path, "fails its checksum")
        try:
            value = loads(payload)
        except CacheFormatError as e:
            # intact but refused: crafted, or written by another sssbake whose classes changed
            return None, self._discard(path, f"holds what sssbake does not write ({str(e).splitlines()[0]})")
        if check is not None:
            try:
                check(value)
            except Exception as e:  # whatever a crafted value makes the check raise refuses it
                first = str(e).splitlines()[0] if str(e) else ""  # one line for the warning it makes
                return None, self._discard(path, f"breaks its stage's invariants ({type(e).__name__}: {first})")
        return value, None

    @staticmethod
    def _discard(path: Path, problem: str) -> str:
        try:
            path.unlink(missing_ok=True)
        except OSError:  # a folder we may not write: it stays, and each bake recomputes it
            pass
        return problem

    def put(self, key: str, value) -> None:
        """Store `value` under `key` (TypeError, before anything is written, for a value
        `cache_codec.dumps` cannot store; OSError when the folder cannot take it, nothing left)."""
        if self.folder is None:
            return
        payload = dumps(value)
        path = self.path(key)
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
