"""End to end through the command line: the bundled samples, the bad-input corpus, inspect."""

import json
from pathlib import Path

import pytest
from pxr import Usd

from sssbake.pipeline.cli import main

from bad_inputs import write_bad_inputs
from generate import generate


@pytest.fixture(scope="module")
def baked_samples(tmp_path_factory):
    src = tmp_path_factory.mktemp("samples")
    generate(src)
    out = tmp_path_factory.mktemp("out")
    code = main(["bake", str(src), "-o", str(out), "--config", str(src / "sssbake.toml"), "-q"])
    return src, out, code


def test_samples_bake_clean(baked_samples):
    src, out, code = baked_samples
    assert code == 0
    batch = json.loads((out / "batch.json").read_text())
    assert batch["failed"] == 0 and batch["ok"] == 5
    for name in ("sphere", "torus", "thin_slab", "blob", "candle"):
        report = json.loads((out / f"{name}.report.json").read_text())
        assert (out / f"{name}.glb").stat().st_size > 0 and (out / f"{name}.usdc").stat().st_size > 0
        assert report["validation"]["gltf"]["errors"] == 0, report["validation"]
        assert report["validation"]["gltf"]["warnings"] == 0, report["validation"]
        assert report["validation"]["usd"]["errors"] == 0, report["validation"]
        assert report["stages"]["simplify"]["skipped"]
    slab = json.loads((out / "thin_slab.report.json").read_text())
    assert slab["materials"]["sssbake_default"]["scattering"]["name"] == "skin1"
    candle = json.loads((out / "candle.report.json").read_text())
    assert candle["materials"]["Brass"]["scattering"] is None
    assert candle["materials"]["Wax"]["reason"].startswith("material name matches")
    assert candle["scale_mm_per_unit"] == 1000.0
    # Outputs are written under temporary names; the default prim is named after the real file.
    assert Usd.Stage.Open(str(out / "thin_slab.usdc")).GetDefaultPrim().GetName() == "thin_slab"


def test_rerun_does_no_work(baked_samples):
    src, out, _ = baked_samples
    before = {p: p.stat().st_mtime_ns for p in out.glob("*.glb")}
    assert main(["bake", str(src), "-o", str(out), "--config", str(src / "sssbake.toml"), "-q"]) == 0
    batch = json.loads((out / "batch.json").read_text())
    assert {r["status"] for r in batch["assets"]} == {"up-to-date"}
    assert before == {p: p.stat().st_mtime_ns for p in out.glob("*.glb")}


def test_stage_cache_serves_a_rebake(baked_samples, tmp_path):
    src, out, _ = baked_samples
    # New output folder, same cache: every cached stage is a hit, outputs are identical.
    args = ["bake", str(src / "sphere.obj"), "-o", str(tmp_path), "--config", str(src / "sssbake.toml"),
            "--cache-dir", str(out / ".sssbake-cache"), "-q"]
    assert main(args) == 0
    report = json.loads((tmp_path / "sphere.report.json").read_text())
    for stage in ("load", "clean", "atlas", "thickness", "thickness_map"):
        assert report["stages"][stage]["cached"] == report["stages"][stage]["runs"] >= 1
    assert (tmp_path / "sphere.glb").read_bytes() == (out / "sphere.glb").read_bytes()


def test_inspect_shows_thickness(baked_samples, capsys):
    _, out, _ = baked_samples
    assert main(["inspect", str(out / "sphere.glb")]) == 0
    assert "_THICKNESS" in capsys.readouterr().out
    assert main(["inspect", str(out / "sphere.usdc")]) == 0
    assert "primvars:sss:thickness" in capsys.readouterr().out


def test_bad_inputs_fail_alone_and_leave_nothing(tmp_path, capsys):
    src = tmp_path / "in"
    src.mkdir()
    expected = write_bad_inputs(src)
    assert len(expected) >= 15
    generate(tmp_path / "good")
    (src / "good.obj").write_bytes((tmp_path / "good" / "sphere.obj").read_bytes())
    out = tmp_path / "out"
    code = main(["bake", str(src), "-o", str(out), "--scale-mm", "1", "-q"])
    assert code == 1
    batch = json.loads((out / "batch.json").read_text())
    by_name = {Path(r["asset"]).name: r for r in batch["assets"]}
    assert by_name["good.obj"]["status"] == "ok"
    err = capsys.readouterr().err
    for name, needle in expected.items():
        if name not in by_name:  # files the batch does not pick up (unsupported extension)
            continue
        rec = by_name[name]
        assert rec["status"] == "failed", name
        assert name in rec["error"] and needle.lower() in rec["error"].lower(), rec["error"]
        assert "\n" not in rec["error"]
        assert rec["error"] in err
    leftovers = sorted(p.name for p in out.rglob("*") if p.is_file() and ".sssbake-cache" not in p.parts)
    assert leftovers == ["batch.json", "good.glb", "good.report.json", "good.usdc"]


def test_missing_scale_is_refused_not_guessed(tmp_path, capsys):
    generate(tmp_path / "s")
    code = main(["bake", str(tmp_path / "s" / "sphere.obj"), "-o", str(tmp_path / "o"), "-q"])
    assert code == 1
    assert "no scale" in capsys.readouterr().err
    assert not list((tmp_path / "o").glob("sphere.*"))


def test_bad_material_is_one_line(tmp_path, capsys):
    generate(tmp_path / "s")
    code = main(["bake", str(tmp_path / "s" / "sphere.obj"), "-o", str(tmp_path / "o"), "--scale-mm", "1",
                 "--material", "granite", "-q"])
    assert code == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert any("sphere.obj" in line and "unknown material preset 'granite'" in line for line in err)


def test_parallel_jobs_match_serial(baked_samples, tmp_path):
    src, out, _ = baked_samples
    code = main(["bake", str(src), "-o", str(tmp_path), "--config", str(src / "sssbake.toml"), "--jobs", "2",
                 "--no-cache", "-q"])
    assert code == 0
    for name in ("sphere", "candle"):
        assert (tmp_path / f"{name}.glb").read_bytes() == (out / f"{name}.glb").read_bytes()


def test_prt_bake_writes_validated_readable_data(baked_samples, tmp_path):
    import numpy as np

    from sssbake.exporters.read_prt import read_prt_glb, read_prt_usd
    from sssbake.pipeline.prt_compress import decode_at_directions

    src, _, _ = baked_samples
    args = ["bake", str(src / "sphere.obj"), "-o", str(tmp_path), "--config", str(src / "sssbake.toml"),
            "--techniques", "prt", "--prt-directions", "32", "--prt-sh-order", "2", "-q"]
    assert main(args) == 0
    report = json.loads((tmp_path / "sphere.report.json").read_text())
    assert report["validation"]["gltf"]["errors"] == report["validation"]["gltf"]["warnings"] == 0
    assert report["validation"]["usd"]["errors"] == 0
    prt_report = report["prt"]["sphere.obj"]
    assert prt_report["directions"] == 32 and prt_report["shOrder"] == 2
    assert 0 < prt_report["droppedFraction"][0] <= 0.01 + 1e-12
    from_glb = read_prt_glb(tmp_path / "sphere.glb")[(0, 0)]
    from_usd = next(iter(read_prt_usd(tmp_path / "sphere.usdc").values()))
    q = decode_at_directions(from_glb)
    np.testing.assert_array_equal(q, decode_at_directions(from_usd))
    assert np.all(np.isfinite(q)) and abs(q.max() - prt_report["qMax"]) <= 0.1 * prt_report["qMax"]


def test_unknown_technique_is_a_clear_error(tmp_path, capsys):
    src = tmp_path / "in"
    src.mkdir()
    (src / "a.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    assert main(["bake", str(src), "-o", str(tmp_path / "out"), "--scale-mm", "1", "--techniques", "magic", "-q"]) != 0
    assert "unknown technique(s) ['magic']" in capsys.readouterr().err
