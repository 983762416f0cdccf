"""Results made in a forked child while this process goes on: stages whose inputs are known early
run beside the stages before them.

A bake's worker runs its stages one after another, and most of them leave the second core idle
part of the time (the 50k dragon's stages: 11.7 CPU-s in 10.1 s). Threads did not help: the
atlas is numpy, which waited on the GIL that the plan's compiled loops held (7.0 s on a thread
against 3.7 s in turn: benchmarks/README.md#atlas-reuse). A forked child has a GIL of its own.

The child is forked before the process has started any thread pool (numba's, embree's, the GL
driver's): a child of a process with running pools inherits their locks, not their threads, and
may hang on them. Only a fresh asset worker (`asset_process.child_main`) says it has none
(`allow_fork`), and only its first fork is allowed: the bake starts its pools right after. Where
no fork is allowed (a test or a script calling `asset.bake_asset` in a process of its own, the
budget check's second bake), `Beside.start` returns None and the caller runs everything itself,
as before.

What the child makes comes back pickled through a pipe, in the order it was made; a thread of
this process drains the pipe, so the child never waits on a reader. Whatever the child does not
deliver (it raised, or died) the caller makes itself, in its own process: an error then surfaces
there, once, as it would have without the child. The child dies with this process
(`parent_death.die_with_parent`), and its memory counts in the asset's process tree
(`asset_process.supervise`).
"""

from __future__ import annotations

import os
import pickle
import signal
import struct
import threading
from collections.abc import Callable, Hashable, Iterator

from sssbake.pipeline.mesh.parent_death import die_with_parent

#: Length prefix of a message's name and body.
_HEAD = struct.Struct("<QQ")


#: Whether this process has started no thread pool yet (`allow_fork`).
_fork_allowed = False


def allow_fork() -> None:
    """Say that this process has started no thread pool: its next `Beside.start` may fork."""
    global _fork_allowed
    _fork_allowed = hasattr(os, "fork")


class Beside:
    """A forked child producing named results (`work`'s (name, value) pairs, in its order).

    Use `Beside.start`, `take` each result where it is needed, and `close` when done (a context
    manager does it).
    """

    def __init__(self, pid: int, fd: int):
        self.pid = pid
        self._got: dict[Hashable, bytes] = {}
        self._ended = False
        self._cond = threading.Condition()
        self._reader = threading.Thread(target=self._read, args=(fd,), name="sssbake-beside", daemon=True)
        self._reader.start()

    @staticmethod
    def start(work: Callable[[], Iterator[tuple[Hashable, object]]]) -> "Beside | None":
        """Fork a child that runs `work` (whose values are not None) and sends back what it
        yields; None unless `allow_fork` allowed it (one fork per allowance) and this process may
        use more than one CPU (on one, the child would only take turns with it: `--jobs` pins each
        worker to its share, `batch.pin_to_share`)."""
        global _fork_allowed
        if not _fork_allowed or len(os.sched_getaffinity(0)) < 2:
            return None
        _fork_allowed = False
        read, write = os.pipe()
        parent = os.getpid()
        pid = os.fork()
        if pid == 0:
            os.close(read)
            _serve(write, work, parent)
        os.close(write)
        return Beside(pid, read)

    def take(self, name: Hashable) -> object | None:
        """The value the child sent as `name`, once it came; None if it ended without (the caller
        makes it). Each result is taken once."""
        with self._cond:
            self._cond.wait_for(lambda: name in self._got or self._ended)
            body = self._got.pop(name, None)
        return None if body is None else pickle.loads(body)

    def close(self) -> None:
        """End the child (at once if it is still working) and reap it."""
        try:
            os.kill(self.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
        os.waitpid(self.pid, 0)
        self._reader.join()

    def __enter__(self) -> "Beside":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def _read(self, fd: int) -> None:
        with os.fdopen(fd, "rb") as pipe:
            while True:
                head = pipe.read(_HEAD.size)
                if len(head) < _HEAD.size:
                    break
                name_size, body_size = _HEAD.unpack(head)
                name, body = pipe.read(name_size), pipe.read(body_size)
                if len(body) < body_size:
                    break
                with self._cond:
                    self._got[pickle.loads(name)] = body
                    self._cond.notify_all()
        with self._cond:
            self._ended = True
            self._cond.notify_all()


def _serve(fd: int, work: Callable[[], Iterator[tuple[Hashable, object]]], parent: int) -> None:
    """The child: send each of `work`'s results, then end without running the parent's exit
    handlers or ``finally`` blocks (they belong to the parent's bake). An exception ends it
    silently: the parent makes what is missing and meets the error itself."""
    code = 1
    try:
        die_with_parent(parent)
        with os.fdopen(fd, "wb") as pipe:
            for name, value in work():
                key, body = pickle.dumps(name), pickle.dumps(value, protocol=pickle.HIGHEST_PROTOCOL)
                pipe.write(_HEAD.pack(len(key), len(body)) + key)
                pipe.write(body)
                pipe.flush()
        code = 0
    except BaseException:  # noqa: BLE001 - the parent redoes the work in its own process
        pass
    finally:
        os._exit(code)
