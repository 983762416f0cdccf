"""Per-asset isolation (`asset_process`): an asset over its time or memory limit (its worker's
descendants' memory counted), or whose worker crashes, fails alone with one line while its
neighbour bakes, and leaves nothing behind: no output, no temporary of its outputs or of the stage
cache, no private temporary folder. A stop signal ends the batch the same way for every worker."""

import contextlib
import fcntl
import multiprocessing
import os
import signal
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import psutil
import pytest
import trimesh
from fixtures import FAST_DEFAULTS
from generate import blob
from waiting import until_done, wait_for

from sssbake.exporters.atomic import atomic_path
from sssbake.pipeline.bake.asset_process import Interrupted, signals_held, stop_on_signals, tree_rss
from sssbake.pipeline.bake.batch import LOCK_NAME, run_batch
from sssbake.pipeline.cli import main
from sssbake.pipeline.config import BatchConfig, load_config
from sssbake.pipeline.options import BAKE_DEFAULTS, SUPERVISION


@dataclass(frozen=True)
class HookConfig(BatchConfig):
    """A config that, in an asset's worker process only, misbehaves for the assets named in `hooks`
    (a crash, a hang after writing temporaries, a memory hog) before baking as usual."""

    hooks: tuple[tuple[str, str], ...] = ()

    def options_for(self, rel_path, cli_overrides):
        action = dict(self.hooks).get(rel_path)
        if action is not None and multiprocessing.parent_process() is not None:  # never in the batch's process
            _misbehave(action, self.source)
        return super().options_for(rel_path, cli_overrides)


def _misbehave(action: str, out: str) -> None:
    if action == "segv":
        os.kill(os.getpid(), signal.SIGSEGV)
    elif action == "exit":
        os._exit(3)
    elif action == "hang":
        # what a worker killed mid-write leaves: its output's temporary and a stage cache entry's
        out_dir = Path(out)
        with atomic_path(out_dir / "hang.glb") as tmp:
            tmp.write_bytes(b"half a glb")
            (out_dir / ".sssbake-cache" / "ab").mkdir(parents=True, exist_ok=True)
            (out_dir / ".sssbake-cache" / "ab" / "tmpq1w2e3r4.tmp").write_bytes(b"half an entry")
            time.sleep(120)
    elif action == "hog":
        hog = np.ones(1024**3 // 8)  # 1 GiB, touched
        time.sleep(120 + hog[0])
    elif action == "hog below":  # the memory is a process's it started, as xatlas's is the atlas's
        subprocess.run([sys.executable, "-c", "import time; hog = b'x' * 1024**3; time.sleep(120)"])


def _inputs(folder: Path, *names: str) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    for name in names:
        trimesh.creation.icosphere(subdivisions=2, radius=5.0).export(folder / name)
    return folder


def _hooked(out: Path, hooks: dict) -> HookConfig:
    base = load_config(_write(out.parent / "c.toml", FAST_DEFAULTS))
    return HookConfig(base.defaults, base.assets, base.materials, source=str(out), hooks=tuple(hooks.items()))


def _write(path: Path, text: str) -> Path:
    path.write_text(text)
    return path


@pytest.fixture
def private_tmp(tmp_path, monkeypatch):
    """The supervisor's per-asset temporary folders go here, to be checked for leftovers."""
    folder = tmp_path / "tmp"
    folder.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(folder))
    return folder


def _files(out: Path) -> set[str]:
    return {p.relative_to(out).as_posix() for p in out.rglob("*") if p.is_file()}


def _good(out: Path, stem: str) -> set[str]:
    return {f"{stem}.glb", f"{stem}.usdc", f"{stem}.mtlx", f"{stem}.materials.json", f"{stem}.thickness0.png",
            f"{stem}.report.json"}


@pytest.mark.parametrize("action, message", [
    ("segv", "the worker process baking it died by signal 11 (SIGSEGV), a crash in native code or an interpreter "
             "abort; nothing was written for it"),
    ("exit", "the worker process baking it exited with code 3, a crash in native code or an interpreter abort; "
             "nothing was written for it"),
])
def test_a_crashing_worker_fails_alone(tmp_path, private_tmp, action, message):
    src, out = _inputs(tmp_path / "in", "crash.obj", "good.obj"), tmp_path / "out"
    summary = run_batch([src], out, _hooked(out, {"crash.obj": action}), {}, cache_dir=None, progress=False)
    crash, good = summary["assets"]
    assert crash["status"] == "failed" and crash["outputs"] == [] and crash["error"] == f"{src / 'crash.obj'}: {message}"
    assert good["status"] == "ok" and summary["ok"] == 1 and summary["failed"] == 1
    assert _files(out) == {LOCK_NAME, "batch.json"} | _good(out, "good")
    assert not list(private_tmp.glob("sssbake-asset-*"))


def test_a_hanging_worker_is_killed_and_its_temporaries_removed(tmp_path, private_tmp):
    src, out = _inputs(tmp_path / "in", "hang.obj", "good.obj"), tmp_path / "out"
    config = _hooked(out, {"hang.obj": "hang"})
    rules = ({"glob": "hang.obj", "asset_timeout_s": 3.0},)
    config = HookConfig(config.defaults, rules, (), source=config.source, hooks=config.hooks)
    summary = run_batch([src], out, config, {}, jobs=2, cache_dir=str(out / ".sssbake-cache"), progress=False)
    good, hang = summary["assets"]
    assert hang == {"asset": str(src / "hang.obj"), "outputs": [], "status": "failed", "seconds": hang["seconds"],
                    "error": f"{src / 'hang.obj'}: exceeded 3 s; raise --asset-timeout (or asset_timeout_s in the "
                             "config)"}
    assert 3.0 < hang["seconds"] < 120  # killed, not waited for: it sleeps for 120 s
    assert good["status"] == "ok"
    # the dead worker's output temporary and stage cache temporary are gone, the cache's entries stay
    left = {f for f in _files(out) if not f.startswith(".sssbake-cache/") or "tmp" in f}
    assert left == {LOCK_NAME, "batch.json"} | _good(out, "good")
    assert not list(private_tmp.glob("sssbake-asset-*"))


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM, signal.SIGHUP])
def test_each_stop_signal_raises_interrupted(signum):
    before = signal.getsignal(signum)
    with pytest.raises(Interrupted) as caught, stop_on_signals():
        os.kill(os.getpid(), signum)
        time.sleep(60)  # the handler raises at once
    assert caught.value.signum == signum and caught.value.records is None
    assert str(caught.value) == f"interrupted by {signal.Signals(signum).name} before any asset was baked; nothing " \
                                "was written"
    assert signal.getsignal(signum) == before


def test_a_stop_signal_taken_by_another_thread_waits_for_the_held_block_to_end():
    # blocked in the main thread, a signal goes to another (OpenBLAS's in a batch, this helper here),
    # and Python runs its handler in the main thread at once: it must wait for the block's end
    go, reached = threading.Event(), []
    sender = threading.Thread(target=lambda: go.wait() and os.kill(os.getpid(), signal.SIGTERM))
    sender.start()  # before the block: its mask lets the signal through
    with pytest.raises(Interrupted) as caught, stop_on_signals():
        with signals_held():
            go.set()
            sender.join()
            for _ in range(200):  # bytecode boundaries, where Python runs a handler
                time.sleep(0.001)
            reached.append("the block's end")
        time.sleep(60)  # not reached: the block's end raises
    assert reached == ["the block's end"] and caught.value.signum == signal.SIGTERM
    assert signal.getsignal(signal.SIGTERM) == signal.SIG_DFL


def test_a_stop_signal_ends_the_batch_and_leaves_nothing(tmp_path, private_tmp, capfd):
    # SIGINT, as Ctrl-C sends it to the whole process group, is tested from the command line
    # (test_batch_resume.py); here the batch's own process gets kill's default signal.
    signum = signal.SIGTERM
    src, out = _inputs(tmp_path / "in", "good.obj", "hang.obj"), tmp_path / "out"
    config = _hooked(out, {"hang.obj": "hang"})
    hung = out / ".sssbake-cache" / "ab" / "tmpq1w2e3r4.tmp"  # the hanging worker's, before it sleeps 120 s
    done = threading.Event()

    def send():
        # once the good asset is baked and the other is hung: the batch runs on, its handlers installed
        while not done.is_set():
            if (out / "good.report.json").exists() and hung.exists():
                os.kill(os.getpid(), signum)
                return
            time.sleep(0.01)

    sender = threading.Thread(target=send, daemon=True)
    sender.start()
    try:
        with pytest.raises(Interrupted) as caught, stop_on_signals():
            run_batch([src], out, config, {}, jobs=2, cache_dir=str(out / ".sssbake-cache"), progress=False)
    finally:
        done.set()
        sender.join()
    assert caught.value.signum == signum
    good, hang = caught.value.records
    assert good["status"] == "ok" and hang is None
    assert str(caught.value) == (f"interrupted by {signal.Signals(signum).name}: 1 baked, 0 failed, 1 not baked; "
                                 "run the same command again to bake the rest")
    # the hung worker killed (an asset's worker leads a session of its own), its temporaries gone, no batch.json
    assert [p for p in psutil.Process().children(recursive=True) if os.getsid(p.pid) != os.getsid(0)] == []
    left = {f for f in _files(out) if not f.startswith(".sssbake-cache/") or "tmp" in f}
    assert left == {LOCK_NAME} | _good(out, "good")
    assert not list(private_tmp.glob("sssbake-asset-*"))
    assert "Traceback" not in capfd.readouterr().err


# A batch in a process of its own, with the hook config of this module (and the folders it imports from).
_HERE = Path(__file__).resolve()
BATCH = f"""
import sys
from pathlib import Path
sys.path[:0] = {[str(_HERE.parent), str(_HERE.parents[1]), str(_HERE.parents[2] / "samples")]!r}
from test_batch_isolation import _hooked
from sssbake.pipeline.bake.batch import run_batch
src, out = Path(sys.argv[1]), Path(sys.argv[2])
run_batch([src], out, _hooked(out, {{"hang.obj": "hang"}}), {{}}, cache_dir=str(out / ".sssbake-cache"), progress=False)
"""


def test_a_worker_dies_with_its_batch_killed_outright(tmp_path, private_tmp):
    # as a Dask worker killed under its asset, or a batch the kernel's OOM killer picks: the fork
    # server ends with the batch, and the asset's worker with it, which must not bake on unseen
    src, out = _inputs(tmp_path / "in", "hang.obj"), tmp_path / "out"
    proc = subprocess.Popen([sys.executable, "-c", BATCH, str(src), str(out)],
                            env={**os.environ, "TMPDIR": str(private_tmp)})
    try:
        wait_for((out / ".sssbake-cache" / "ab" / "tmpq1w2e3r4.tmp").exists, proc, "the hanging asset's worker")
        (worker,) = [p for p in psutil.Process(proc.pid).children(recursive=True) if os.getsid(p.pid) == p.pid]
    finally:
        proc.kill()  # the batch alone, not its process group
        proc.wait()
    until_done(worker.wait)
    assert not [f for f in _files(out) if f.startswith("hang.")]  # it died in its sleep: it never baked


def test_a_killed_workers_output_temporaries_go_even_under_another_batch(tmp_path, private_tmp):
    # Another batch holds the folder: the end-of-batch sweep may not run, the supervisor's own cleaning must.
    src, out = _inputs(tmp_path / "in", "hang.obj"), tmp_path / "out"
    out.mkdir()
    rules = ({"glob": "hang.obj", "asset_timeout_s": 2.0},)
    base = _hooked(out, {"hang.obj": "hang"})
    config = HookConfig(base.defaults, rules, (), source=base.source, hooks=base.hooks)
    with open(out / LOCK_NAME, "a+b") as other:
        fcntl.flock(other.fileno(), fcntl.LOCK_SH)
        summary = run_batch([src], out, config, {}, cache_dir=None, progress=False)
    assert summary["failed"] == 1
    assert not [f for f in _files(out) if "hang.glb" in f], _files(out)


@pytest.mark.parametrize("action", ["hog", "hog below"])
def test_a_memory_hog_is_killed_at_its_limit(tmp_path, private_tmp, action):
    src, out = _inputs(tmp_path / "in", "hog.obj", "good.obj"), tmp_path / "out"
    base = _hooked(out, {"hog.obj": action})
    rules = ({"glob": "hog.obj", "asset_memory_gib": 0.75},)
    config = HookConfig(base.defaults, rules, (), source=base.source, hooks=base.hooks)
    summary = run_batch([src], out, config, {}, jobs=2, cache_dir=None, progress=False)
    good, hog = summary["assets"]
    assert hog["status"] == "failed" and hog["outputs"] == []
    head, rss = hog["error"].split(" GiB resident")[0].rsplit("(", 1)
    assert head == f"{src / 'hog.obj'}: exceeded 0.75 GiB of memory "
    assert 0.75 <= float(rss) < 1.5  # what it held when caught: at most the 1 GiB hog and the interpreters
    assert hog["error"].endswith("raise --asset-memory (or asset_memory_gib in the config)")
    assert hog["seconds"] < 120  # caught as it grew: it holds its memory for 120 s
    assert good["status"] == "ok" and _files(out) == {LOCK_NAME, "batch.json"} | _good(out, "good")


def test_a_real_bake_over_its_time_fails_alone_from_the_command_line(tmp_path, capsys, private_tmp):
    src = tmp_path / "in"
    src.mkdir()
    blob(5).export(src / "slow.obj")  # 10k vertices: seconds of real baking
    trimesh.creation.icosphere(subdivisions=2, radius=5.0).export(src / "good.obj")
    # the flag limits every asset; a rule (which beats flags) gives the neighbour room on a busy machine
    config = _write(tmp_path / "c.toml", FAST_DEFAULTS + '[[assets]]\nglob = "good.obj"\nasset_timeout_s = 600\n')
    out = tmp_path / "out"
    code = main(["bake", str(src), "-o", str(out), "--config", str(config), "--asset-timeout", "1", "-q",
                 "--jobs", "2", "--no-cache"])
    err = capsys.readouterr().err.splitlines()
    assert code == 1
    assert err[0] == f"error: {src / 'slow.obj'}: exceeded 1 s; raise --asset-timeout (or asset_timeout_s in the config)"
    assert len(err) == 2 and err[1].startswith("1 baked, 1 failed")
    assert _files(out) == {LOCK_NAME, "batch.json"} | _good(out, "good")


def test_limits_are_options_outside_the_job_key(tmp_path):
    from sssbake.pipeline.bake.asset import job_key

    assert BAKE_DEFAULTS.asset_timeout_s > 0 and BAKE_DEFAULTS.asset_memory_gib > 0
    changed = BAKE_DEFAULTS.merged({"asset_timeout_s": 5.0, "asset_memory_gib": 0.0})
    assert job_key("d" * 64, changed) == job_key("d" * 64, BAKE_DEFAULTS)
    assert not set(SUPERVISION) & set(BAKE_DEFAULTS.to_json())
    for bad in ("-1", "inf", "nan"):
        with pytest.raises(ValueError, match="asset_timeout_s must be a finite number >= 0"):
            BatchConfig({"asset_timeout_s": float(bad)}, (), ()).options_for("a.obj", {})
    with pytest.raises(ValueError, match="asset_memory_gib must be a number, got True"):
        BatchConfig({"asset_memory_gib": True}, (), ()).options_for("a.obj", {})


def test_tree_rss_counts_the_descendants(tmp_path):
    # a child that starts a grandchild holding 320 MiB, which says when it is; both then sleep
    hog = "import time; a = b'x' * 320 * 2**20; print(flush=True); time.sleep(600)"
    code = f"import subprocess, sys, time; subprocess.Popen([sys.executable, '-c', {hog!r}]); time.sleep(600)"
    # in a group of its own, which the grandchild joins: killing the group kills both
    child = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True, start_new_session=True)
    try:
        child.stdout.readline()  # the grandchild's memory is touched
        (grandchild,) = psutil.Process(child.pid).children()
        assert tree_rss(child.pid) > tree_rss(grandchild.pid) >= 320 * 2**20
        # this process's own (pytest and the pipeline: well over 50 MiB) and its descendants', together
        assert tree_rss(os.getpid()) > tree_rss(child.pid) + 50 * 2**20
    finally:
        os.killpg(child.pid, signal.SIGKILL)
        child.wait()
    assert tree_rss(child.pid) == 0


def test_a_killed_childs_descendants_are_waited_for_until_they_have_exited(monkeypatch):
    from sssbake.pipeline.bake import asset_process

    # a child with a grandchild in its group, unknown to the caller (as one started since the last
    # listing); the child is reaped here, the grandchild is not this process's to reap
    code = ("import subprocess, sys, time; "
            "subprocess.Popen([sys.executable, '-c', 'import time; print(flush=True); time.sleep(600)']); "
            "time.sleep(600)")
    child = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True, start_new_session=True)
    try:
        child.stdout.readline()
        (grandchild,) = psutil.Process(child.pid).children()
        monkeypatch.setattr(asset_process, "EXIT_WAIT_S", 0.5)
        t0 = time.monotonic()
        asset_process._wait_exited(child.pid, set())  # nothing killed: it waits its whole limit
        assert time.monotonic() - t0 >= 0.5
        assert grandchild.is_running() and grandchild.status() != psutil.STATUS_ZOMBIE
        monkeypatch.setattr(asset_process, "EXIT_WAIT_S", 600.0)
        os.killpg(child.pid, signal.SIGKILL)
        child.wait()
        asset_process._wait_exited(child.pid, set())
        # what `clean` removes next cannot be written to again by it
        assert not grandchild.is_running() or grandchild.status() == psutil.STATUS_ZOMBIE
    finally:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(child.pid, signal.SIGKILL)
        child.wait()


def test_isolate_false_bakes_in_this_process(tmp_path, monkeypatch):
    # what a test that patches the pipeline relies on: the patch is seen, no child is started
    from sssbake.pipeline.bake import asset as bake

    def patched(path, *_args, **_kwargs):
        raise ValueError(f"patched in process {os.getpid()}")

    monkeypatch.setattr(bake, "bake_asset", patched)
    src = _inputs(tmp_path / "in", "a.obj")
    summary = run_batch([src], tmp_path / "out", BatchConfig({"scale_mm": 1.0}, (), ()), {}, cache_dir=None,
                        progress=False, isolate=False)
    assert summary["assets"][0]["error"] == f"{src / 'a.obj'}: patched in process {os.getpid()}"


def test_folders_of_a_dead_supervisor_are_swept_and_a_live_ones_kept(private_tmp):
    from sssbake.pipeline.bake.asset_process import FOLDER_PREFIX, supervise, sweep_orphaned_folders

    ended = multiprocessing.get_context("spawn").Process(target=time.sleep, args=(0,))
    ended.start()
    ended.join()  # a pid nothing holds now: a supervisor killed outright
    dead = private_tmp / f"{FOLDER_PREFIX}{ended.pid}-abc123"
    live = private_tmp / f"{FOLDER_PREFIX}{os.getpid()}-def456"
    for folder in (dead, live):
        (folder / "sssbake-atlas-x").mkdir(parents=True)
        (folder / "record.json").write_text("{}")
    lookalike = private_tmp / "sssbake-assets-not-ours"
    lookalike.mkdir()
    assert supervise([]) == []  # every supervisor sweeps first
    assert not dead.exists() and live.exists() and lookalike.exists()
    assert sweep_orphaned_folders() == 0
