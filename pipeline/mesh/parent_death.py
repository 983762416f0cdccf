"""Make a worker process die with its parent, so that no bake runs on unseen after its batch is gone."""

from __future__ import annotations

import ctypes
import os
import signal
from multiprocessing import forkserver

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


def release_fork_server() -> None:
    """In a child of multiprocessing's fork server: let go of the server, so that it ends with the
    process that started it, and this child (`die_with_parent`: its parent is the server) with it.

    The server ends when the write end of its "alive" pipe is closed everywhere, and each child it
    forks inherits a copy: while a child lives, so does the server. A child waiting for the
    server's death would then outlive a killed batch or Dask worker and bake on, unseen, holding
    the batch's terminal (stdout and stderr). A no-op in any other process (the one that started
    the server holds that end in its own right).
    """
    server = forkserver._forkserver  # the module's one server (CPython 3.4+)
    if server._forkserver_pid is None and server._forkserver_alive_fd is not None:  # a child of a server
        os.close(server._forkserver_alive_fd)
        # as in a process with no server: one it needs is started afresh
        server._forkserver_alive_fd = server._forkserver_address = None
