"""Atomic file writes: a file appears under its final name complete, or not at all."""

from __future__ import annotations

import contextlib
import os
import re
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
    # The name's shape is what `temporary_target` recognises: change both together.
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


# `.<final name>.<8 characters of mkstemp's alphabet>.tmp<rest>`; see `temporary_target`.
_TEMPORARY = re.compile(r"\.(?P<final>.+)\.[a-z0-9_]{8}\.tmp(?P<rest>.*)")
# USD's own safe-save (TfSafeOutputFile) writes `<our temporary minus its suffix>.<6 letters or digits>`
# and renames it to our temporary, so a kill in between leaves that name.
_USD_SAFE_SAVE = re.compile(r"\.[A-Za-z0-9]{6}")


def temporary_target(name: str) -> str | None:
    """The final file name whose `atomic_path` temporary `name` is, or None when it is not one.

    Recognises the temporary files `atomic_path` names (``.<final>.<random>.tmp<suffix>``, the
    random part mkstemp's 8 characters) and the one USD's save writes on its way to such a name
    (``.<final>.<random>.tmp.<6 characters>``); nothing else, so that a sweep of stale temporaries
    (`sssbake.pipeline.bake.batch`) never touches another program's files.

    Parameters
    ----------
    name : str
        A file name, without folder.

    Returns
    -------
    str or None
        The final name (``teapot.glb`` for ``.teapot.glb.k2_9xq0a.tmp.glb``), or None.
    """
    m = _TEMPORARY.fullmatch(name)
    if m is None:
        return None
    final, rest = m["final"], m["rest"]
    if rest == Path(final).suffix or (Path(final).suffix and _USD_SAFE_SAVE.fullmatch(rest)):
        return final
    return None


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
