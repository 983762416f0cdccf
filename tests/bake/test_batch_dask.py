"""The Dask backend (`--dask`): outputs byte-identical to the local pool's, a bad asset failing
alone, a worker killed mid-asset retried (its asset's child dying with it), an asset that kills
every worker a failed record, nothing left running once a batch ends. Every wait is on the
batch's progress (`waiting`), not on a time a quiet machine needs."""

import json
import logging
import os
import signal
import threading
import time
from pathlib import Path

import distributed  # a dependency: never skipped
import psutil
import pytest
import trimesh
from fixtures import FAST_DEFAULTS
from generate import blob, candle_scene
from waiting import until_done

from sssbake.exporters.gltf import write_glb
from sssbake.pipeline.bake.batch import find_assets, run_batch
from sssbake.pipeline.bake.batch_dask import ALLOWED_FAILURES
from sssbake.pipeline.cli import main
from sssbake.pipeline.config import load_config
from sssbake.pipeline.mesh.baked import BakedAsset

CONFIG = FAST_DEFAULTS + """
[[assets]]
glob = "candle.glb"
scale_mm = 1000.0

[materials]
"Wax*" = "skin1"
"Brass" = "opaque"
"""


@pytest.fixture(scope="module")
def cluster():
    from distributed import LocalCluster

    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1", dashboard_address=None,
                      scheduler_kwargs={"allowed_failures": ALLOWED_FAILURES}, silence_logs=logging.ERROR) as c:
        yield c


@pytest.fixture(scope="module")
def config(tmp_path_factory):
    path = tmp_path_factory.mktemp("config") / "sssbake.toml"
    path.write_text(CONFIG)
    return load_config(path)


def _small_assets(folder: Path) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    trimesh.creation.icosphere(subdivisions=3, radius=10.0).export(folder / "sphere.obj")
    trimesh.creation.torus(major_radius=12.0, minor_radius=4.0, major_sections=32, minor_sections=16).export(
        folder / "torus.ply")
    return folder


def _slow_asset(path: Path) -> Path:
    """A 10k-vertex blob: a few seconds of baking, long enough to be killed in the middle."""
    blob(5).export(path)
    return path


def _executed(client) -> int:
    return sum(client.run(lambda dask_worker: dask_worker.state.executed_count).values())


def test_dask_outputs_match_the_local_pool(cluster, config, tmp_path):
    src = _small_assets(tmp_path / "in")
    write_glb(BakedAsset(candle_scene()), src / "candle.glb")  # two meshes, a translucent and an opaque material
    local = run_batch([src], tmp_path / "local", config, {}, jobs=1, cache_dir=str(tmp_path / "local-cache"),
                      progress=False)
    with distributed.Client(cluster, set_as_default=False) as client:
        before = _executed(client)
        remote = until_done(run_batch, [src], tmp_path / "dask", config, {},
                            cache_dir=str(tmp_path / "dask-cache"), progress=False, dask=cluster.scheduler_address)
        # every asset ran as a task on the workers, not in this process
        assert _executed(client) - before == 3
    assert remote["ok"] == local["ok"] == 3 and remote["failed"] == 0
    assert [(r["asset"], r["status"], r["warnings"]) for r in remote["assets"]] == \
        [(r["asset"], r["status"], r["warnings"]) for r in local["assets"]]
    assert json.loads((tmp_path / "dask" / "batch.json").read_text())["assets"] == remote["assets"]
    for name in ("sphere", "torus", "candle"):
        for suffix in (".glb", ".usdc"):
            ours, theirs = tmp_path / "dask" / f"{name}{suffix}", tmp_path / "local" / f"{name}{suffix}"
            assert ours.read_bytes() == theirs.read_bytes(), ours
        report = json.loads((tmp_path / "dask" / f"{name}.report.json").read_text())
        assert report["validation"]["gltf"]["errors"] == report["validation"]["usd"]["errors"] == 0
    # the workers filled the cache folder the client named
    assert any((tmp_path / "dask-cache").rglob("*.entry"))


def test_an_asset_this_batch_baked_is_ok_even_when_a_rerun_finds_it_up_to_date(cluster, config, tmp_path):
    # A task whose worker dies after it finished, before the client has its result, runs again and
    # finds its own outputs: still "ok". Outputs from before the batch are "up-to-date".
    from sssbake.pipeline.bake.batch_dask import run_on_dask

    src, out = _small_assets(tmp_path / "in"), tmp_path / "out"
    out.mkdir()
    (out / "clock").touch()
    before = (out / "clock").stat().st_mtime  # the filesystem's clock, as run_batch reads it
    run_batch([src], out, config, {}, cache_dir=None, progress=False)
    jobs = find_assets([src], out)
    redone = until_done(run_on_dask, jobs, config, {}, None, cluster.scheduler_address, since=before)
    assert [r["status"] for r in redone] == ["ok", "ok"]
    later = run_batch([src], out, config, {}, cache_dir=None, progress=False, dask=cluster.scheduler_address)
    assert [r["status"] for r in later["assets"]] == ["up-to-date", "up-to-date"]


def test_bad_asset_fails_alone_on_a_local_cluster(cluster, tmp_path, monkeypatch, capfd):
    # Relative paths, as a user types them: the workers get absolute ones, the records keep these.
    monkeypatch.chdir(tmp_path)
    src = _small_assets(Path("in"))
    (src / "broken.obj").write_text("f 1 2 3\n")  # a face, no vertices
    Path("sssbake.toml").write_text(CONFIG)
    common = ["bake", "in", "--config", "sssbake.toml", "-q"]
    assert main(common + ["-o", "local"]) == 1
    capfd.readouterr()
    before = {p.pid for p in psutil.Process().children(recursive=True)}  # the module's cluster and fork server
    assert until_done(main, common + ["-o", "dask", "--dask", "local:2"]) == 1
    # Nothing of its cluster outlives the batch to keep the command from exiting (the interpreter
    # waits for worker processes that are not daemonic, and for threads that are not) or to hold its
    # output open
    assert [p for p in psutil.Process().children(recursive=True) if p.pid not in before] == []
    assert [t.name for t in threading.enumerate() if not t.daemon] == ["MainThread"]
    err = capfd.readouterr().err
    assert "Traceback" not in err
    err = [line for line in err.splitlines() if line.startswith("error:")]
    local = json.loads(Path("local/batch.json").read_text())["assets"]
    remote = json.loads(Path("dask/batch.json").read_text())["assets"]
    assert [(r["asset"], r["status"]) for r in remote] == [
        ("in/broken.obj", "failed"), ("in/sphere.obj", "ok"), ("in/torus.ply", "ok")]
    # the same one-line error as the local pool's, naming the file as it was given
    assert remote[0]["error"] == local[0]["error"] and remote[0]["error"].startswith("in/broken.obj: ")
    assert "\n" not in remote[0]["error"]
    assert err == [f"error: {remote[0]['error']}"]
    assert Path("dask/sphere.glb").read_bytes() == Path("local/sphere.glb").read_bytes()


def test_dask_flag_errors_are_one_line(tmp_path, capsys):
    import dask

    src = _small_assets(tmp_path / "in")
    base = ["bake", str(src), "-o", str(tmp_path / "out"), "--scale-mm", "1", "-q"]
    assert main(base + ["--dask", "local:2", "--jobs", "2"]) == 2
    assert "--jobs or --dask" in capsys.readouterr().err
    assert main(base + ["--dask", "local:0"]) == 2
    assert "local:N, N >= 1" in capsys.readouterr().err
    with dask.config.set({"distributed.comm.timeouts.connect": "1s"}):
        assert until_done(main, base + ["--dask", "tcp://127.0.0.1:9"]) == 2  # nothing listens on port 9
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert line.startswith("error: --dask tcp://127.0.0.1:9: cannot reach the Dask scheduler")


class _Killer(threading.Thread):
    """SIGKILLs the worker process executing the batch's task `index`, at most `times` times; then
    notes the worker processes seen executing it again. Also notes the most tasks of the batch the
    scheduler had out on workers at once, and for each process of an asset (an asset's child, in a
    session of its own, and what it started) under a killed worker, whether `report` existed by the
    time it was gone.

    Reads the in-process LocalCluster's own state (the scheduler's view of each worker, which its
    heartbeats refresh twice a second, and the nannies' worker pids): a call to the workers could
    wait on a dead one for the connect timeout and miss what happens meanwhile.
    """

    def __init__(self, cluster, index: int, times: int, report: Path):
        super().__init__(daemon=True)
        self.cluster, self.index, self.times, self.report = cluster, index, times, report
        self.killed: list[int] = []
        self.seen_after: list[int] = []
        self.most_out = 0
        self.orphans: dict[int, bool | None] = {}  # pid -> whether the report existed when it was gone
        self.stop = threading.Event()

    def run(self):
        def ours(key) -> bool:
            return isinstance(key, tuple) and key[0].startswith("sssbake-bake-")

        scheduler = self.cluster.scheduler
        while not self.stop.is_set():
            pids = {n.worker_address: n.pid for n in list(self.cluster.workers.values()) if n.pid}
            workers = list(scheduler.workers.items())
            self.most_out = max(self.most_out, sum(ours(ts.key) for _, ws in workers for ts in list(ws.processing)))
            for address, ws in workers:
                pid = pids.get(address)
                # executing by the last heartbeat, and not finished since
                if pid is None or pid in self.killed or not any(
                        ours(ts.key) and ts.key[1] == self.index and ts.state == "processing"
                        and ts.processing_on is ws for ts in list(ws.executing)):
                    continue
                if len(self.killed) < self.times:
                    try:
                        under = [p.pid for p in psutil.Process(pid).children(recursive=True)
                                 if _session(p.pid) not in (os.getsid(0), None)]
                    except psutil.NoSuchProcess:
                        continue
                    if not under:  # its asset's child not started yet: killed mid-bake, the worker leaves one
                        continue
                    os.kill(pid, signal.SIGKILL)
                    self.killed.append(pid)
                    self.orphans.update(dict.fromkeys(under))
                elif pid not in self.seen_after:
                    self.seen_after.append(pid)
            for orphan in [p for p, report in self.orphans.items() if report is None and _gone(p)]:
                self.orphans[orphan] = self.report.exists()
            time.sleep(0.02)


def _session(pid: int) -> int | None:
    try:
        return os.getsid(pid)
    except ProcessLookupError:
        return None


def _gone(pid: int) -> bool:
    """Whether process `pid` has ended (a zombie not yet reaped by its parent has)."""
    try:
        return psutil.Process(pid).status() == psutil.STATUS_ZOMBIE
    except psutil.NoSuchProcess:
        return True


def _bake_with_killer(cluster, config, src: Path, out: Path, victim: str, times: int):
    index = [j.rel for j in find_assets([src], out)].index(victim)
    killer = _Killer(cluster, index, times, out / Path(victim).with_suffix(".report.json"))
    killer.start()
    try:
        summary = until_done(run_batch, [src], out, config, {}, cache_dir=str(out / ".sssbake-cache"),
                             progress=False, dask=cluster.scheduler_address)
    finally:
        killer.stop.set()
        killer.join()
    return summary, killer


def test_worker_killed_mid_asset_is_retried(cluster, config, tmp_path, capfd):
    src = _small_assets(tmp_path / "in")
    _slow_asset(src / "slow.obj")
    summary, killer = _bake_with_killer(cluster, config, src, tmp_path / "out", "slow.obj", times=1)
    assert len(killer.killed) == 1 and _gone(killer.killed[0]), (killer.killed, summary)
    assert killer.seen_after, "the killed worker's asset never ran again"
    # Its asset's child died with it, before the asset's retry was done: it did not bake on unseen,
    # racing the retry for the same outputs, holding the batch's output open and failing on the
    # folder the retry's supervisor swept.
    assert killer.orphans and set(killer.orphans.values()) == {False}, killer.orphans
    assert "Traceback" not in capfd.readouterr().err
    # never more assets out than worker threads: a death costs only the asset that was running
    assert 1 <= killer.most_out <= 2
    assert [(Path(r["asset"]).name, r["status"]) for r in summary["assets"]] == [
        ("slow.obj", "ok"), ("sphere.obj", "ok"), ("torus.ply", "ok")]
    report = json.loads((tmp_path / "out" / "slow.report.json").read_text())
    assert report["validation"]["gltf"]["errors"] == 0 and (tmp_path / "out" / "slow.usdc").stat().st_size > 0


def test_asset_that_kills_every_worker_fails_alone(cluster, config, tmp_path):
    src = _small_assets(tmp_path / "in")
    _slow_asset(src / "crash.obj")
    summary, killer = _bake_with_killer(cluster, config, src, tmp_path / "out", "crash.obj", times=100)
    # the scheduler gives up after allowed-failures + 1 dead workers, not at the killer's limit
    assert len(killer.killed) == ALLOWED_FAILURES + 1 and not killer.seen_after, (killer.killed, summary)
    assert 1 <= killer.most_out <= 2  # so no innocent asset was queued on a worker it killed
    crash, *rest = summary["assets"]
    assert [r["status"] for r in rest] == ["ok", "ok"], summary
    assert crash["status"] == "failed" and crash["outputs"] == []
    assert crash["error"] == (f"{src / 'crash.obj'}: {ALLOWED_FAILURES + 1} Dask workers died while baking it "
                              "(killed, out of memory or a crash in native code); the workers' logs say which")
    assert [r["status"] for r in rest] == ["ok", "ok"] and summary["failed"] == 1
    assert not (tmp_path / "out" / "crash.glb").exists()


def test_dask_applies_the_asset_limits(cluster, config, tmp_path):
    # each task supervises its asset in a child process, as the local batch does: over its time the
    # asset fails alone and the worker lives on
    from dataclasses import replace

    src = _small_assets(tmp_path / "in")
    _slow_asset(src / "slow.obj")
    limited = replace(config, assets=config.assets + ({"glob": "slow.obj", "asset_timeout_s": 1.0},))
    out = tmp_path / "out"
    workers = {n.pid for n in cluster.workers.values()}
    summary = until_done(run_batch, [src], out, limited, {}, cache_dir=None, progress=False,
                         dask=cluster.scheduler_address)
    slow, *rest = summary["assets"]
    assert slow["status"] == "failed" and slow["outputs"] == []
    assert slow["error"] == f"{src / 'slow.obj'}: exceeded 1 s; raise --asset-timeout (or asset_timeout_s in the config)"
    assert [r["status"] for r in rest] == ["ok", "ok"]
    assert {n.pid for n in cluster.workers.values()} == workers  # no worker died for it
    assert not [p for p in out.rglob("*") if p.name.startswith(("slow", ".slow"))]
