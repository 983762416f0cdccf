"""Make a worker process die with its parent, so that no bake runs on unseen after its batch is gone."""

from __future__ import annotations

import ctypes
import os
import signal

PR_SET_PDEATHSIG = 1


def die_with_parent(parent: int | None = None) -> None:
    """Ask Linux to SIGKILL this process when its parent ends; a no-op elsewhere.

    An asset's worker and the xatlas process under it each call this: killing the batch outright
    (SIGKILL, a closed terminal) would otherwise leave them running for as long as their asset takes
    (an atlas of 400k copies of one triangle ran on for hours).

    Parameters
    ----------
    parent : int, optional
        The pid of the process that started this one. A parent that died before the request was
        made (while this process imported for seconds) sends no signal: then this process ends now.
    """
    try:
        ctypes.CDLL(None, use_errno=True).prctl(PR_SET_PDEATHSIG, signal.SIGKILL)
    except (OSError, AttributeError):  # not Linux
        return
    if parent is not None and os.getppid() != parent:
        os.kill(os.getpid(), signal.SIGKILL)
