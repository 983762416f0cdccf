"""Resume: a batch killed with SIGKILL, or stopped by Ctrl-C, and run again redoes only the
unfinished assets, and the temporary files a killed batch leaves are swept, ours only, and never
under a live batch. Ctrl-C ends a batch with one line, killing its workers and their temporaries."""

import fcntl
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import psutil
import trimesh
from fixtures import FAST_DEFAULTS
from generate import blob
from waiting import finish, wait_for

from sssbake.exporters.atomic import atomic_path, temporary_target
from sssbake.pipeline.bake.batch import LOCK_NAME, STALE_AFTER_S, run_batch, sweep_temporaries
from sssbake.pipeline.bake.staging import is_staging
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
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    try:
        # the last of an asset's outputs
        wait_for((out / f"{names[0]}.report.json").exists, proc, "the batch's first asset")
        # Kill while the next asset bakes, at a temporary file if one shows within a moment.
        until = time.monotonic() + 0.5
        while time.monotonic() < until and not _temporaries(out) and not (out / f"{names[1]}.glb").exists():
            time.sleep(0.001)
    finally:
        os.killpg(proc.pid, signal.SIGKILL)  # the batch and its helpers (xatlas, the validator)
        proc.wait()
    assert proc.returncode == -signal.SIGKILL
    assert not (out / "batch.json").exists(), "the batch finished before the kill"
    assert not any((out / f"{n}.report.json").exists() for n in names[1:])
    # What else a SIGKILL can leave, planted so the sweep is exercised whatever the kill hit.
    _plant(out, [f".{names[1]}.glb.k2_9xq0a.tmp.glb", f".{names[1]}.usdc.k2_9xq0a.tmp.Ab3dE9",
                 ".sssbake-cache/ab/tmpq1w2e3r4.tmp"], age_s=60)

    again = subprocess.Popen(_bake_command(src, out, config), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    _, err = finish(again, "the batch run again")
    assert again.returncode == 0, err
    batch = json.loads((out / "batch.json").read_text())
    assert [(Path(r["asset"]).stem, r["status"]) for r in batch["assets"]] == [
        (names[0], "up-to-date")] + [(n, "ok") for n in names[1:]]
    assert batch["temporaries_removed"] >= 3
    assert _temporaries(out) == []

    clean_run = subprocess.Popen(_bake_command(src, clean, config), stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                 text=True)
    finish(clean_run, "a clean batch")
    assert clean_run.returncode == 0
    for n in names:
        for suffix in (".glb", ".usdc"):
            assert (out / f"{n}{suffix}").read_bytes() == (clean / f"{n}{suffix}").read_bytes(), f"{n}{suffix}"


def test_ctrl_c_stops_the_batch_in_one_line_and_the_rerun_skips_what_was_done(tmp_path):
    from sssbake.pipeline.cli import main

    src, out, tmp = tmp_path / "in", tmp_path / "out", tmp_path / "tmp"
    names = _assets(src)
    tmp.mkdir()
    config = tmp_path / "sssbake.toml"
    config.write_text(CONFIG)
    command = _bake_command(src, out, config) + ["--jobs", "2", "--no-validate"]
    # TMPDIR: where the assets' workers get their private folders, to be seen removed
    proc = subprocess.Popen(command, start_new_session=True, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, env={**os.environ, "TMPDIR": str(tmp)})
    try:
        wait_for(lambda: any(out.glob("*.report.json")), proc, "the batch's first asset")
        # an asset's worker leads a session of its own, with what it started (xatlas, the validator)
        workers = [p for p in psutil.Process(proc.pid).children(recursive=True) if os.getsid(p.pid) != proc.pid]
        os.killpg(proc.pid, signal.SIGINT)  # Ctrl-C: the terminal signals the whole foreground process group
        _, err = finish(proc, "the interrupted batch")  # its output closes: the fork server is gone too
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    done = sorted(p.name.removesuffix(".report.json") for p in out.glob("*.report.json"))
    assert 1 <= len(done) < len(names)
    # one line, and no traceback from any process (the batch, its fork server, its workers)
    assert err.splitlines() == [f"error: interrupted by SIGINT: {len(done)} baked, 0 failed, {len(names) - len(done)} "
                                "not baked; run the same command again to bake the rest"]
    assert proc.returncode == 128 + signal.SIGINT
    assert workers and all(not p.is_running() or p.status() == psutil.STATUS_ZOMBIE for p in workers)
    assert _temporaries(out) == [] and not [p for p in out.rglob("*") if is_staging(p.name)]
    assert list(tmp.iterdir()) == [] and not (out / "batch.json").exists()

    # every asset whose outputs were all written is up to date (baking the rest again is the test above's)
    for path in src.iterdir():
        if path.stem not in done:
            path.unlink()
    assert main(command[3:]) == 0
    batch = json.loads((out / "batch.json").read_text())
    assert [(Path(r["asset"]).stem, r["status"]) for r in batch["assets"]] == [(n, "up-to-date") for n in done]


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
