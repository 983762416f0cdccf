"""End to end through the command line: the bundled samples, the bad-input corpus, inspect."""

import json
import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest
from bad_inputs import write_bad_inputs
from generate import generate
from pxr import Usd

from sssbake.pipeline.cli import main


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
    # techniques default to auto: every translucent sample gets SSS data, each choice with its reason
    for name in ("sphere", "torus", "thin_slab", "candle"):
        report = json.loads((out / f"{name}.report.json").read_text())
        (entry,) = report["plan"]
        assert entry["techniques"] == ["prt"] and entry["reasons"][0].startswith("thin or small"), entry
        assert report["prt"] and report["prt"][entry["mesh"]]["bytesPerVertex"]["total"] > 0
    blob = json.loads((out / "blob.report.json").read_text())
    assert blob["plan"] == [] and blob["stages"]["simplify"]["skipped"]  # the config names lpv
    slab = json.loads((out / "thin_slab.report.json").read_text())
    assert slab["materials"]["sssbake_default"]["scattering"]["name"] == "skin1"
    # a closed 2 mm slab lets far more light through than the half-space profile carries across it
    # (core/back_share.py: ~2.8, 5, 12 x for skin1), and that is in the file's material
    scattering = slab["materials"]["sssbake_default"]["scattering"]
    assert min(scattering["back_gain"]) > 2.0 and min(scattering["escape_gain"]) > 1.0
    # the heterogeneous sample: veined marble, an lpv grid whose absorption varies
    (veined,) = json.loads((out / "blob.report.json").read_text())["lpv"].values()
    assert veined["field"] == "marble" and veined["cellsWithMedium"] > 0
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


def test_a_damaged_cache_entry_is_recomputed_and_reported(tmp_path):
    src = tmp_path / "in"
    generate(src)
    cache = tmp_path / "cache"
    args = ["bake", str(src / "torus.ply"), "--config", str(src / "sssbake.toml"), "--techniques", "none",
            "--atlas-resolution", "64", "--cache-dir", str(cache), "-q"]
    assert main([*args, "-o", str(tmp_path / "a")]) == 0
    for entry in cache.rglob("*.entry"):  # one flipped bit in every entry's payload
        data = bytearray(entry.read_bytes())
        data[len(data) // 2] ^= 0x01
        entry.write_bytes(bytes(data))
    assert main([*args, "-o", str(tmp_path / "b")]) == 0
    report = json.loads((tmp_path / "b" / "torus.report.json").read_text())
    damaged = [w for w in report["warnings"] if w.startswith("stage cache:")]
    assert damaged and all("deleted and recomputed" in w for w in damaged)
    assert report["stages"]["load"]["corrupt_cache_entries"] == 1 and report["stages"]["load"]["cached"] == 0
    assert (tmp_path / "b" / "torus.glb").read_bytes() == (tmp_path / "a" / "torus.glb").read_bytes()


def test_inspect_shows_thickness(baked_samples, capsys):
    _, out, _ = baked_samples
    assert main(["inspect", str(out / "sphere.glb"), "--json"]) == 0
    shown = json.loads(capsys.readouterr().out)
    assert "_THICKNESS" in json.dumps(shown) and shown["meshes"][0]["sssbake"]["prt"]["technique"] == "prt"
    mesh = shown["meshes"][0]
    ref = mesh["primitives"][0]["attributes"]["_SSS_PRT_REF"]["bytesPerVertex"]
    assert shown["footprint"]["techniques"]["prt"]["attributes"] == ref * (1 + len(mesh["sssbake"]["prt"]["attributes"]["dq"]))
    assert main(["inspect", str(out / "sphere.usdc"), "--json"]) == 0
    assert "primvars:sss:thickness" in capsys.readouterr().out


def test_inspect_prints_a_summary_and_refuses_files_without_sssbake_data(baked_samples, tmp_path, capsys):
    import pygltflib

    _, out, _ = baked_samples
    assert main(["inspect", str(out / "sphere.glb"), "--json"]) == 0
    prt = json.loads(capsys.readouterr().out)["footprint"]["techniques"]["prt"]
    for name in ("sphere.glb", "sphere.usdc"):
        assert main(["inspect", str(out / name)]) == 0
        lines = capsys.readouterr().out.splitlines()
        assert lines[0].startswith(f"{out / name}: sssbake schema 2.")
        assert lines[1].startswith("mesh ") and " vertices, 1 mm per unit" in lines[1]
        assert "(marble): fallback " in lines[2]
        assert lines[3] == f"  prt       {prt['attributes']:.1f} B/vertex attributes, {prt['total']:.1f} with tables"
        assert prt["tables"] > 0
        assert lines[-1].startswith("file: ")
    # a glTF with no sssbake data (a tool known to strip it would be named: test_sssbake_extension), refused by
    # inspect as by verify
    gltf = pygltflib.GLTF2.load(str(out / "sphere.glb"))
    gltf.extensions, gltf.extensionsUsed = {}, []
    for mesh in gltf.meshes:
        mesh.extensions = {}
        for prim in mesh.primitives:
            for key in [k for k in vars(prim.attributes) if k.startswith("_")]:
                setattr(prim.attributes, key, None)
    for material in gltf.materials:
        material.extensions = {}
    gltf.asset.generator = "some exporter"  # no tool known to strip sssbake data (those are named instead)
    # not `save`: it swaps in its default Asset, one object shared by every call, which another test may
    # have given a generator
    gltf.save_binary(str(tmp_path / "stripped.glb"))
    for command in ("inspect", "verify"):
        assert main([command, str(tmp_path / "stripped.glb")]) == 1
        assert capsys.readouterr().err == (f"error: {tmp_path / 'stripped.glb'}: no SSSBAKE_subsurface data: not a "
                                           "file sssbake baked (bake the asset with sssbake), or one a tool stripped "
                                           "it from\n")


def test_help_imports_no_technique():
    """`sssbake --help` lists the commands without building their arguments, whose defaults import
    every technique (numpy, scipy, numba)."""
    probe = """
import sys
from sssbake.pipeline.cli import main
try:
    main(['--help'])
except SystemExit:
    pass
print('numpy' in sys.modules, 'sssbake.pipeline.techniques.registry' in sys.modules)
"""
    done = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, check=True)
    assert "inspect" in done.stdout and done.stdout.split()[-2:] == ["False", "False"]


def test_khr_materials_volume_scatter_flag_sets_the_option():
    from sssbake.pipeline.cli import _overrides, build_parser

    args = ["bake", "a.obj", "-o", "out"]
    assert _overrides(build_parser().parse_args([*args, "--khr-materials-volume-scatter"])) == {
        "khr_materials_volume_scatter": True}
    # absent: the config's value stands
    assert "khr_materials_volume_scatter" not in _overrides(build_parser().parse_args(args))


@pytest.mark.parametrize("command", ["bake", "plan", "tradeoff"])
def test_command_help_imports_no_numerical_stack(command):
    """A command's ``--help`` builds its flags from the techniques' entries and options modules
    (`registry.ENTRIES`), not from their implementations, which import scipy, numba, trimesh, USD and
    pygltflib (~1 s)."""
    probe = f"""
import sys
from sssbake.pipeline.cli import main
try:
    main([{command!r}, '--help'])
except SystemExit:
    pass
print(sorted(m for m in ('scipy', 'numba', 'trimesh', 'embreex', 'pxr', 'pygltflib') if m in sys.modules))
"""
    done = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, check=True)
    assert "usage: sssbake" in done.stdout and done.stdout.splitlines()[-1] == "[]", done.stdout[-300:]


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
    # the batch lock (`batch._batch_lock`) stays: it is how a later batch knows whether it runs alone
    assert leftovers == [".sssbake.lock", "batch.json", "good.glb", "good.materials.json", "good.mtlx",
                         "good.report.json", "good.thickness0.png", "good.usdc"]


def test_missing_scale_is_refused_not_guessed(tmp_path, capsys):
    generate(tmp_path / "s")
    code = main(["bake", str(tmp_path / "s" / "sphere.obj"), "-o", str(tmp_path / "o"), "-q"])
    assert code == 1
    assert "no scale" in capsys.readouterr().err
    assert not list((tmp_path / "o").glob("sphere.*"))


def test_bad_material_refuses_the_batch_in_one_line(tmp_path, capsys):
    generate(tmp_path / "s")
    code = main(["bake", str(tmp_path / "s" / "sphere.obj"), "-o", str(tmp_path / "o"), "--scale-mm", "1",
                 "--material", "granite", "-q"])
    assert code == 2  # before any bake: no asset could bake with it
    assert capsys.readouterr().err == "error: --material: unknown material preset 'granite'; choose one of apple, " \
                                      "chicken1, chicken2, cream, ketchup, marble, potato, skimmilk, skin1, skin2, " \
                                      "spectralon, wholemilk\n"
    assert not (tmp_path / "o").exists()


def test_parallel_jobs_match_serial(baked_samples, tmp_path):
    src, out, _ = baked_samples
    code = main(["bake", str(src), "-o", str(tmp_path), "--config", str(src / "sssbake.toml"), "--jobs", "2",
                 "--no-cache", "-q"])
    assert code == 0
    for name in ("sphere", "candle"):
        assert (tmp_path / f"{name}.glb").read_bytes() == (out / f"{name}.glb").read_bytes()


def test_prt_bake_writes_validated_readable_data(baked_samples, tmp_path, capsys):
    import numpy as np

    from sssbake.pipeline.techniques.prt.compress import decode_at_directions
    from sssbake.pipeline.techniques.prt.decode import bytes_per_vertex
    from sssbake.pipeline.techniques.prt.reader import read_prt_glb, read_prt_usd

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
    # the planner's bytes per vertex (prt's byte budget, `decode.bytes_per_vertex`) is the file's
    # (`footprint`): on the data read back, whose vertices are the render vertices, the same figures; the
    # bake's report spreads the same table bytes over the welded surface's fewer vertices
    assert main(["inspect", str(tmp_path / "sphere.glb"), "--json"]) == 0
    used = json.loads(capsys.readouterr().out)["footprint"]["techniques"]["prt"]
    planned = bytes_per_vertex(from_glb)
    assert used["attributes"] == planned["per_vertex"] == prt_report["bytesPerVertex"]["per_vertex"] == 12.0 * 5
    assert used["tables"] == pytest.approx(planned["tables"]) and used["total"] == pytest.approx(planned["total"])
    assert prt_report["bytesPerVertex"]["tables"] > used["tables"] > 0


def test_unknown_technique_is_a_clear_error(tmp_path, capsys):
    src = tmp_path / "in"
    src.mkdir()
    (src / "a.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    assert main(["bake", str(src), "-o", str(tmp_path / "out"), "--scale-mm", "1", "--techniques", "magic", "-q"]) != 0
    assert "unknown technique(s) ['magic']" in capsys.readouterr().err


def test_spectral_bake_writes_normals_variant_and_basis(baked_samples, tmp_path):
    import numpy as np
    import pygltflib
    from pxr import UsdGeom

    from sssbake.exporters.gltf import read_accessor
    from sssbake.exporters.gltf_tables import load_sssbake_gltf, technique_tables
    from sssbake.exporters.gltf_validator import ValidatorUnavailable, find_validator
    from sssbake.pipeline.core.materials import Material
    from sssbake.pipeline.mesh.clean import clean_scene
    from sssbake.pipeline.mesh.load import load_scene
    from sssbake.pipeline.techniques.spectral.precompute import SpectralPrecomputeOptions, precompute_spectral

    src, _, _ = baked_samples
    args = ["bake", str(src / "sphere.obj"), "-o", str(tmp_path), "--config", str(src / "sssbake.toml"),
            "--atlas-resolution", "128", "--techniques", "spectral", "--spectral-eigenpairs", "40",
            "--spectral-variant", "--spectral-basis", "-q"]
    assert main(args) == 0
    report = json.loads((tmp_path / "sphere.report.json").read_text())
    variant_path = tmp_path / "sphere.sss_normals.glb"
    assert str(variant_path) in report["outputs"] and report["stages"]["spectral"]["runs"] == 1
    spectral = report["spectral"]["sphere.obj"]
    assert spectral["eigenpairs"] == 40 and spectral["basis"] is True and spectral["bytes"]["basis"] > 0
    try:
        find_validator()
        validated = ("gltf", "gltf_sss_normals", "usd")
    except ValidatorUnavailable:
        validated = ("usd",)
    for name in validated:
        assert report["validation"][name]["errors"] == report["validation"][name].get("warnings", 0) == 0, name

    # the sample config: marble at 1 mm per unit, with the sphere's escape gain (the report's material)
    surface = clean_scene(load_scene(str(src / "sphere.obj"))).surfaces[0]
    (record,) = [m["scattering"] for m in report["materials"].values() if m["scattering"]]
    assert min(record["escape_gain"]) > 1.0
    pre = precompute_spectral(surface, 1.0, Material.from_json(record), SpectralPrecomputeOptions(eigenpairs=40))
    gltf = pygltflib.GLTF2.load(str(tmp_path / "sphere.glb"))
    attributes = gltf.meshes[0].primitives[0].attributes
    stored = read_accessor(gltf, attributes._SSS_NORMAL).astype(np.float64)  # float32 VEC3
    ids = read_accessor(gltf, attributes._SSS_SPECTRAL_VERTEX)[:, 0].astype(np.int64)  # (id, 0, 0)
    assert np.abs(stored - pre.normals[ids]).max() <= 2.0**-24
    assert np.abs(np.linalg.norm(stored, axis=1) - 1.0).max() <= 1e-6
    tables = technique_tables(load_sssbake_gltf(tmp_path / "sphere.glb"), "meshes", 0, "spectral")
    n, m = tables["vertexCount"], tables["eigenpairs"]
    original = tables["basis"].reshape(n, m).astype(np.float64) @ tables["coefficients"] + tables["residual"]
    np.testing.assert_allclose(original, surface.normals, atol=2e-6)

    variant = pygltflib.GLTF2.load(str(variant_path))
    v_attributes = variant.meshes[0].primitives[0].attributes
    v_normal = read_accessor(variant, v_attributes.NORMAL).astype(np.float64)
    np.testing.assert_allclose(v_normal, read_accessor(variant, v_attributes._SSS_NORMAL), atol=1e-6)
    np.testing.assert_allclose(v_normal, stored, atol=1e-6)
    assert "spectral" not in variant.meshes[0].extensions["SSSBAKE_subsurface"]
    assert variant.extensions["SSSBAKE_subsurface"]["variant"] == "sss_normals"

    stage = Usd.Stage.Open(str(tmp_path / "sphere.usdc"))
    mesh = next(p for p in stage.Traverse() if p.IsA(UsdGeom.Mesh))
    primvar = UsdGeom.PrimvarsAPI(mesh).GetPrimvar("sss:normal")
    # normal3f[], one per point (Blender's USD import zeroes primvars with elementSize > 1)
    assert str(primvar.GetTypeName()) == "normal3f[]" and primvar.GetElementSize() == 1
    assert len(primvar.Get()) == len(UsdGeom.Mesh(mesh).GetPointsAttr().Get())
    np.testing.assert_allclose(np.asarray(primvar.Get()), stored, atol=1e-6)


@pytest.mark.parametrize("flags, flag, needle", [
    (["--techniques", "spectral", "--spectral-eigenpairs", "0"], "--spectral-eigenpairs",
     "spectral: eigenpairs must be"),
    (["--techniques", "spectral", "--spectral-width-mm", "-1"], "--spectral-width-mm",
     "spectral_width_mm must be in [0, 1e+12] mm, got -1.0"),
    (["--spectral-variant"], "--spectral-variant", "spectral_variant needs the spectral technique"),
])
def test_bad_spectral_options_are_one_line(tmp_path, capsys, flags, flag, needle):
    generate(tmp_path / "s")
    code = main(["bake", str(tmp_path / "s" / "sphere.obj"), "-o", str(tmp_path / "o"), "--scale-mm", "1", "-q",
                 *flags])
    assert code == 2
    (line,) = capsys.readouterr().err.splitlines()
    assert line.startswith(f"error: {flag}: {needle}"), line
    assert not (tmp_path / "o").exists()


def test_screen_bake_exports_the_material_tables(tmp_path):
    from sssbake.exporters.gltf_tables import load_sssbake_gltf, technique_tables

    generate(tmp_path / "s")
    args = ["bake", str(tmp_path / "s" / "sphere.obj"), "-o", str(tmp_path / "o"), "--scale-mm", "1",
            "--atlas-resolution", "64", "--techniques", "screen", "--screen-samples", "9", "--screen-uniform", "2",
            "--screen-table-error", "0.01", "--no-validate", "-q"]
    assert main(args) == 0
    report = json.loads((tmp_path / "o" / "sphere.report.json").read_text())
    (entry,) = report["screen"].values()
    assert entry["options"]["samples"] == 9 and entry["offsets"] == 11 and entry["tableError"] <= 0.01
    assert report["stages"]["screen"]["runs"] == 1 and "skipped" not in report["stages"]["screen"]
    data = load_sssbake_gltf(tmp_path / "o" / "sphere.glb")
    tables = next(t for t in (technique_tables(data, "materials", m, "screen") for m in range(len(data.gltf.materials)))
                  if t is not None)
    assert tables["offsets"].shape == (11, 2) and tables["uniform"] == 2


def test_screen_is_skipped_when_not_asked(baked_samples, tmp_path):
    src, out, _ = baked_samples
    report = json.loads((out / "sphere.report.json").read_text())
    assert report["screen"] == {} and "the plan chose it for no object" in report["stages"]["screen"]["skipped"]
    # none: the fallback only, every technique skipped as not requested
    assert main(["bake", str(src / "sphere.obj"), "-o", str(tmp_path), "--config", str(src / "sssbake.toml"),
                 "--techniques", "none", "-q"]) == 0
    report = json.loads((tmp_path / "sphere.report.json").read_text())
    assert report["plan"] == [] and report["prt"] == {}
    assert all("not requested" in report["stages"][t]["skipped"] for t in ("prt", "kernels", "spectral", "screen", "lpv"))


def test_none_must_stand_alone(baked_samples, tmp_path, capsys):
    src, _, _ = baked_samples
    assert main(["bake", str(src / "sphere.obj"), "-o", str(tmp_path), "--scale-mm", "1",
                 "--techniques", "none,prt", "-q"]) == 2
    assert "none bakes only the fallback; give it alone" in capsys.readouterr().err


@pytest.mark.parametrize("flags, needle", [
    (["--screen-samples", "0"], "screen: samples must be"),
    (["--screen-uniform", "-2"], "screen: uniform must be"),
    (["--screen-table-error", "1"], "screen: table_error must be"),
])
def test_bad_screen_options_are_one_line(tmp_path, capsys, flags, needle):
    generate(tmp_path / "s")
    code = main(["bake", str(tmp_path / "s" / "sphere.obj"), "-o", str(tmp_path / "o"), "--scale-mm", "1", "-q",
                 "--techniques", "screen", *flags])
    assert code == 2
    (line,) = capsys.readouterr().err.splitlines()
    assert line.startswith(f"error: {flags[0]}: {needle}"), line
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("jobs", ["-1", "0", "1.5", "two"])
def test_jobs_must_be_a_whole_number_at_least_one(tmp_path, capsys, jobs):
    with pytest.raises(SystemExit) as e:
        main(["bake", str(tmp_path), "-o", str(tmp_path / "out"), "--jobs", jobs])
    assert e.value.code == 2
    assert f"argument --jobs: must be a whole number >= 1, got '{jobs}'" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()


def test_a_reader_gone_before_the_output_gets_no_traceback():
    """`sssbake presets | head -1`: the pipe's reader has gone (here before the first write, so
    that the write must fail): the shell's code for SIGPIPE and nothing on stderr."""
    read, write = os.pipe()
    proc = subprocess.Popen([sys.executable, "-m", "sssbake.pipeline.cli", "presets"], stdout=write,
                            stderr=subprocess.PIPE)
    os.close(read)  # before the child has imported the CLI: its first write meets a closed pipe
    os.close(write)
    stderr = proc.communicate()[1].decode()
    assert proc.returncode == 128 + signal.SIGPIPE and stderr == "", stderr


def test_bake_starts_its_fork_server_before_the_pipelines_imports():
    """The CLI imports no technique until a command needs one, and ``bake`` starts the fork server its
    workers come from first, so that the server's imports run beside the CLI's own; not for
    ``--help`` nor ``--dask`` (no worker of this machine), nor for other commands."""
    probe = """
import sys
from multiprocessing import forkserver
from sssbake.pipeline import cli
print('sssbake.pipeline.techniques.registry' in sys.modules, 'numpy' in sys.modules)
cli._early_fork_server(sys.argv[1:])
print(forkserver._forkserver._forkserver_pid is not None, 'sssbake.pipeline.options' in sys.modules)
"""

    def run(*argv):
        done = subprocess.run([sys.executable, "-c", probe, *argv], capture_output=True, text=True, check=True)
        return done.stdout.split()

    assert run("bake", "a.obj", "-o", "out") == ["False", "False", "True", "False"]
    for argv in (("bake", "a.obj", "-o", "out", "--help"), ("bake", "a.obj", "-o", "out", "--dask", "local:1"),
                 ("plan", "a.obj")):
        assert run(*argv) == ["False", "False", "False", "False"], argv
