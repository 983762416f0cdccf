"""The supervisor's own CPU: what watching a baking child's time and memory costs the batch.

    python benchmarks/bench_supervisor.py [--others 300] [--looks 500] [--seconds 10]

Starts `--others` unrelated processes (sleeping) beside a child that has a grandchild, as a bake's
worker has xatlas under it, and measures the CPU time of this process (``time.process_time``):

- per look at the child's tree (its descendants and their resident memory): psutil's
  ``children(recursive=True)`` and ``memory_info`` per process, as the supervisor did until issue
  32, against `asset_process`'s look (`ProcessTree.rss`: the known descendants' memory) and its
  listing (`_Processes.new` and `ProcessTree.adopt`: new descendants among the processes started
  since), each with and without the unrelated processes;
- for a whole `asset_process.supervise` of one asset whose worker sleeps before it bakes, for 1 s
  and for `--seconds`: from the two, what starting and ending a worker costs once, and what
  watching it costs per second, as a share of one core (a look every `POLL_S`, a listing of the
  machine's processes every `LIST_S`).
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import psutil

from sssbake.pipeline.bake.asset_process import (
    LIST_S,
    POLL_S,
    Limits,
    ProcessTree,
    Task,
    _Processes,
    supervise,
    tree_rss,
)
from sssbake.pipeline.bake.batch import Job
from sssbake.pipeline.config import BatchConfig

# A child that starts a grandchild holding 100 MiB, then sleeps: a worker with xatlas under it.
TREE = ("import subprocess, sys, time; subprocess.Popen([sys.executable, '-c', "
        "'import time; a = bytearray(100 * 2**20); time.sleep(3600)']); time.sleep(3600)")


@dataclass(frozen=True)
class SleepingConfig(BatchConfig):
    """A config whose options, asked for in an asset's worker, come after `seconds` of sleep: a
    worker that runs that long, costing the supervisor what a bake does."""

    seconds: float = 0.0

    def options_for(self, rel_path, cli_overrides):
        time.sleep(self.seconds)
        return super().options_for(rel_path, cli_overrides)


def _old_look(pid: int) -> int:
    """The look before issue 32: every process's parent through psutil, then each descendant's memory."""
    try:
        root = psutil.Process(pid)
        tree = [root, *root.children(recursive=True)]
    except psutil.Error:
        return 0
    total = 0
    for proc in tree:
        try:
            total += proc.memory_info().rss
        except psutil.Error:
            pass
    return total


def _cpu_per_look(look, looks: int) -> float:
    """CPU seconds of this process per call of `look`, over `looks` calls."""
    look()
    t0 = time.process_time()
    for _ in range(looks):
        look()
    return (time.process_time() - t0) / looks


def _looks(child: int, looks: int) -> tuple[float, float, float, int, int]:
    """CPU seconds per old look, per new look and per listing; the tree's RSS by the old and the new."""
    processes, tree = _Processes(), ProcessTree(child)
    grandchild = psutil.Process(child).children()[0].pid
    tree.adopt({grandchild: child})  # what the listing after its start found
    old = _cpu_per_look(lambda: _old_look(child), looks)
    new = _cpu_per_look(tree.rss, looks)
    listing = _cpu_per_look(lambda: tree.adopt(processes.new()), looks)
    try:
        return old, new, listing, _old_look(child), tree.rss()
    finally:
        tree.close()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--others", type=int, default=300, help="unrelated processes alive meanwhile (default 300)")
    parser.add_argument("--looks", type=int, default=500, help="looks timed per figure (default 500)")
    parser.add_argument("--seconds", type=float, default=20.0, help="the longer supervised worker's run (default 20)")
    args = parser.parse_args()

    child = subprocess.Popen([sys.executable, "-c", TREE])
    others: list[subprocess.Popen] = []
    try:
        while len(psutil.Process(child.pid).children()) < 1:
            time.sleep(0.05)
        time.sleep(1.0)  # the grandchild's 100 MiB touched
        print(f"a child with one grandchild, CPU of the supervising process per look ({POLL_S:g} s apart) and "
              f"per listing ({LIST_S:g} s apart):")
        for label in ("alone", f"+{args.others} processes"):
            if label != "alone":
                others = [subprocess.Popen(["sleep", "3600"]) for _ in range(args.others)]
            old, new, listing, rss_old, rss_new = _looks(child.pid, args.looks)
            print(f"  {label:>16} ({len(psutil.pids())} on the machine): psutil {old * 1e6:5.0f} us a look "
                  f"({old / POLL_S:5.2%} of a core); now {new * 1e6:3.0f} us a look and {listing * 1e6:3.0f} us a "
                  f"listing ({new / POLL_S + listing / LIST_S:5.2%}); tree RSS {rss_old / 2**20:.0f} MiB, "
                  f"{rss_new / 2**20:.0f} MiB now, {tree_rss(child.pid) / 2**20:.0f} MiB by tree_rss")

        with tempfile.TemporaryDirectory() as folder:
            job = Job(Path(folder) / "nothing.obj", "nothing.obj", Path(folder) / "out" / "nothing")

            def task(seconds: float) -> Task:
                config = SleepingConfig({"scale_mm": 1.0}, (), (), seconds=seconds)
                return Task(job, config, {}, None, Limits(0.0, 16.0))

            supervise([task(0.0)])  # the fork server started and its imports done, as in a batch after its first asset
            runs = []
            for seconds in (1.0, args.seconds):
                t0, cpu0 = time.perf_counter(), time.process_time()
                supervise([task(seconds)])
                runs.append((time.perf_counter() - t0, time.process_time() - cpu0))
        (wall1, cpu1), (wall2, cpu2) = runs
        per_second = (cpu2 - cpu1) / (wall2 - wall1)
        print(f"supervise ({len(psutil.pids())} processes on the machine; a look every {POLL_S:g} s, a listing "
              f"every {LIST_S:g} s): {cpu1 * 1e3:.0f} ms of CPU for a {wall1:.1f} s worker, {cpu2 * 1e3:.0f} ms "
              f"for {wall2:.1f} s: {(cpu1 - per_second * wall1) * 1e3:.0f} ms to start and end one, "
              f"{per_second:.2%} of a core while it runs")
    finally:
        for proc in [child, *others]:
            proc.kill()
        for proc in psutil.Process().children(recursive=True):
            proc.kill()


if __name__ == "__main__":
    main()
