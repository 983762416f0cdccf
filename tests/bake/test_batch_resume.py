"""Resume: a batch killed with SIGKILL and run again redoes only the unfinished assets, and the
temporary files a killed batch leaves are swept, ours only, and never under a live batch."""

import fcntl
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import trimesh
from fixtures import FAST_DEFAULTS
from generate import blob

from sssbake.exporters.atomic import atomic_path, temporary_target
from sssbake.pipeline.bake.batch import LOCK_NAME, STALE_AFTER_S, run_batch, sweep_temporaries
from sssbake.pipeline.config import EMPTY_CONFIG

CONFIG = FAST_DEFAULTS
# What a SIGKILL leaves, name by name: atomic_path's temporaries, the one USD's save writes on its
# way to ours, a stage cache entry's.
OURS = (".sphere.glb.k2_9xq0a.tmp.glb", ".sphere.usdc.k2_9xq0a.tmp.usdc", ".sphere.usdc.k2_9xq0a.tmp.Ab3dE9",
        ".sphere.report.json.a_b_c_d_.tmp.json", "sub/.batch.json.0123abcd.tmp.json",
        ".sssbake-cache/ab/tmpq1w2e3r4.tmp")
# Alike but not ours: left alone.
NOT_OURS = ("notes.tmp", "sphere.tmp.glb", ".sphere.glb.K2_9XQ0A.tmp.glb", ".sphere.glb.k2_9xq0.tmp.glb",
            ".sphere.glb.k2_9xq0a.tmp.usdc", ".sssbake-cache/zz/tmpq1w2e3r4.tmp", ".sssbake-cache/ab/tmpq1w2e3.tmp",
            ".sssbake-cache/ab/xyzq1w2e3r4.tmp", "user/.draft.abcdefgh.tmp.txt.bak")


def _plant(out: Path, names, age_s: float) -> list[Path]:
    paths = []
    for name in names:
        p = out / name
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_bytes(b"partial")
        t = time.time() - age_s
        os.utime(p, (t, t))
        paths.append(p)
    return paths


def test_temporary_names_are_what_atomic_path_writes(tmp_path):
    seen = []
    for final in ("a.glb", "b.usdc", "batch.json", "noext"):
        with atomic_path(tmp_path / final) as tmp:
            seen.append((temporary_target(tmp.name), final))
            tmp.write_bytes(b"x")
    assert all(got == want for got, want in seen)
    assert [temporary_target(Path(n).name) for n in OURS[:5]] == [
        "sphere.glb", "sphere.usdc", "sphere.usdc", "sphere.report.json", "batch.json"]
    assert [temporary_target(Path(n).name) for n in NOT_OURS if not n.startswith(".sssbake-cache")] == [None] * 6


def test_a_batch_sweeps_stale_temporaries_of_ours_only(tmp_path):
    (tmp_path / "in").mkdir()
    out = tmp_path / "out"
    ours = _plant(out, OURS, age_s=60)
    theirs = _plant(out, NOT_OURS, age_s=60)
    summary = run_batch([tmp_path / "in"], out, EMPTY_CONFIG, {}, cache_dir=str(out / ".sssbake-cache"),
                        progress=False)
    assert summary["temporaries_removed"] == len(ours)
    assert not any(p.exists() for p in ours)
    assert all(p.exists() for p in theirs)


def test_temporaries_newer_than_the_run_are_left(tmp_path):
    out = tmp_path / "out"
    old = _plant(out, OURS[:1], age_s=60)
    new = _plant(out, OURS[1:2], age_s=-60)  # written after the cutoff (by a worker still running)
    assert sweep_temporaries(out, None, time.time()) == 1
    assert not old[0].exists() and new[0].exists()


def test_a_live_batch_keeps_its_temporaries(tmp_path):
    (tmp_path / "in").mkdir()
    out = tmp_path / "out"
    out.mkdir()
    # Another batch on the same OUT holds the shared lock, as run_batch does while it bakes.
    with open(out / LOCK_NAME, "a+b") as other:
        fcntl.flock(other.fileno(), fcntl.LOCK_SH)
        live = _plant(out, OURS[:3], age_s=60)  # possibly being written right now: kept
        dead = _plant(out, OURS[3:4], age_s=STALE_AFTER_S + 60)  # untouched for too long: no live write
        summary = run_batch([tmp_path / "in"], out, EMPTY_CONFIG, {}, cache_dir=None, progress=False)
    assert summary["temporaries_removed"] == 1
    assert all(p.exists() for p in live) and not dead[0].exists()
    # once that batch is gone, the next one sweeps the rest
    assert run_batch([tmp_path / "in"], out, EMPTY_CONFIG, {}, cache_dir=None, progress=False)[
        "temporaries_removed"] == 3


def _assets(folder: Path) -> list[str]:
    folder.mkdir(parents=True)
    blob(4).export(folder / "a_blob.obj")  # the slowest first: the kill lands while a later asset bakes
    trimesh.creation.icosphere(subdivisions=3, radius=10.0).export(folder / "b_sphere.obj")
    trimesh.creation.torus(major_radius=12.0, minor_radius=4.0, major_sections=32, minor_sections=16).export(
        folder / "c_torus.ply")
    trimesh.creation.box(extents=(40.0, 40.0, 2.0)).export(folder / "d_slab.stl")
    return ["a_blob", "b_sphere", "c_torus", "d_slab"]


def _temporaries(out: Path) -> list[Path]:
    """Every file under `out` that looks temporary in any way (ours or a library's)."""
    return [p for p in out.rglob("*") if p.is_file() and (".tmp" in p.name or p.name.startswith("tmp"))]


def _bake_command(src: Path, out: Path, config: Path) -> list[str]:
    return [sys.executable, "-m", "sssbake.pipeline.cli", "bake", str(src), "-o", str(out), "--config", str(config),
            "-q"]


def test_killed_batch_resumes_where_it_stopped(tmp_path):
    src, out, clean = tmp_path / "in", tmp_path / "out", tmp_path / "clean"
    names = _assets(src)
    config = tmp_path / "sssbake.toml"
    config.write_text(CONFIG)
    proc = subprocess.Popen(_bake_command(src, out, config), start_new_session=True,
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    try:
        deadline = time.monotonic() + 120
        while not (out / f"{names[0]}.report.json").exists():  # the last of an asset's outputs
            assert proc.poll() is None, proc.stderr.read().decode()
            assert time.monotonic() < deadline, "the first asset never finished"
            time.sleep(0.005)
        # Kill while the next asset bakes, at a temporary file if one shows within a moment.
        until = time.monotonic() + 0.5
        while time.monotonic() < until and not _temporaries(out) and not (out / f"{names[1]}.glb").exists():
            time.sleep(0.001)
    finally:
        os.killpg(proc.pid, signal.SIGKILL)  # the batch and its helpers (xatlas, the validator)
        proc.wait(10)
    assert proc.returncode == -signal.SIGKILL
    assert not (out / "batch.json").exists(), "the batch finished before the kill"
    assert not any((out / f"{n}.report.json").exists() for n in names[1:])
    # What else a SIGKILL can leave, planted so the sweep is exercised whatever the kill hit.
    _plant(out, [f".{names[1]}.glb.k2_9xq0a.tmp.glb", f".{names[1]}.usdc.k2_9xq0a.tmp.Ab3dE9",
                 ".sssbake-cache/ab/tmpq1w2e3r4.tmp"], age_s=60)

    again = subprocess.run(_bake_command(src, out, config), capture_output=True, text=True, timeout=180)
    assert again.returncode == 0, again.stderr
    batch = json.loads((out / "batch.json").read_text())
    assert [(Path(r["asset"]).stem, r["status"]) for r in batch["assets"]] == [
        (names[0], "up-to-date")] + [(n, "ok") for n in names[1:]]
    assert batch["temporaries_removed"] >= 3
    assert _temporaries(out) == []

    assert subprocess.run(_bake_command(src, clean, config), capture_output=True, timeout=180).returncode == 0
    for n in names:
        for suffix in (".glb", ".usdc"):
            assert (out / f"{n}{suffix}").read_bytes() == (clean / f"{n}{suffix}").read_bytes(), f"{n}{suffix}"


def test_a_missing_thickness_texture_rebakes_the_asset(tmp_path):
    """The .usdc references ``<stem>.thickness0.png`` beside it: without that file the asset is not
    up to date, and baking again writes it back."""
    from sssbake.pipeline.cli import main

    src, out = tmp_path / "in", tmp_path / "out"
    src.mkdir()
    trimesh.creation.icosphere(subdivisions=2).export(src / "ball.obj")
    config = tmp_path / "c.toml"
    config.write_text(CONFIG)
    command = ["bake", str(src), "-o", str(out), "--config", str(config), "--no-validate", "-q"]
    texture = out / "ball.thickness0.png"
    assert main(command) == 0 and texture.is_file()
    png = texture.read_bytes()
    assert main(command) == 0
    assert [r["status"] for r in json.loads((out / "batch.json").read_text())["assets"]] == ["up-to-date"]
    texture.unlink()
    assert main(command) == 0
    assert [r["status"] for r in json.loads((out / "batch.json").read_text())["assets"]] == ["ok"]
    assert texture.read_bytes() == png
