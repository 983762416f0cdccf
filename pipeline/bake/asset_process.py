"""Each asset baked in its own supervised worker process, under a wall-time and a memory limit.

A bit-flipped GLB or a mesh of a million duplicated vertices can run for hours or eat the
machine, and a crash in native code (xatlas, embree) kills its process: in the batch's own process
either takes every other asset down. So `supervise` starts one child per asset, polls it
`POLL_S` apart, and when it runs past `Limits.timeout_s`, or its process tree (the child and its
own children: the atlas runs xatlas in a grandchild) holds more than `Limits.memory_gib` of
resident memory, kills the whole tree and records one line naming the flag to raise. A child that
dies on its own (a signal, ``os._exit``) is a one-line failure too. Either way its half-written
outputs (`atomic.temporary_target` names of its own outputs, its staging folder: `bake.staging`)
and its private temporary folder (``TMPDIR`` of the child) are removed as soon as its whole tree has
exited (`_wait_exited`: a process killed in a system call finishes it first); the stage cache's
temporaries of a killed child are swept at the end of the batch (`batch.run_batch`).

Memory is measured by polling, not with ``RLIMIT_AS``: address-space limits count reservations,
not use, and embree's and OpenBLAS's thread stacks and EGL's driver mappings reserve gigabytes
they never touch, so a limit sized for what the bake uses would fail them at random. Polling
misses an allocation burst shorter than `POLL_S` (the kernel's OOM killer remains the last
resort); RSS counts pages shared with the fork server once per process, a few hundred MiB at most.

Watching costs the supervisor well under 0.5 % of a core per child, however many processes the
machine runs (benchmarks/README.md#supervisor-cost): a look reads the memory of the children's
known descendants only (`ProcessTree`), and every `LIST_S` the pids are listed (one directory read
of ``/proc``) to find new descendants among the processes started since, where reading every
process's parent each look (psutil's ``children(recursive=True)``) cost 1.5-6 ms of CPU.

Children come from a ``forkserver`` that has imported the pipeline once (`PRELOAD`): importing it
afresh costs seconds per asset, a fork from the server milliseconds
(benchmarks/README.md#batch-worker-start). A daemonic process (a Dask worker under its nanny) may
not have multiprocessing children; there the child is ``python -m sssbake.pipeline.bake.asset_process``
instead, paying the imports. Either way a child dies with its supervisor (`child_main`).

Ctrl-C reaches the whole foreground process group: the batch, the fork server, a Dask worker.
Under `stop_on_signals` SIGINT, SIGTERM and SIGHUP raise `Interrupted` in the batch's main thread,
between two looks (`signals_held`), and `supervise` kills its children's trees and cleans up after
them before it passes it on. Every process started under `signals_held` inherits the signals
blocked (the fork server and its children, a local Dask cluster's workers), so none of them prints
a KeyboardInterrupt traceback: a child, in a session of its own, unblocks them once it is out of
the terminal's reach; the fork server and the workers end with the batch.
"""

from __future__ import annotations

import contextlib
import json
import multiprocessing
import multiprocessing.connection
import os
import pickle
import select
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from multiprocessing import forkserver, resource_tracker
from pathlib import Path

import psutil

from sssbake.exporters.atomic import temporary_of, temporary_target
from sssbake.pipeline.bake.beside import allow_fork
from sssbake.pipeline.bake.staging import holds_any, is_staging
from sssbake.pipeline.mesh.parent_death import die_with_parent, release_fork_server

# Seconds between two looks at a child's time and memory.
POLL_S = 0.1
# Seconds between two listings of the machine's processes, to find the children's new descendants:
# a look reads the memory of those found (the pipeline starts a few, each running for seconds).
LIST_S = 1.0
# What the fork server imports once, so that a child starts baking at once.
PRELOAD = ["sssbake.pipeline.bake.batch", "sssbake.pipeline.bake.asset", "sssbake.pipeline.bake.check"]
# Output suffixes one bake writes (`bake.bake_asset`), for removing a killed child's temporaries.
OUTPUT_SUFFIXES = (".glb", ".usdc", ".report.json", ".sss_normals.glb")
_GIB = 1024.0**3
# Seconds a killed child's descendants may take to exit (one in a system call ends it first): beyond,
# one blocked on a hung disk, its temporaries are left to the next batch (`sweep_orphaned_folders`).
EXIT_WAIT_S = 10.0
# A child's private temporary folder: ``<tempdir>/sssbake-asset-<supervisor's pid>-<random>``.
FOLDER_PREFIX = "sssbake-asset-"
# What stops a batch (`stop_on_signals`): Ctrl-C, kill's default, a closed terminal.
STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)
# Linux's per-process files; elsewhere psutil answers (`_pid_names`, `_parent`, `_watch`, `_resident`).
_PROCFS = os.path.exists("/proc/self/stat")
_PAGE = os.sysconf("SC_PAGE_SIZE") if _PROCFS else 4096


class Interrupted(KeyboardInterrupt):
    """A stop signal ended the batch (`stop_on_signals`).

    Attributes
    ----------
    signum : int
    records : list of (dict or None), or None
        Set on its way out of the batch: per asset its record where it was done, None where not.
    """

    def __init__(self, signum: int):
        super().__init__(signum)
        self.signum = signum
        self.records: list[dict | None] | None = None

    def __str__(self) -> str:
        name = _signal_name(self.signum)
        if self.records is None:
            return f"interrupted by {name} before any asset was baked; nothing was written"
        done = [r for r in self.records if r is not None]
        failed = sum(r["status"] == "failed" for r in done)
        return (f"interrupted by {name}: {len(done) - failed} baked, {failed} failed, {len(self.records) - len(done)} "
                "not baked; run the same command again to bake the rest")


@contextlib.contextmanager
def stop_on_signals() -> Iterator[None]:
    """Within the block, `STOP_SIGNALS` raise `Interrupted` (within `signals_held`, as it ends); one
    more while the batch stops is ignored, as the stopping (killing the children, removing their
    temporaries) is quick and, cut short, would leave children baking on. Entered in another thread
    than the main one, which alone may handle signals, it changes nothing."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def handler(signum, _frame):
        for s in STOP_SIGNALS:
            signal.signal(s, signal.SIG_IGN)
        if _HELD[0]:
            _DEFERRED.append(signum)
        else:
            raise Interrupted(signum)

    old = {s: signal.signal(s, handler) for s in STOP_SIGNALS}
    try:
        yield
    finally:
        _DEFERRED.clear()
        for s, h in old.items():
            signal.signal(s, h)


# How deep the main thread is in `signals_held`, and the stop signal its handler put off meanwhile.
_HELD = [0]
_DEFERRED: list[int] = []


@contextlib.contextmanager
def signals_held() -> Iterator[None]:
    """Hold `STOP_SIGNALS` within the block; one sent meanwhile raises `Interrupted` as it ends.

    A batch stopped in the middle of a look could leave a child started but not yet watched, or
    ended but not yet cleaned up after. The signals are blocked in this thread, so that processes
    started within inherit them blocked; and in the main thread `stop_on_signals`'s handler puts one
    off to the block's end, as blocking is not enough there: the kernel hands a process's signal to
    any thread not blocking it (OpenBLAS's, started as numpy is imported), and Python then runs its
    handler in the main thread at once.

    multiprocessing's resource tracker unblocks SIGINT and SIGTERM in the thread that starts it
    (and its fork server starts it): start it first (`resource_tracker.ensure_running`), so that it
    leaves the block alone.
    """
    if not hasattr(signal, "pthread_sigmask"):  # not POSIX
        yield
        return
    main = threading.current_thread() is threading.main_thread()
    old = signal.pthread_sigmask(signal.SIG_BLOCK, STOP_SIGNALS)
    _HELD[0] += main
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, old)  # one pending in this thread is handled (put off) now
        _HELD[0] -= main
    if main and not _HELD[0] and _DEFERRED:
        raise Interrupted(_DEFERRED.pop())


@dataclass(frozen=True)
class Limits:
    """What one asset may use; 0 means no limit.

    Attributes
    ----------
    timeout_s : float
        Wall-clock seconds from the child's start.
    memory_gib : float
        Resident memory of the child and its descendants together, GiB.
    """

    timeout_s: float
    memory_gib: float


@dataclass(frozen=True)
class Task:
    """One asset for a child: the arguments of `batch.run_job` and its limits.

    Attributes
    ----------
    job : batch.Job
    config : config.BatchConfig
    overrides : dict
    cache_dir : str or None
    limits : Limits
    """

    job: object
    config: object
    overrides: dict
    cache_dir: str | None
    limits: Limits


def supervise(tasks: Sequence[Task], slots: int = 1, on_done: Callable[[int, dict], object] | None = None,
              pin: tuple[int, int] | None = None, tag: str | None = None) -> list[dict]:
    """Bake `tasks`, at most `slots` children at once, each under its own limits.

    Parameters
    ----------
    tasks : sequence of Task
        Started in the given order.
    slots : int
        Children at once; with more than one, each is confined to its slot's share of the CPUs
        (`batch.pin_to_share`).
    on_done : callable, optional
        Called with a task's index and its record as each ends.
    pin : (index, count), optional
        Confine every child to share `index` of `count` instead (a Dask worker's share).
    tag : str, optional
        The batch these tasks belong to, for `stop`.

    Returns
    -------
    list of dict
        One `batch.run_job` record per task, in the order of `tasks`; a child over a limit, or one
        that died, gives a failed record with a one-line error naming the asset. None for a task not
        started because its batch was stopped (`stop`).

    Raises
    ------
    Interrupted
        From `stop_on_signals`, once every child is killed and cleaned up after (`on_done` is
        called for a child that had finished as it was killed).
    """
    sweep_orphaned_folders()
    records: list[dict | None] = [None] * len(tasks)
    pending = iter(range(len(tasks)))
    running: dict[int, _Child] = {}  # slot -> child
    live = _LIVE.setdefault(tag, set()) if tag is not None else set()
    processes = _Processes()  # before any child starts: its descendants are new in every later listing
    listed = time.monotonic()
    if tasks:
        resource_tracker.ensure_running()  # before `signals_held`, which it would undo
    try:
        while True:
            with signals_held():  # a stop signal lands between two looks, never in one
                new: dict[int, int] = {}
                if time.monotonic() - listed >= LIST_S:
                    new, listed = processes.new(), time.monotonic()
                for slot, child in list(running.items()):
                    child.tree.adopt(new)
                    record = child.poll()
                    if record is not None:
                        del running[slot]
                        live.discard(child)
                        records[child.index] = record
                        if on_done is not None:
                            on_done(child.index, record)
                for slot in range(slots):
                    if slot not in running and tag not in _STOPPED and (i := next(pending, None)) is not None:
                        running[slot] = _Child(i, tasks[i], pin or (slot, slots))
                        live.add(running[slot])
                if not running:
                    return records  # type: ignore[return-value]
            # the next look at once when a child ends (its record is then waiting), else in POLL_S
            sentinels = [c.proc.sentinel for c in running.values() if isinstance(c.proc, multiprocessing.process.BaseProcess)]
            if sentinels:
                multiprocessing.connection.wait(sentinels, timeout=POLL_S)
            else:
                time.sleep(POLL_S)
    except BaseException:  # a stop signal, Ctrl-C, a bug: no orphans baking on
        with signals_held():
            for child in running.values():
                if (record := child.end(None)) is not None and on_done is not None:
                    on_done(child.index, record)
        raise
    finally:
        live.difference_update(running.values())
        if tag is not None and not live:
            _LIVE.pop(tag, None)


# Per batch (`supervise`'s tag) its children running in this process, and the batches stopped (`stop`).
_LIVE: dict[str, set] = {}
_STOPPED: set[str] = set()


def stop(tag: str) -> int:
    """Stop the batch `tag` in this process: kill the process trees of its children (their
    supervisors clean up after them as after any death) and start no more; returns how many.

    A batch interrupted while its tasks run on Dask workers runs this on every worker
    (`batch_dask`): cancelling a task does not stop it.
    """
    _STOPPED.add(tag)
    children = list(_LIVE.get(tag, ()))
    for child in children:
        # its group holds its descendants (its supervisor's thread, which reads its tree, kills the rest)
        for kill in (os.killpg, os.kill):  # the group exists once the child has left the batch's (`child_main`)
            try:
                kill(child.pid, signal.SIGKILL)
            except (ProcessLookupError, PermissionError):
                pass
    return len(children)


class _Child:
    """One running child and what it needs cleaned when it ends."""

    def __init__(self, index: int, task: Task, share: tuple[int, int]):
        self.index, self.task = index, task
        self.tmp = Path(tempfile.mkdtemp(prefix=f"{FOLDER_PREFIX}{os.getpid()}-"))
        self.result = self.tmp / "record.json"
        self.t0 = time.monotonic()
        args = (task, str(self.tmp), *share, os.getpid())
        ctx = _context()
        if ctx is not None:
            self.proc = ctx.Process(target=child_main, args=args, daemon=True)
            self.proc.start()
            # readable once the fork server has told its end: a look at it costs one system call
            self.ended = select.poll()
            self.ended.register(self.proc.sentinel, select.POLLIN)
        else:
            self.proc = subprocess.Popen([sys.executable, "-m", __name__, str(os.getpid())], stdin=subprocess.PIPE,
                                         start_new_session=True)
            self.proc.stdin.write(pickle.dumps(args))
            self.proc.stdin.close()
        self.pid = self.proc.pid
        self.tree = ProcessTree(self.pid)

    def exitcode(self) -> int | None:
        if isinstance(self.proc, multiprocessing.process.BaseProcess):
            return self.proc.exitcode if self.ended.poll(0) else None
        return self.proc.poll()

    def poll(self) -> dict | None:
        """The record once the child has ended (killing it first when over a limit), else None."""
        path, limits = self.task.job.path, self.task.limits
        code = self.exitcode()
        if code is None:
            seconds = time.monotonic() - self.t0
            if limits.timeout_s and seconds > limits.timeout_s:
                return self.end(f"{path}: exceeded {limits.timeout_s:g} s; raise --asset-timeout "
                                "(or asset_timeout_s in the config)")
            if limits.memory_gib and (rss := self.tree.rss()) > limits.memory_gib * _GIB:
                return self.end(f"{path}: exceeded {limits.memory_gib:g} GiB of memory ({rss / _GIB:.2f} GiB "
                                "resident); raise --asset-memory (or asset_memory_gib in the config)")
            return None
        why = (f"died by signal {-code} ({_signal_name(-code)})" if code < 0 else f"exited with code {code}")
        return self.end(f"{path}: the worker process baking it {why}, a crash in native code or an interpreter "
                        "abort; nothing was written for it")

    def end(self, error: str | None) -> dict | None:
        """Kill the child's tree if still alive, reap it and clean up after it. Its record where it
        wrote one, or where its asset's outputs are all in place and up to date (it had finished,
        and was ending as it was killed), else a failed record with `error`, or None without one
        (the batch was interrupted)."""
        from sssbake.pipeline.bake.batch import up_to_date_record

        self.kill()
        try:
            record = json.loads(self.result.read_text())
        except (OSError, ValueError):  # never written, or cut short by the kill
            task = self.task
            if (record := up_to_date_record(task.job, task.config, task.overrides)) is not None:
                record["status"] = "ok"  # a batch starts no child for an asset up to date: this one baked it
        self.clean()
        if record is not None or error is None:
            return record
        return {"asset": str(self.task.job.path), "outputs": [], "status": "failed", "error": error,
                "seconds": round(time.monotonic() - self.t0, 3)}

    def kill(self) -> None:
        """SIGKILL the child's whole tree and reap the child."""
        self.tree.kill()
        try:
            os.killpg(self.pid, signal.SIGKILL)  # those started since the last listing are in its group
        except (ProcessLookupError, PermissionError):
            pass
        if isinstance(self.proc, multiprocessing.process.BaseProcess):
            self.proc.join()
        else:
            self.proc.wait()
        # Its descendants are not ours to reap: wait for them to have exited, as one killed in a
        # system call (creating a file in its temporary folder) ends that call first, and would put
        # back what `clean` had just removed.
        _wait_exited(self.pid, set(self.tree.members))
        self.tree.close()

    def clean(self) -> None:
        """Remove the child's temporary folder and any half-written output of its asset."""
        shutil.rmtree(self.tmp, ignore_errors=True)
        out_base = self.task.job.out_base
        ours = {out_base.name + suffix for suffix in OUTPUT_SUFFIXES}
        try:
            names = os.listdir(out_base.parent)
        except OSError:  # never created
            return
        for name in names:
            target = temporary_target(name)
            # the .usdc's thickness textures: <stem>.thickness<k>.png (one named after a name too long,
            # or holding what a USD asset path cannot, is left to the batch's sweep: `batch._batch_lock`)
            if any(temporary_of(name, final) for final in ours) or (
                    target and target.startswith(out_base.name + ".thickness") and target.endswith(".png")):
                (out_base.parent / name).unlink(missing_ok=True)
            elif is_staging(name) and holds_any(out_base.parent / name, ours):  # its bake's outputs (`bake.staging`)
                shutil.rmtree(out_base.parent / name, ignore_errors=True)


def sweep_orphaned_folders() -> int:
    """Remove the children's temporary folders whose supervisor is gone; returns how many.

    A supervisor killed outright (a Dask worker killed under its asset, a batch SIGKILLed) cannot
    remove its children's folders; the next supervisor on this machine does. A folder whose
    supervisor's pid is alive, even if the pid was reused, is left alone.
    """
    removed = 0
    root = Path(tempfile.gettempdir())
    for folder in root.glob(f"{FOLDER_PREFIX}*-*"):
        pid = folder.name[len(FOLDER_PREFIX):].split("-", 1)[0]
        if pid.isdigit() and not psutil.pid_exists(int(pid)) and folder.is_dir() and not folder.is_symlink():
            shutil.rmtree(folder, ignore_errors=True)
            removed += 1
    return removed


def tree_rss(pid: int) -> int:
    """Resident bytes of process `pid` and all its descendants (0 once it is gone); reads every process."""
    tree = ProcessTree(pid)
    try:
        tree.adopt({p: parent for p in _pids() if (parent := _parent(p)) is not None})
        return tree.rss()
    finally:
        tree.close()


class ProcessTree:
    """A process and its descendants, as far as `adopt` has been told of them.

    A process joins the tree when it is new with a parent in the tree (`_Processes.new`), and stays
    until it ends, even once its parent has ended and it is another's child. Each is watched through
    its own open ``/proc/<pid>/statm``: one read a look, and one that never reads another process
    that was given the pid since. `close` when done with it.
    """

    def __init__(self, root: int):
        self.members: dict[int, object] = {}  # pid -> `_watch` handle
        self._add(root)

    def _add(self, pid: int) -> None:
        if (handle := _watch(pid)) is not None:
            self.members[pid] = handle

    def adopt(self, new: dict[int, int]) -> None:
        """Add the processes of `new` (pid -> parent pid) whose parent is in the tree, or joins it."""
        pending = {pid: parent for pid, parent in new.items() if pid not in self.members}
        while found := [pid for pid, parent in pending.items() if parent in self.members]:
            for pid in found:
                del pending[pid]
                self._add(pid)

    def rss(self) -> int:
        """Resident bytes of the tree's processes together; those that ended leave it."""
        total = 0
        for pid, handle in list(self.members.items()):
            if (rss := _resident(handle)) is None:
                _unwatch(self.members.pop(pid))
            else:
                total += rss
        return total

    def kill(self) -> None:
        """SIGKILL every process of the tree still running."""
        for pid, handle in list(self.members.items()):
            if _resident(handle) is not None:  # still that process: its pid is no other's yet
                try:
                    os.kill(pid, signal.SIGKILL)
                except (ProcessLookupError, PermissionError):  # ended meanwhile
                    pass

    def close(self) -> None:
        while self.members:
            _unwatch(self.members.popitem()[1])


class _Processes:
    """The machine's processes as of the last listing, to tell which are new at the next.

    A listing reads the pids (``/proc``: one directory read) and the parent of only the new ones,
    so its cost grows with the processes started since, not with all there are. A pid that ended
    and was reused between two listings would go unseen: the kernel hands pids out in turn, and
    reaching the same one again takes tens of thousands of processes started.
    """

    def __init__(self):
        self.known = _pid_names()

    def new(self) -> dict[int, int]:
        """pid -> parent pid of every process started since the last listing (and still running)."""
        now = _pid_names()
        fresh = now - self.known
        self.known = now
        return {pid: parent for name in fresh if name.isdigit() and (parent := _parent(pid := int(name))) is not None}


def _pid_names() -> set[str]:
    """The running processes' pids, as strings (``/proc``'s entries, some of them not pids)."""
    return set(os.listdir("/proc")) if _PROCFS else {str(p) for p in psutil.pids()}


def _pids() -> list[int]:
    return [int(name) for name in _pid_names() if name.isdigit()]


def _parent(pid: int) -> int | None:
    """Process `pid`'s parent pid; None once it has ended."""
    return None if (stat := _stat(pid)) is None else stat[1]


def _stat(pid: int) -> tuple[str, int, int] | None:
    """Process `pid`'s state (``"Z"``: exited, not yet reaped), parent pid and process group; None once it has ended."""
    if not _PROCFS:
        try:
            with psutil.Process(pid).oneshot() as p:
                return ("Z" if p.status() == psutil.STATUS_ZOMBIE else "R"), p.ppid(), os.getpgid(pid)
        except (psutil.Error, OSError):
            return None
    try:
        with open(f"/proc/{pid}/stat", "rb") as f:
            # after the command's name (which may hold spaces and parentheses): state, ppid, pgrp (proc(5))
            state, ppid, pgrp = f.read().rpartition(b")")[2].split()[:3]
            return state.decode(), int(ppid), int(pgrp)
    except (OSError, ValueError):  # ended meanwhile
        return None


def _wait_exited(group: int, pids: set[int]) -> None:
    """Wait until every process of process group `group` and of `pids`, all sent SIGKILL, has
    exited (a zombie, or gone), for at most `EXIT_WAIT_S`."""
    until = time.monotonic() + EXIT_WAIT_S
    while time.monotonic() < until:
        if not any((stat := _stat(pid)) is not None and stat[0] not in "ZX" and (pid in pids or stat[2] == group)
                   for pid in _pids()):
            return
        time.sleep(0.001)


def _watch(pid: int):
    """A handle on process `pid` for `_resident`: its ``statm`` opened, or a psutil.Process; None once it has ended."""
    if not _PROCFS:
        try:
            return psutil.Process(pid)
        except psutil.Error:
            return None
    try:
        return os.open(f"/proc/{pid}/statm", os.O_RDONLY)
    except OSError:
        return None


def _resident(handle) -> int | None:
    """Resident bytes of the process `handle` watches (`_watch`); None once it has ended."""
    if not _PROCFS:
        try:
            return handle.memory_info().rss
        except psutil.Error:
            return None
    try:
        fields = os.pread(handle, 256, 0).split()  # size resident shared text lib data dt, in pages
    except OSError:  # ESRCH: the process is gone
        return None
    return int(fields[1]) * _PAGE if fields else None


def _unwatch(handle) -> None:
    if _PROCFS:
        os.close(handle)


def _signal_name(number: int) -> str:
    try:
        return signal.Signals(number).name
    except ValueError:
        return "unknown signal"


_CONTEXT: list = []


def _context():
    """The fork-server context (started on first use, preloaded), or None in a daemonic process."""
    if multiprocessing.current_process().daemon:
        return None
    if not _CONTEXT:
        ctx = multiprocessing.get_context("forkserver")
        ctx.set_forkserver_preload(PRELOAD)
        _CONTEXT.append(ctx)
    return _CONTEXT[0]


def start_fork_server() -> None:
    """Start the fork server (`_context`) now rather than at the first child, so that its imports
    (`PRELOAD`, ~1.4 s at the 50k dragon) run beside the caller's (the CLI's own, ~1 s); a no-op in
    a daemonic process or once it runs. Started as `supervise` starts its children: the resource
    tracker first, then with the stop signals held, which the server inherits."""
    if _context() is None:
        return
    resource_tracker.ensure_running()
    with signals_held():
        forkserver.ensure_running()


def child_main(task: Task, tmp: str, slot: int, slots: int, supervisor: int) -> None:
    """In the child: bake `task` and write its record to ``tmp/record.json`` for its `supervisor`."""
    from sssbake.pipeline.bake.batch import pin_to_share, run_job

    if os.getsid(0) != os.getpid():
        os.setsid()  # a group of its own, so that killing it reaches every descendant
    # Out of the terminal's process group now. The stop signals, blocked since it was started
    # (`signals_held`), take their default action: one the terminal sent before ends it quietly,
    # as would one sent to it later, where Python's own SIGINT handler would print a traceback.
    for signum in STOP_SIGNALS:
        signal.signal(signum, signal.SIG_DFL)
    signal.pthread_sigmask(signal.SIG_UNBLOCK, STOP_SIGNALS)
    release_fork_server()
    die_with_parent()
    if not psutil.pid_exists(supervisor):  # it died before the request above: nobody waits for this asset
        return
    # Its temporaries (the atlas's, the validators') in a folder the supervisor removes, even after a kill.
    os.environ["TMPDIR"] = tmp
    tempfile.tempdir = tmp
    pin_to_share(slot, slots)
    allow_fork()  # nothing has started a thread pool here yet: the bake may fork a child beside it (`bake.beside`)
    record = run_job(task.job, task.config, task.overrides, task.cache_dir)
    part = Path(tmp) / "record.json.part"
    try:
        part.write_text(json.dumps(record))
        part.rename(Path(tmp) / "record.json")
    except FileNotFoundError:  # its supervisor is gone and the folder swept (`sweep_orphaned_folders`)
        return


if __name__ == "__main__":
    die_with_parent(int(sys.argv[1]))  # before the task's imports: its parent may die meanwhile
    child_main(*pickle.loads(sys.stdin.buffer.read()))
