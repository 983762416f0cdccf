"""Atomic file writes: a file appears under its final name complete, or not at all."""

from __future__ import annotations

import contextlib
import os
import tempfile
from collections.abc import Iterator
from pathlib import Path


@contextlib.contextmanager
def atomic_path(final_path: str | os.PathLike) -> Iterator[Path]:
    """A temporary path next to `final_path` that replaces it when the block succeeds.

    The caller creates the temporary file by any means (its own ``open``, a library's ``save``;
    it does not exist yet, so libraries that refuse to overwrite work too). On a clean exit the
    file is fsynced and renamed over `final_path` with ``os.replace``; on any exception the
    temporary file is removed and `final_path` is left as it was. Leaving the block without
    having created the file raises ``FileNotFoundError``.

    Parameters
    ----------
    final_path : str or PathLike
        Where the file must end up; its folder must exist.

    Yields
    ------
    Path
        The temporary path, in the same folder (so the rename is atomic) and with the same
        suffix (so libraries that pick a format by extension pick the right one).
    """
    final = Path(final_path)
    fd, name = tempfile.mkstemp(prefix=f".{final.name}.", suffix=f".tmp{final.suffix}", dir=final.parent)
    os.close(fd)
    tmp = Path(name)
    # mkstemp only reserves a unique name; the caller's writer creates the file with the
    # permissions a plain open() gives (mkstemp's are 0600).
    tmp.unlink()
    try:
        yield tmp
        if not tmp.is_file():
            raise FileNotFoundError(f"nothing was written to {tmp} for {final}")
        with open(tmp, "rb+") as f:
            os.fsync(f.fileno())
        os.replace(tmp, final)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    _fsync_dir(final.parent)


def _fsync_dir(folder: Path) -> None:
    # The rename is durable only once the folder entry is flushed; not possible on every OS.
    try:
        fd = os.open(folder, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)
