"""The physical inputs' ranges (`core.ranges.Range`): a bake at each end of every range gives finite
outputs with RuntimeWarnings turned into errors, and a value just outside is refused, naming the
option, the file or flag, and the range, before anything is baked."""

import json
import math
import re
import warnings
from dataclasses import fields
from pathlib import Path

import numpy as np
import pygltflib
import pytest
import trimesh

from sssbake.exporters.gltf import read_accessor
from sssbake.pipeline.bake.batch import run_batch
from sssbake.pipeline.cli import main
from sssbake.pipeline.config import BatchConfig, ConfigError, load_config
from sssbake.pipeline.core.materials import COEFFICIENT, ETA_DIPOLE, EXTINCTION, MEAN_FREE_PATH, Material, MaterialError
from sssbake.pipeline.core.montecarlo_profile import ETAS
from sssbake.pipeline.mesh.scale import SCALE_MM
from sssbake.pipeline.options import BAKE_DEFAULTS, BakeOptions, check_options

HIGH, LOW = COEFFICIENT.high, EXTINCTION.low
#: A material a tenth absorbed: the escape walk's photons end within tens of flights (marble's take
#: a thousand, and with no absorption at all they walk to its 200,000-flight cap: minutes).
QUICK = {"sigma_s_prime": 1.0, "sigma_a": 0.1, "eta": 1.3}
#: One asset per end (a rule each), fallback only at 64², the Monte Carlo profile unless named.
ENDS = {
    "scale_low": {"scale_mm": SCALE_MM.low, "material": QUICK},
    "scale_high": {"scale_mm": SCALE_MM.high, "material": QUICK},
    # both coefficients at their top: σ'_t twice it, half of it absorbed
    "coefficients_high": {"material": {"sigma_s_prime": HIGH, "sigma_a": HIGH, "eta": 1.3}},
    "scattering_high": {"material": {"sigma_s_prime": HIGH, "sigma_a": 0.1 * HIGH, "eta": 1.3}},
    "absorbing_only_high": {"material": {"sigma_s_prime": 0.0, "sigma_a": HIGH, "eta": 1.3}},
    # the longest free path, nearly all of it scattering (a diffusion length of 1e7 mm)
    "extinction_low": {"material": {"sigma_s_prime": 0.9 * LOW, "sigma_a": 0.1 * LOW, "eta": 1.3}},
    "no_absorption": {"material": {"sigma_s_prime": 1.0, "sigma_a": 0.0, "eta": 1.3}, "profile": "dipole"},
    "mean_free_path_low": {"material": {"albedo": 0.5, "mean_free_path_mm": MEAN_FREE_PATH.low, "eta": 1.3}},
    "mean_free_path_high": {"material": {"albedo": 0.5, "mean_free_path_mm": MEAN_FREE_PATH.high, "eta": 1.3}},
    "eta_low": {"material": {**QUICK, "eta": 1.0}},
    "eta_montecarlo_high": {"material": {**QUICK, "sigma_a": 0.5, "eta": ETAS[-1]}},
    "eta_dipole_high": {"material": {**QUICK, "eta": ETA_DIPOLE.high}, "profile": "dipole"},
}


def numbers(value):
    """Every float in a JSON value."""
    if isinstance(value, dict):
        for v in value.values():
            yield from numbers(v)
    elif isinstance(value, list):
        for v in value:
            yield from numbers(v)
    elif isinstance(value, float):
        yield value


def assert_finite_outputs(out: Path, stem: str) -> None:
    """Every number the bake wrote for `stem`: the report's, the glTF's JSON and float accessors."""
    report = json.loads((out / f"{stem}.report.json").read_text())
    assert all(math.isfinite(v) for v in numbers(report)), stem
    gltf = pygltflib.GLTF2.load(str(out / f"{stem}.glb"))
    assert all(math.isfinite(v) for v in numbers(json.loads(gltf.to_json()))), stem
    for i, accessor in enumerate(gltf.accessors):
        if accessor.componentType == pygltflib.FLOAT:
            assert np.all(np.isfinite(read_accessor(gltf, i))), (stem, i)


def test_a_bake_at_each_end_of_each_range_is_finite(tmp_path):
    src = tmp_path / "in"
    src.mkdir()
    ball = trimesh.creation.icosphere(subdivisions=1, radius=10.0)  # 20 units across: 20 mm at 1 mm/unit
    for name in ENDS:
        ball.export(src / f"{name}.obj")
    rules = tuple({"glob": f"{name}.obj", **values} for name, values in ENDS.items())
    config = BatchConfig({"scale_mm": 1.0, "techniques": (), "atlas_resolution": 64, "validate": False}, rules, ())
    for name in ENDS:  # every end is a valid setting
        check_options(config.options_for(f"{name}.obj", {}))
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # an overflow, a 0/0 or an invalid cast fails the asset
        summary = run_batch([src], tmp_path / "out", config, {}, cache_dir=None, progress=False, isolate=False)
    failed = {Path(r["asset"]).stem: r["error"] for r in summary["assets"] if r["status"] != "ok"}
    assert not failed, failed
    for name in ENDS:
        assert_finite_outputs(tmp_path / "out", name)


def test_the_techniques_length_options_bake_finite_at_their_ends(tmp_path):
    src = tmp_path / "in"
    src.mkdir()
    ball = trimesh.creation.icosphere(subdivisions=1, radius=10.0)
    ends = {"vein_low": {"techniques": ("lpv",), "lpv_field": "marble", "lpv_resolution": 8},
            "vein_high": {"techniques": ("lpv",), "lpv_field": "marble", "lpv_resolution": 8},
            "width_low": {"techniques": ("spectral",), "spectral_eigenpairs": 8},
            "width_high": {"techniques": ("spectral",), "spectral_eigenpairs": 8}}
    for name in ends:
        ball.export(src / f"{name}.obj")
    vein, width = (next(f.metadata["range"] for f in fields(BakeOptions) if f.name == n)
                   for n in ("lpv_vein_mm", "spectral_width_mm"))
    ends["vein_low"]["lpv_vein_mm"], ends["vein_high"]["lpv_vein_mm"] = vein.low, vein.high
    ends["width_low"]["spectral_width_mm"], ends["width_high"]["spectral_width_mm"] = width.low, width.high
    rules = tuple({"glob": f"{name}.obj", **values} for name, values in ends.items())
    config = BatchConfig({"scale_mm": 1.0, "atlas_resolution": 64, "validate": False, "profile": "dipole"}, rules, ())
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        summary = run_batch([src], tmp_path / "out", config, {}, cache_dir=None, progress=False, isolate=False)
    failed = {Path(r["asset"]).stem: r["error"] for r in summary["assets"] if r["status"] != "ok"}
    assert not failed, failed
    for name in ends:
        assert_finite_outputs(tmp_path / "out", name)
        report = json.loads((tmp_path / "out" / f"{name}.report.json").read_text())
        assert report[name.split("_")[0].replace("vein", "lpv").replace("width", "spectral")], name  # baked


def test_every_ranged_option_is_refused_just_outside_naming_it():
    ranged = [f for f in fields(BakeOptions) if "range" in f.metadata]
    assert {"scale_mm", "asset_timeout_s", "asset_memory_gib", "lpv_vein_mm", "spectral_width_mm"} <= {
        f.name for f in ranged}
    for f in ranged:
        allowed, whole = f.metadata["range"], f.type.removesuffix(" | None") == "int"
        for end, opened, towards in ((allowed.low, allowed.low_open, -math.inf), (allowed.high, allowed.high_open,
                                                                                  math.inf)):
            if abs(end) >= 1e308:  # nothing beyond float64's largest but inf, below
                continue
            step = 1 if towards > 0 else -1
            outside = end if opened else int(end) + step if whole else math.nextafter(end, towards)
            with pytest.raises(ValueError, match=rf"^{f.name} must be .*, got {re.escape(repr(outside))}$"):
                check_options(BAKE_DEFAULTS.merged({f.name: outside}))
        for bad in (float("nan"), float("inf"), -float("inf"), 10**400):
            with pytest.raises(ValueError, match=f"^{f.name} must be"):
                check_options(BAKE_DEFAULTS.merged({f.name: bad}))


@pytest.mark.parametrize("kwargs, needle", [
    (dict(sigma_s_prime=HIGH * 1.001, sigma_a=0.1, eta=1.3), r"sigma_s_prime must be in \[0, 10000\] 1/mm"),
    (dict(sigma_s_prime=1.0, sigma_a=1e308, eta=1.3), r"sigma_a must be in \[0, 10000\] 1/mm"),
    (dict(sigma_s_prime=LOW * 0.999, sigma_a=0.0, eta=1.3), r"sigma_s_prime \+ sigma_a must be in \[1e-06, 20000\]"),
    (dict(sigma_s_prime=1.0, sigma_a=0.1, eta=ETAS[-1] * 1.001),
     r"eta 2.002 is beyond the Monte Carlo profile's table \(1-2\)"),
    (dict(sigma_s_prime=1.0, sigma_a=0.1, eta=ETA_DIPOLE.high * 1.001, profile="dipole"),
     r"eta must be in \[1, 3.8\] \(the dipole's boundary term A is infinite at 3.848\)"),
    (dict(sigma_s_prime=1.0, sigma_a=0.1, eta=1e308, profile="dipole"), r"eta must be in \[1, 3.8\]"),
])
def test_material_values_just_outside_are_refused(kwargs, needle):
    with pytest.raises(MaterialError, match=rf"^material 'm': {needle}"):
        Material("m", **kwargs)


def test_a_bad_value_refuses_the_batch_naming_the_file_rule_and_option(tmp_path, capsys):
    src = tmp_path / "in"
    src.mkdir()
    trimesh.creation.icosphere(subdivisions=1, radius=10.0).export(src / "a.obj")
    out = tmp_path / "out"
    cases = {
        "[defaults]\nscale_mm = 1e308\n":
            "[defaults]: scale_mm must be in [1e-06, 1e+06] mm per file unit, got 1e+308",
        "[defaults]\nscale_mm = 1.0\n[materials]\n\"Wax*\" = { sigma_s_prime = 1e308, sigma_a = 1.0 }\n":
            "[materials] 'Wax*': material 'Wax*': sigma_s_prime must be in [0, 10000] 1/mm in every channel",
        "[defaults]\nscale_mm = 1.0\n[[assets]]\nglob = 'a.obj'\n[[assets]]\nglob = 'b*.obj'\n"
        "material = { albedo = 0.5, mean_free_path_mm = 1e9 }\n":
            "[[assets]] rule 2 (glob 'b*.obj'): material 'material': mean_free_path_mm must be in [0.0001, 1e+06] mm",
        "[[assets]]\nglob = '*'\nlpv_vein_mm = 1e-300\n":
            "[[assets]] rule 1 (glob '*'): lpv_vein_mm must be in [0.001, 1e+12] mm, got 1e-300",
    }
    for text, needle in cases.items():
        config = tmp_path / "c.toml"
        config.write_text(text)
        with pytest.raises(ConfigError) as e:
            load_config(config)
        assert str(e.value) == f"{config}: {needle}" or str(e.value).startswith(f"{config}: {needle}"), str(e.value)
        assert main(["bake", str(src), "-o", str(out), "--config", str(config), "-q"]) == 2
        assert capsys.readouterr().err.startswith(f"error: {config}: {needle}")
        assert not out.exists()
    for flags, needle in (
            (["--scale-mm", "1e308"], "--scale-mm: scale_mm must be in [1e-06, 1e+06] mm per file unit, got 1e+308"),
            (["--scale-mm", "1", "--asset-memory", "1e300"], "--asset-memory: asset_memory_gib must be a finite number "
                                                            ">= 0 and at most 2^34 GiB (0: no limit), got 1e+300"),
            (["--scale-mm", "1", "--lpv-vein-mm", "nan"], "--lpv-vein-mm: lpv_vein_mm must be in [0.001, 1e+12] mm, "
                                                          "got nan")):
        assert main(["bake", str(src), "-o", str(out), "-q", *flags]) == 2
        assert capsys.readouterr().err == f"error: {needle}\n"
        assert not out.exists()
    # a rule valid on [defaults], impossible with a flag: the assets it matches fail alone (a rule
    # may match none of a batch's assets), each on one line naming the asset and the config
    config.write_text("[[assets]]\nglob = '*'\natlas_padding = 8\n")
    assert main(["bake", str(src), "-o", str(out), "--config", str(config), "--scale-mm", "1",
                 "--atlas-resolution", "32", "-q"]) == 1
    assert capsys.readouterr().err.splitlines()[0] == (
        f"error: {src / 'a.obj'}: {config}: atlas_padding must be in [0, resolution/8], got 8")
    assert sorted(p.name for p in out.iterdir()) == [".sssbake-cache", ".sssbake.lock", "batch.json"]


def test_a_file_declaring_a_unit_out_of_range_fails_alone(tmp_path, capsys):
    from pxr import Usd, UsdGeom

    src = tmp_path / "in"
    src.mkdir()
    stage = Usd.Stage.CreateNew(str(src / "huge.usda"))
    UsdGeom.SetStageMetersPerUnit(stage, 1e300)
    ball = trimesh.creation.icosphere(subdivisions=1)
    mesh = UsdGeom.Mesh.Define(stage, "/ball")
    mesh.GetPointsAttr().Set([tuple(map(float, v)) for v in ball.vertices])
    mesh.GetFaceVertexCountsAttr().Set([3] * len(ball.faces))
    mesh.GetFaceVertexIndicesAttr().Set([int(i) for i in ball.faces.reshape(-1)])
    stage.GetRootLayer().Save()
    ball.export(src / "good.glb")
    out = tmp_path / "out"
    config = tmp_path / "c.toml"
    config.write_text('[defaults]\ntechniques = []\natlas_resolution = 64\nvalidate = false\nprofile = "dipole"\n')
    assert main(["bake", str(src), "-o", str(out), "--config", str(config), "-q"]) == 1
    err = capsys.readouterr().err.splitlines()
    assert err[0] == (f"error: {src / 'huge.usda'}: the file declares 1e+303 mm per unit, outside [1e-06, 1e+06] mm "
                      "per file unit; pass --scale-mm (millimetres per file unit) or set scale_mm in the config")
    assert (out / "good.glb").exists() and not list(out.glob("huge*"))


def test_the_docs_list_every_range():
    text = (Path(__file__).resolve().parent.parent / "docs" / "ranges.md").read_text()
    ranged = [f for f in fields(BakeOptions) if "range" in f.metadata]
    for f in ranged:
        assert f"`{f.name}`" in text and f.metadata["range"].text() in text, f.name
    for allowed in (COEFFICIENT, EXTINCTION, MEAN_FREE_PATH, ETA_DIPOLE):
        assert allowed.text() in text, allowed
