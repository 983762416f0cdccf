"""Each asset baked in its own supervised worker process, under a wall-time and a memory limit.

A bit-flipped GLB or a mesh of a million duplicated vertices can run for hours or eat the
machine, and a crash in native code (xatlas, embree) kills its process: in the batch's own process
either takes every other asset down. So `supervise` starts one child per asset, polls it
`POLL_S` apart, and when it runs past `Limits.timeout_s`, or its process tree (the child and its
own children: the atlas runs xatlas in a grandchild) holds more than `Limits.memory_gib` of
resident memory, kills the whole tree and records one line naming the flag to raise. A child that
dies on its own (a signal, ``os._exit``) is a one-line failure too. Either way its half-written
outputs (`atomic.temporary_target` names of its own outputs) and its private temporary folder
(``TMPDIR`` of the child) are removed at once; the stage cache's temporaries of a killed child
are swept at the end of the batch (`batch.run_batch`).

Memory is measured by polling, not with ``RLIMIT_AS``: address-space limits count reservations,
not use, and embree's and OpenBLAS's thread stacks and EGL's driver mappings reserve gigabytes
they never touch, so a limit sized for what the bake uses would fail them at random. Polling
misses an allocation burst shorter than `POLL_S` (the kernel's OOM killer remains the last
resort); RSS counts pages shared with the fork server once per process, a few hundred MiB at most.

Children come from a ``forkserver`` that has imported the pipeline once (`PRELOAD`): importing it
afresh costs seconds per asset, a fork from the server milliseconds
(benchmarks/README.md#batch-worker-start). A daemonic process (a Dask worker under its nanny) may
not have multiprocessing children; there the child is ``python -m sssbake.pipeline.bake.asset_process``
instead, paying the imports.
"""

from __future__ import annotations

import json
import multiprocessing
import os
import pickle
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import psutil

from sssbake.exporters.atomic import temporary_target
from sssbake.pipeline.mesh.parent_death import die_with_parent

# Seconds between two looks at a child's time and memory.
POLL_S = 0.1
# What the fork server imports once, so that a child starts baking at once.
PRELOAD = ["sssbake.pipeline.bake.batch", "sssbake.pipeline.bake.asset", "sssbake.pipeline.bake.check"]
# Output suffixes one bake writes (`bake.bake_asset`), for removing a killed child's temporaries.
OUTPUT_SUFFIXES = (".glb", ".usdc", ".report.json", ".sss_normals.glb")
_GIB = 1024.0**3
# A child's private temporary folder: ``<tempdir>/sssbake-asset-<supervisor's pid>-<random>``.
FOLDER_PREFIX = "sssbake-asset-"


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
              pin: tuple[int, int] | None = None) -> list[dict]:
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

    Returns
    -------
    list of dict
        One `batch.run_job` record per task, in the order of `tasks`; a child over a limit, or one
        that died, gives a failed record with a one-line error naming the asset.
    """
    sweep_orphaned_folders()
    records: list[dict | None] = [None] * len(tasks)
    pending = iter(range(len(tasks)))
    running: dict[int, _Child] = {}  # slot -> child
    try:
        while True:
            for slot in range(slots):
                if slot not in running and (i := next(pending, None)) is not None:
                    running[slot] = _Child(i, tasks[i], pin or (slot, slots))
            if not running:
                return records  # type: ignore[return-value]
            time.sleep(POLL_S)
            for slot, child in list(running.items()):
                record = child.poll()
                if record is not None:
                    del running[slot]
                    records[child.index] = record
                    if on_done is not None:
                        on_done(child.index, record)
    finally:
        for child in running.values():  # interrupted (Ctrl-C): no orphans baking on
            child.kill()
            child.clean()


class _Child:
    """One running child and what it needs cleaned when it ends."""

    def __init__(self, index: int, task: Task, share: tuple[int, int]):
        self.index, self.task = index, task
        self.tmp = Path(tempfile.mkdtemp(prefix=f"{FOLDER_PREFIX}{os.getpid()}-"))
        self.result = self.tmp / "record.json"
        self.t0 = time.monotonic()
        args = (task, str(self.tmp), *share)
        ctx = _context()
        if ctx is not None:
            self.proc = ctx.Process(target=child_main, args=args, daemon=True)
            self.proc.start()
        else:
            self.proc = subprocess.Popen([sys.executable, "-m", __name__, str(os.getpid())], stdin=subprocess.PIPE,
                                         start_new_session=True)
            self.proc.stdin.write(pickle.dumps(args))
            self.proc.stdin.close()
        self.pid = self.proc.pid

    def exitcode(self) -> int | None:
        return self.proc.exitcode if isinstance(self.proc, multiprocessing.process.BaseProcess) else self.proc.poll()

    def poll(self) -> dict | None:
        """The record once the child has ended (killing it first when over a limit), else None."""
        path, limits = self.task.job.path, self.task.limits
        code = self.exitcode()
        if code is None:
            seconds = time.monotonic() - self.t0
            if limits.timeout_s and seconds > limits.timeout_s:
                return self._failed(f"{path}: exceeded {limits.timeout_s:g} s; raise --asset-timeout "
                                    "(or asset_timeout_s in the config)")
            if limits.memory_gib and (rss := tree_rss(self.pid)) > limits.memory_gib * _GIB:
                return self._failed(f"{path}: exceeded {limits.memory_gib:g} GiB of memory ({rss / _GIB:.2f} GiB "
                                    "resident); raise --asset-memory (or asset_memory_gib in the config)")
            return None
        if code == 0 and self.result.is_file():
            record = json.loads(self.result.read_text())
            self.clean()
            return record
        why = (f"died by signal {-code} ({_signal_name(-code)})" if code < 0 else f"exited with code {code}")
        return self._failed(f"{path}: the worker process baking it {why}, a crash in native code or an "
                            "interpreter abort; nothing was written for it")

    def _failed(self, error: str) -> dict:
        self.kill()
        self.clean()
        return {"asset": str(self.task.job.path), "outputs": [], "status": "failed", "error": error,
                "seconds": round(time.monotonic() - self.t0, 3)}

    def kill(self) -> None:
        """SIGKILL the child's whole tree and reap the child."""
        for proc in _tree(self.pid):
            try:
                proc.kill()
            except psutil.Error:  # ended meanwhile
                pass
        try:
            os.killpg(self.pid, signal.SIGKILL)  # descendants that outlived their parent keep its group
        except (ProcessLookupError, PermissionError):
            pass
        if isinstance(self.proc, multiprocessing.process.BaseProcess):
            self.proc.join()
        else:
            self.proc.wait()

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
            # the .usdc's thickness textures: <stem>.thickness<k>.png
            if target in ours or (target and target.startswith(out_base.name + ".thickness") and target.endswith(".png")):
                (out_base.parent / name).unlink(missing_ok=True)


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
    """Resident bytes of process `pid` and all its descendants (0 once it is gone)."""
    total = 0
    for proc in _tree(pid):
        try:
            total += proc.memory_info().rss
        except psutil.Error:  # ended between the listing and the reading
            pass
    return total


def _tree(pid: int) -> list[psutil.Process]:
    try:
        root = psutil.Process(pid)
        return [root, *root.children(recursive=True)]
    except psutil.Error:
        return []


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


def child_main(task: Task, tmp: str, slot: int, slots: int) -> None:
    """In the child: bake `task` and write its record to ``tmp/record.json``."""
    from sssbake.pipeline.bake.batch import pin_to_share, run_job

    if os.getsid(0) != os.getpid():
        os.setsid()  # a group of its own, so that killing it reaches every descendant
    die_with_parent()
    # Its temporaries (the atlas's, the validators') in a folder the supervisor removes, even after a kill.
    os.environ["TMPDIR"] = tmp
    tempfile.tempdir = tmp
    pin_to_share(slot, slots)
    record = run_job(task.job, task.config, task.overrides, task.cache_dir)
    part = Path(tmp) / "record.json.part"
    part.write_text(json.dumps(record))
    part.rename(Path(tmp) / "record.json")


if __name__ == "__main__":
    die_with_parent(int(sys.argv[1]))  # before the task's imports: its parent may die meanwhile
    child_main(*pickle.loads(sys.stdin.buffer.read()))
