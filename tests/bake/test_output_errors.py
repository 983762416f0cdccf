"""Output problems give one line each and a non-zero exit, and leave nothing behind: `-o` naming a
file, a read-only output folder, a full disk (a tiny tmpfs, mounted in a private mount namespace)."""

import shutil
import subprocess
from pathlib import Path

import pytest
import trimesh
from fixtures import FAST_DEFAULTS
from generate import blob

from sssbake.pipeline.cli import main


def _inputs(folder: Path) -> Path:
    folder.mkdir(parents=True)
    blob(5).export(folder / "big.obj")  # outputs of ~2 MB
    trimesh.creation.icosphere(subdivisions=1, radius=5.0).export(folder / "small.obj")  # ~20 kB
    return folder


def _in_namespace(tmp_path: Path, mount: str, bake: list[str]) -> subprocess.CompletedProcess:
    """Run `mount` then the bake in a private mount namespace; skips where none can be made. The
    script lists OUT's files from inside, where the mount is seen."""
    if shutil.which("unshare") is None:
        pytest.skip("no unshare(1)")
    probe = subprocess.run(["unshare", "-m", "sh", "-c", f"mount -t tmpfs -o size=16k tmpfs {tmp_path}"],
                           capture_output=True)
    if probe.returncode != 0:
        pytest.skip(f"no private mount namespace here ({probe.stderr.decode().strip()})")
    script = f"{mount} && sssbake {' '.join(bake)}; echo rc=$?; cd {bake[bake.index('-o') + 1]} && find . -type f"
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
    assert sorted(lines[1:]) == ["./.sssbake.lock", "./batch.json", "./small.glb", "./small.report.json",
                                 "./small.thickness0.png", "./small.usdc"]
