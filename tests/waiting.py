"""Waiting on a batch in a test without a wall-clock limit tuned to a quiet machine: a wait fails
only when the batch has made no progress for `STALL_S`, however slowly a loaded machine runs it.

Progress is what a batch that moves on changes: the processes under it (a worker, a fork server or
an asset's child started or ended) and the CPU time of its assets' children, each of which leads a
session of its own (`asset_process.child_main`), their helpers (xatlas, the validators) included.
A Dask worker or a batch's own process waiting on a hung batch spends CPU on its event loop or its
looks, which is not progress: processes in the test's session, or in that of the batch's process,
do not count.
"""

from __future__ import annotations

import os
import subprocess
import threading
import time

import psutil
import pytest

# No progress for this long: the batch hangs. Longer than any step of a batch without a child at
# work (starting an interpreter, importing the pipeline, starting a Dask cluster) on a loaded machine.
STALL_S = 300.0


def _progress(root: psutil.Process) -> tuple[frozenset[int], float]:
    """The pids under `root` and the CPU seconds (to 0.1 s) of those in sessions of their own."""
    try:
        procs = root.children(recursive=True)
        quiet = {os.getsid(0), os.getsid(root.pid)}
    except (psutil.Error, ProcessLookupError):  # `root` ended
        return frozenset(), 0.0
    cpu = 0.0
    for proc in procs:
        try:
            if os.getsid(proc.pid) not in quiet:
                times = proc.cpu_times()
                cpu += times.user + times.system
        except (psutil.Error, ProcessLookupError):  # ended meanwhile
            pass
    return frozenset(p.pid for p in procs), round(cpu, 1)


class _Watch:
    """Fails the test when `root`'s progress has not changed for `STALL_S`."""

    def __init__(self, root: int, what: str):
        self.root, self.what = psutil.Process(root), what
        self.seen, self.since = _progress(self.root), time.monotonic()

    def check(self) -> None:
        now = _progress(self.root)
        if now != self.seen:
            self.seen, self.since = now, time.monotonic()
        elif time.monotonic() - self.since > STALL_S:
            pytest.fail(f"{self.what}: no progress for {STALL_S:g} s (no process started or ended, no CPU spent "
                        "baking): the batch hangs")


def until_done(fn, *args, **kwargs):
    """`fn(*args, **kwargs)` run in a daemon thread of this process to its end: its value, or its
    exception raised again here. Fails the test when it stalls (`STALL_S`)."""
    box: dict = {}

    def target():
        try:
            box["value"] = fn(*args, **kwargs)
        except BaseException as e:  # raised again in the test's thread
            box["error"] = e

    watch = _Watch(os.getpid(), getattr(fn, "__name__", repr(fn)))
    thread = threading.Thread(target=target, daemon=True)
    thread.start()
    while thread.is_alive():
        thread.join(0.5)
        watch.check()
    if "error" in box:
        raise box["error"]
    return box["value"]


def wait_for(predicate, proc: subprocess.Popen, what: str) -> None:
    """Return once `predicate()` holds while `proc` runs. Fails the test when `proc` ends first
    (with its stderr, when piped) or stalls (`STALL_S`)."""
    watch = _Watch(proc.pid, what)
    while not predicate():
        if proc.poll() is not None:
            pytest.fail(f"{what}: the batch ended first (code {proc.returncode})"
                        + (f"\n{proc.stderr.read()}" if proc.stderr else ""))
        watch.check()
        time.sleep(0.01)


def finish(proc: subprocess.Popen, what: str) -> tuple[str, str]:
    """Wait for `proc` (started with its output piped) to end and its pipes to close; its stdout and
    stderr. Fails the test when it stalls (`STALL_S`), or when its pipes stay open `STALL_S` after
    it ended: a process it started lives on, holding them."""
    watch = _Watch(proc.pid, what)
    out: dict = {}
    reader = threading.Thread(target=lambda: out.update(zip(("stdout", "stderr"), proc.communicate())), daemon=True)
    reader.start()
    while reader.is_alive() and proc.poll() is None:
        reader.join(0.5)
        watch.check()
    reader.join(STALL_S)
    if reader.is_alive():
        pytest.fail(f"{what}: ended, but its output is still open {STALL_S:g} s later: a process it started lives on")
    return out["stdout"], out["stderr"]
