"""Atomic file writes: a file appears under its final name complete, or not at all."""

from __future__ import annotations

import contextlib
import errno
import hashlib
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
        suffix (so libraries that pick a format by extension pick the right one). Its name is
        ``.<final name>.<random>.tmp<suffix>``, or where that would pass the folder's longest
        name, ``.<start of the final name>~<digest of it>.<random>.tmp<suffix>`` (`temporary_of`).

    Raises
    ------
    OSError
        ENAMETOOLONG at once when the final name itself is longer than the folder allows: the
        outputs are named after their asset, and a name shortened here would break that (the
        user shortens the asset's name instead).
    """
    final = Path(final_path)
    limit = _name_max(final.parent)
    size = len(os.fsencode(final.name))
    if size > limit:
        raise OSError(errno.ENAMETOOLONG, f"File name too long ({size} bytes; this folder allows {limit}): "
                                          "give the asset a shorter name", str(final))
    # The name's shape is what `temporary_target` and `temporary_of` recognise: change them together.
    fd, name = tempfile.mkstemp(prefix=f".{_head(final.name, limit)}.", suffix=f".tmp{final.suffix}",
                                dir=final.parent)
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
_TEMPORARY = re.compile(r"\.(?P<final>.+)\.[a-z0-9_]{8}\.tmp(?P<rest>.*)", re.DOTALL)
# A final name too long for that: `.<its start>~<_DIGEST hex digits of its digest>.<8 characters>.tmp<rest>`.
_DIGEST = 12
_SHORTENED = re.compile(rf"\.(?P<start>.*)~(?P<digest>[0-9a-f]{{{_DIGEST}}})\.[a-z0-9_]{{8}}\.tmp(?P<rest>.*)",
                        re.DOTALL)
# USD's own safe-save (TfSafeOutputFile) writes `<our temporary minus its suffix>.<6 letters or digits>`
# and renames it to our temporary, so a kill in between leaves that name.
_USD_SAFE_SAVE = re.compile(r"\.[A-Za-z0-9]{6}")
# After a shortened temporary's `.tmp`: nothing, a suffix or USD's save name (the final's suffix is unknown).
_ANY_REST = re.compile(r"(\.[^.]+)?")
# mkstemp's random part and the `.tmp`, and what USD's save name may add to ours (`_USD_SAFE_SAVE`
# in place of a suffix shorter than it): the bytes a temporary's name adds to its head and suffix.
_FIXED = len(".." + 8 * "x" + ".tmp")
_USD_EXTRA = len(".Ab3dE9")


def _name_max(folder: Path) -> int:
    """The longest file name `folder` allows, in bytes (255, the common limit, where it cannot say)."""
    try:
        return os.pathconf(folder, "PC_NAME_MAX")
    except (OSError, ValueError):
        return 255


def _head(final: str, limit: int) -> str:
    """What a temporary for `final` is named after in a folder allowing `limit`-byte names: `final`
    itself where the temporary (and USD's save name on its way to it) fits, else as many of its
    first characters as fit, ``~`` and a digest of the whole name."""
    suffix = len(os.fsencode(Path(final).suffix))
    room = limit - _FIXED - suffix - max(0, _USD_EXTRA - suffix)
    if len(os.fsencode(final)) <= room:
        return final
    start = final
    while start and len(os.fsencode(start)) > room - 1 - _DIGEST:
        start = start[:-1]  # whole characters: the temporary's name stays as decodable as the final's
    return f"{start}~{_digest(final)}"


def _digest(final: str) -> str:
    return hashlib.sha256(os.fsencode(final)).hexdigest()[:_DIGEST]


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
        The final name (``teapot.glb`` for ``.teapot.glb.k2_9xq0a.tmp.glb``), or None; None too for
        a temporary named after the start of a long name (`is_temporary`, `temporary_of`).
    """
    m = _TEMPORARY.fullmatch(name)
    # a shortened temporary of a name with no suffix reads as an unshortened one of `<start>~<digest>`
    if m is None or _SHORTENED.fullmatch(name) is not None:
        return None
    final, rest = m["final"], m["rest"]
    return final if _rest_fits(rest, Path(final).suffix) else None


def is_temporary(name: str) -> bool:
    """Whether `name` is an `atomic_path` temporary: `temporary_target`'s, or one named after the
    start of a final name too long to be named in full (its final name cannot be told from it)."""
    if temporary_target(name) is not None:
        return True
    m = _SHORTENED.fullmatch(name)
    return m is not None and _ANY_REST.fullmatch(m["rest"]) is not None


def temporary_of(name: str, final: str) -> bool:
    """Whether `name` is an `atomic_path` temporary for the file named `final`, in either shape."""
    if temporary_target(name) == final:
        return True
    m = _SHORTENED.fullmatch(name)
    return (m is not None and final.startswith(m["start"]) and m["digest"] == _digest(final)
            and _rest_fits(m["rest"], Path(final).suffix))


def _rest_fits(rest: str, suffix: str) -> bool:
    """Whether `rest`, after ``.tmp``, ends a temporary for a final name with `suffix`: the suffix
    itself, or USD's save name on its way to it."""
    return rest == suffix or bool(suffix and _USD_SAFE_SAVE.fullmatch(rest))


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
