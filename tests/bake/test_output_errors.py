"""Output problems give one line each and a non-zero exit, and leave nothing behind: `-o` naming a
file, a read-only output folder, a full disk (a tiny tmpfs, mounted in a private mount namespace);
a failed asset leaves no outputs, a failed rebake the old ones (`bake.staging`); the stage cache's
folder read-only or full."""

import dataclasses
import errno
import fcntl
import json
import multiprocessing
import os
import re
import shutil
import subprocess
import time
from pathlib import Path

import pytest
import trimesh
from fixtures import FAST_DEFAULTS
from generate import blob
from gltf_corpus import GltfBuilder, _material, _mesh, box24, uv_sphere

from sssbake.exporters.atomic import is_temporary
from sssbake.exporters.usd import write_usdc
from sssbake.pipeline.bake import asset as asset_module
from sssbake.pipeline.bake.asset import bake_asset
from sssbake.pipeline.bake.batch import LOCK_NAME, run_batch, sweep_temporaries
from sssbake.pipeline.bake.cache import StageCache
from sssbake.pipeline.bake.staging import commit, is_staging, staging
from sssbake.pipeline.cli import main
from sssbake.pipeline.config import BatchConfig, load_config
from sssbake.pipeline.mesh.load import load_scene
from sssbake.pipeline.options import BakeOptions


def _inputs(folder: Path) -> Path:
    folder.mkdir(parents=True)
    blob(5).export(folder / "big.obj")  # outputs of ~2 MB
    trimesh.creation.icosphere(subdivisions=1, radius=5.0).export(folder / "small.obj")  # ~20 kB
    return folder


def _in_namespace(tmp_path: Path, mount: str, bake: list[str],
                  listed: Path | None = None) -> subprocess.CompletedProcess:
    """Run `mount` then the bake in a private mount namespace; skips where none can be made. The
    script lists the files of `listed` (default OUT) from inside, where the mount is seen."""
    if shutil.which("unshare") is None:
        pytest.skip("no unshare(1)")
    probe = subprocess.run(["unshare", "-m", "sh", "-c", f"mount -t tmpfs -o size=16k tmpfs {tmp_path}"],
                           capture_output=True)
    if probe.returncode != 0:
        pytest.skip(f"no private mount namespace here ({probe.stderr.decode().strip()})")
    listed = listed or bake[bake.index("-o") + 1]
    script = f"{mount} && sssbake {' '.join(bake)}; echo rc=$?; cd {listed} && find . -type f"
    return subprocess.run(["unshare", "-m", "sh", "-c", script], capture_output=True, text=True, timeout=300)


def test_out_naming_a_file(tmp_path, capsys):
    src = _inputs(tmp_path / "in")
    (tmp_path / "out").write_text("mine")
    assert main(["bake", str(src), "-o", str(tmp_path / "out"), "--scale-mm", "1", "-q"]) == 2
    assert capsys.readouterr().err.splitlines() == [f"error: {tmp_path / 'out'}: is a file, not a folder; give -o a folder"]
    assert (tmp_path / "out").read_text() == "mine" and sorted(p.name for p in tmp_path.iterdir()) == ["in", "out"]


def test_out_below_a_file(tmp_path, capsys):
    src = _inputs(tmp_path / "in")
    (tmp_path / "file").write_text("mine")
    assert main(["bake", str(src), "-o", str(tmp_path / "file" / "out"), "--scale-mm", "1", "-q"]) == 2
    assert capsys.readouterr().err.splitlines() == [
        f"error: {tmp_path / 'file' / 'out'}: a file is in the way of this folder; give -o a folder"]


def test_read_only_output_folder(tmp_path):
    src, out = _inputs(tmp_path / "in"), tmp_path / "out"
    out.mkdir()
    (out / "keep.txt").write_text("mine")
    config = tmp_path / "c.toml"
    config.write_text(FAST_DEFAULTS)
    run = _in_namespace(tmp_path, f"mount --bind {out} {out} && mount -o remount,bind,ro {out}",
                        ["bake", str(src), "-o", str(out), "--config", str(config), "-q"])
    assert run.stderr.splitlines() == [
        f"error: {out}: {out / '.sssbake.lock'}: Read-only file system; give -o a folder you may write"]
    lines = run.stdout.splitlines()
    assert lines[0] == "rc=2" and lines[1:] == ["./keep.txt"]


def test_full_disk_fails_the_assets_that_do_not_fit_and_leaves_no_part(tmp_path):
    src, out = _inputs(tmp_path / "in"), tmp_path / "out"
    out.mkdir()
    config = tmp_path / "c.toml"
    config.write_text(FAST_DEFAULTS)
    run = _in_namespace(tmp_path, f"mount -t tmpfs -o size=400k tmpfs {out}",
                        ["bake", str(src), "-o", str(out), "--config", str(config), "-q", "--no-cache"])
    err = run.stderr.splitlines()
    assert err[0] == f"error: {src / 'big.obj'}: No space left on device; free some space or give -o a folder on another disk"
    assert len(err) == 2 and err[1].startswith("1 baked, 1 failed")
    lines = run.stdout.splitlines()
    assert lines[0] == "rc=1"
    assert sorted(lines[1:]) == ["./.sssbake.lock", "./batch.json", "./small.glb", "./small.materials.json",
                                 "./small.mtlx", "./small.report.json", "./small.thickness0.png", "./small.usdc"]


# --- all or nothing: a failed asset leaves no outputs, a failed rebake leaves the old ones ---------------


def _flat_gltf(folder: Path, name: str, with_box: bool) -> Path:
    """A .glb whose ball (its first mesh) hangs under a node of scale 0, then, when `with_box`, a box
    at scale 1 (its second mesh, its last node: both renumbered when the ball goes)."""
    b = GltfBuilder()
    _material(b)
    _mesh(b, uv_sphere())
    b.doc["meshes"][0]["name"] = "Ball"
    nodes = [{"name": "Flat", "children": [1], "scale": [0.0, 0.0, 0.0]},
             {"name": "Under", "mesh": 0, "translation": [2.0, 0.0, 0.0]}]
    if with_box:
        _mesh(b, box24())
        nodes.append({"name": "Box", "mesh": 1})
    b.doc["nodes"] = nodes
    b.doc["scenes"], b.doc["scene"] = [{"nodes": [0] + ([2] if with_box else [])}], 0
    path = folder / name
    path.write_bytes(b.glb())
    return path


def _left_behind(out: Path) -> list[str]:
    """Temporaries and staging folders anywhere under `out`."""
    return [str(p) for p in out.rglob("*") if is_temporary(p.name) or is_staging(p.name)]


def test_a_node_of_scale_0_is_left_out_and_an_asset_of_nothing_else_fails_alone(tmp_path, capsys):
    src = tmp_path / "in"
    src.mkdir()
    trimesh.creation.icosphere(subdivisions=1, radius=5.0).export(src / "good.obj")
    _flat_gltf(src, "half.glb", with_box=True)
    flat = _flat_gltf(src, "flat.glb", with_box=False)
    config = tmp_path / "c.toml"
    config.write_text(FAST_DEFAULTS + 'profile = "dipole"\n')  # the dipole: no escape-gain walk, a cheap bake
    out = tmp_path / "out"
    assert main(["bake", str(src), "-o", str(out), "--config", str(config), "-q", "--no-cache"]) == 1
    err = capsys.readouterr().err.splitlines()
    assert err[0] == (f"error: {flat}: every mesh is placed by a node of scale 0 (a singular transform): nothing has "
                      "volume to bake")
    assert len(err) == 2 and err[1].startswith("2 baked, 1 failed")
    assert sorted(p.name for p in out.iterdir()) == [".sssbake.lock", "batch.json", "good.glb",
                                                      "good.materials.json", "good.mtlx", "good.report.json",
                                                      "good.thickness0.png", "good.usdc", "half.glb",
                                                      "half.materials.json", "half.mtlx", "half.report.json",
                                                      "half.thickness0.png", "half.usdc"]
    assert not _left_behind(out)
    report = json.loads((out / "half.report.json").read_text())
    assert report["warnings"][:2] == ["node 'Flat' has scale 0 (a singular transform): what it places has no volume; "
                                      "left out with the 1 nodes below it",
                                      "mesh 'Ball' is placed only by nodes of scale 0; left out"]
    assert [m.name for m in load_scene(out / "half.glb").meshes] == ["Box"]
    assert report["validation"]["gltf"]["errors"] == 0


@pytest.fixture(scope="module")
def baked(tmp_path_factory):
    """A small sphere, a stage cache holding its stages and a folder of its complete outputs."""
    root = tmp_path_factory.mktemp("baked")
    trimesh.creation.icosphere(subdivisions=1, radius=5.0).export(root / "ball.obj")
    (root / "old").mkdir()
    bake_asset(root / "ball.obj", CHEAP, root / "old" / "ball", StageCache(root / "cache"))
    return root


CHEAP = BakeOptions(material="marble", scale_mm=1.0, techniques=(), atlas_resolution=64, profile="dipole",
                    validate=False)


def _files(folder: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in folder.iterdir()}


def _rebake_failing(baked: Path, tmp_path: Path, monkeypatch, where: str, failure) -> tuple[dict, dict, str]:
    """Bake the ball into a fresh folder and over its old outputs (with other options, so not up to
    date) with `failure` monkeypatched in as `asset.<where>`; the folders' files before and after and
    the error's message."""
    shutil.copytree(baked / "old", tmp_path / "old")
    (tmp_path / "fresh").mkdir()
    monkeypatch.setattr(asset_module, where, failure)
    before = _files(tmp_path / "old")
    messages = []
    for folder in ("fresh", "old"):
        with pytest.raises(Exception) as raised:
            bake_asset(baked / "ball.obj", CHEAP.merged({"atlas_padding": 6}), tmp_path / folder / "ball",
                       StageCache(baked / "cache"))
        messages.append(str(raised.value))
    assert messages[0] == messages[1]
    return before, _files(tmp_path / "old"), messages[0]


def test_a_failure_in_the_last_exporter_leaves_nothing_and_the_old_outputs_as_they_were(baked, tmp_path, monkeypatch):
    def usdc_then_full(asset, path, materialx):
        # the .glb, the .mtlx, the .usdc and its texture all written (the engines' materials come after): then
        # the disk is full
        write_usdc(asset, path, materialx)
        assert {p.name for p in Path(path).parent.iterdir()} == {"ball.glb", "ball.mtlx", "ball.usdc",
                                                                 "ball.thickness0.png"}
        raise OSError(errno.ENOSPC, "No space left on device")

    before, after, message = _rebake_failing(baked, tmp_path, monkeypatch, "write_usdc", usdc_then_full)
    assert message == "[Errno 28] No space left on device"
    assert not list((tmp_path / "fresh").iterdir())
    assert after == before and set(before) == {"ball.glb", "ball.mtlx", "ball.materials.json", "ball.usdc",
                                                 "ball.thickness0.png", "ball.report.json"}


def test_outputs_with_validation_errors_fail_the_bake_and_are_not_left(baked, tmp_path, monkeypatch):
    def invalid(runner, glbs, usdc, options, warnings, source=None, copied_images=0):
        assert glbs["gltf"].is_file() and usdc.is_file()  # validated where staged, before anything moves
        return {"gltf": {"errors": 1, "warnings": 0, "messages": [
            {"code": "NODE_MATRIX_NON_TRS", "severity": "Error", "pointer": "/nodes/1/matrix",
             "message": "Matrix must be decomposable to TRS.", "inherited": False}]}}

    before, after, message = _rebake_failing(baked, tmp_path, monkeypatch, "_validate", invalid)
    assert message == (f"{baked / 'ball.obj'}: exported files are invalid (gltf: 1 error(s), first NODE_MATRIX_NON_TRS "
                       "at /nodes/1/matrix: Matrix must be decomposable to TRS.)")
    assert not list((tmp_path / "fresh").iterdir()) and after == before


def test_a_move_that_fails_takes_back_those_made(tmp_path, monkeypatch):
    staged, folder = tmp_path / "staged", tmp_path / "out"
    staged.mkdir(), folder.mkdir()
    for name in ("a.glb", "a.usdc", "a.report.json"):
        (staged / name).write_text(name)
    real = os.replace

    def replace(src, dst):
        if Path(dst).name == "a.report.json":
            raise OSError(errno.EIO, "Input/output error")
        real(src, dst)

    monkeypatch.setattr(os, "replace", replace)
    with pytest.raises(OSError):
        commit(staged, ["a.glb", "a.usdc", "a.report.json"], folder)
    assert not list(folder.iterdir())


def test_a_killed_bakes_staging_folder_is_swept(tmp_path):
    out = tmp_path / "out"
    (out / "sub" / ".sssbake-staging.abcd1234").mkdir(parents=True)
    (out / "sub" / ".sssbake-staging.abcd1234" / "a.glb").write_text("half")
    (out / ".sssbake-staging.notmine").mkdir()  # not the name staging makes: someone else's
    assert sweep_temporaries(out, None, time.time() + 1) == 1
    assert sorted(str(p.relative_to(out)) for p in out.rglob("*")) == [".sssbake-staging.notmine", "sub"]


# --- the stage cache's folder: its messages name it and its fix ---------------------------------------


def test_read_only_cache_folder(tmp_path):
    src, out, cache = _inputs(tmp_path / "in"), tmp_path / "out", tmp_path / "cache"
    cache.mkdir()
    config = tmp_path / "c.toml"
    config.write_text(FAST_DEFAULTS)
    run = _in_namespace(tmp_path, f"mount --bind {cache} {cache} && mount -o remount,bind,ro {cache}",
                        ["bake", str(src), "-o", str(out), "--config", str(config), "-q", "--cache-dir", str(cache)])
    assert run.stderr.splitlines() == [f"error: {cache}: {cache / '.sssbake.lock'}: Read-only file system; give "
                                       "--cache-dir a folder you may write, or --no-cache"]
    lines = run.stdout.splitlines()
    assert lines[0] == "rc=2" and lines[1:] == ["./.sssbake.lock"]


def test_a_full_cache_folder_is_warned_of_and_the_bake_goes_on_without_it(tmp_path):
    src, out, cache = _inputs(tmp_path / "in"), tmp_path / "out", tmp_path / "cache"
    (src / "big.obj").unlink()
    cache.mkdir()
    config = tmp_path / "c.toml"
    config.write_text(FAST_DEFAULTS + 'profile = "dipole"\n')
    run = _in_namespace(tmp_path, f"mount -t tmpfs -o size=16k tmpfs {cache}",
                        ["bake", str(src), "-o", str(out), "--config", str(config), "-q", "--cache-dir", str(cache)],
                        listed=cache)
    lines = run.stdout.splitlines()
    assert lines[0] == "rc=0" and "./.sssbake.lock" in lines[1:], run.stderr
    assert not [name for name in lines[1:] if name.endswith(".tmp")]  # the entry that did not fit: no half of it
    report = json.loads((out / "small.report.json").read_text())
    full = [w for w in report["warnings"] if w.startswith("stage cache:")]
    assert len(full) == 1 and re.fullmatch(
        rf"stage cache: \w+ and the stages after it not stored: {re.escape(str(cache))}: No space left on device; "
        r"free some space or give --cache-dir a folder on another disk, or --no-cache", full[0]), full
    assert sorted(p.name for p in out.iterdir() if not p.name.startswith(".")) == [
        "batch.json", "small.glb", "small.materials.json", "small.mtlx", "small.report.json",
        "small.thickness0.png", "small.usdc"]


@dataclasses.dataclass(frozen=True)
class StagingHang(BatchConfig):
    """A config that, in an asset's worker process only, leaves what a bake killed while writing its
    outputs leaves (its staging folder with half an output in it), and hangs there."""

    def options_for(self, rel_path, cli_overrides):
        if multiprocessing.parent_process() is not None:  # never in the batch's process
            with staging(Path(self.source)) as staged:
                (staged / "hang.glb").write_bytes(b"half a glb")
                time.sleep(120)
        return super().options_for(rel_path, cli_overrides)


def test_a_killed_bakes_staging_folder_goes_with_it_even_under_another_batch(tmp_path):
    src, out = tmp_path / "in", tmp_path / "out"
    src.mkdir(), out.mkdir()
    trimesh.creation.icosphere(subdivisions=1, radius=5.0).export(src / "hang.obj")
    (tmp_path / "c.toml").write_text(FAST_DEFAULTS)
    base = load_config(tmp_path / "c.toml")
    config = StagingHang(base.defaults, ({"glob": "hang.obj", "asset_timeout_s": 2.0},), (), source=str(out))
    with open(out / LOCK_NAME, "a+b") as other:  # another batch: the end-of-batch sweep may not run
        fcntl.flock(other.fileno(), fcntl.LOCK_SH)
        summary = run_batch([src], out, config, {}, cache_dir=None, progress=False)
    assert summary["failed"] == 1 and "exceeded 2 s" in summary["assets"][0]["error"]
    assert sorted(p.name for p in out.iterdir()) == [LOCK_NAME, "batch.json"]
