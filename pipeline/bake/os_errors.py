"""One line for an OSError met on a folder the user named: the file, the problem and, for a full disk
or a folder that may not be written, the fix, naming the option that gave the folder (``-o`` for the
outputs, ``--cache-dir`` for the stage cache)."""

from __future__ import annotations

import errno
from pathlib import Path

from sssbake.exporters.atomic import temporary_target
from sssbake.pipeline.bake.staging import is_staging

# errno values that mean "no room left" (EFBIG: over the file size limit, RLIMIT_FSIZE or the filesystem's)
_FULL = (errno.ENOSPC, errno.EDQUOT, errno.EFBIG)
_DENIED = (errno.EACCES, errno.EPERM, errno.EROFS)
# What else the user may do besides giving the option another folder: a stage cache can be done without.
_INSTEAD = {"-o": "", "--cache-dir": ", or --no-cache"}


def os_error_line(path: Path, e: OSError, option: str = "-o") -> str:
    """One line for `e` met while working on `path`: the file and the problem, and for a full disk or
    a folder we may not write the fix; a temporary's name is given as the file it was written for,
    and a file in a bake's staging folder (`staging`) as the one it is moved to.

    Parameters
    ----------
    path : Path
        The asset or folder the work was for.
    e : OSError
    option : str
        The option that names the folder written (a key of `_INSTEAD`): the fix names it.
    """
    if e.errno is None:
        return f"{path}: {e}"
    name = e.filename if isinstance(e.filename, str) else None
    if name is not None and (final := temporary_target(Path(name).name)) is not None:
        name = str(Path(name).with_name(final))
    if name is not None and is_staging(Path(name).parent.name):
        name = str(Path(name).parent.parent / Path(name).name)
    elif name is not None and is_staging(Path(name).name):
        name = str(Path(name).parent)
    what = f"{name}: {e.strerror}" if name is not None and name != str(path) else e.strerror
    if e.errno in _FULL:
        return f"{path}: {what}; free some space or give {option} a folder on another disk{_INSTEAD[option]}"
    if e.errno in _DENIED:
        return f"{path}: {what}; give {option} a folder you may write{_INSTEAD[option]}"
    return f"{path}: {what}"
