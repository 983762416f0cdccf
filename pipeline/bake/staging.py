"""A bake's outputs, all or nothing: written into a private folder next to them under their final
names, validated there, then moved into place only once every one of them is written and valid.

A failed bake moves nothing: the asset's output paths keep what they held. The files keep their
final names while staged because they name each other (the .usdc references its thickness
textures by name) and are validated as they will be read. A bake killed outright leaves its
folder, ``.sssbake-staging.<8 random characters>``, behind: its supervisor removes it
(`asset_process`), or else the next batch (`batch.sweep_temporaries`), as they remove
`atomic.atomic_path`'s temporaries.
"""

from __future__ import annotations

import contextlib
import os
import re
import shutil
import tempfile
from collections.abc import Iterable, Iterator
from pathlib import Path

from sssbake.exporters.atomic import temporary_of

PREFIX = ".sssbake-staging."
_STAGING = re.compile(re.escape(PREFIX) + r"[a-z0-9_]{8}")  # mkdtemp's 8 random characters


def is_staging(name: str) -> bool:
    """Whether `name` is a staging folder's (`staging`)."""
    return _STAGING.fullmatch(name) is not None


@contextlib.contextmanager
def staging(folder: Path) -> Iterator[Path]:
    """A new staging folder in `folder`, removed with whatever is still in it when the block ends."""
    path = Path(tempfile.mkdtemp(prefix=PREFIX, dir=folder))
    try:
        yield path
    finally:
        shutil.rmtree(path, ignore_errors=True)


def commit(staged: Path, names: Iterable[str], folder: Path) -> None:
    """Move the files `names` from `staged` into `folder`, in order (the one that marks the set
    complete last); when one cannot be moved, those moved already are removed and the error raised."""
    moved: list[Path] = []
    try:
        for name in names:
            os.replace(staged / name, folder / name)
            moved.append(folder / name)
    except BaseException:
        for path in moved:
            path.unlink(missing_ok=True)
        raise
    # the renames are durable once the folder's entries are flushed (not possible on every OS)
    with contextlib.suppress(OSError):
        fd = os.open(folder, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)


def holds_any(folder: Path, finals: set[str]) -> bool:
    """Whether the staging `folder` holds one of the files `finals`, or a temporary of one: it is the
    bake of the asset they belong to. A folder that holds nothing yet cannot be told from another
    bake's just made."""
    try:
        names = os.listdir(folder)
    except OSError:
        return False
    return any(name in finals or any(temporary_of(name, final) for final in finals) for name in names)
