"""Engine-native subsurface parameters (pipeline/core/engine_materials.py) and <stem>.materials.json."""

import json
import math

import numpy as np
import pytest

from sssbake.pipeline.core.engine_materials import (
    FAR,
    GODOT_MIN_DEPTH,
    burley_s,
    burley_shape_distance_mm,
    engine_materials,
    godot4_subsurface,
    khr_materials_volume_scatter,
    multiscatter_albedo,
    openpbr_subsurface,
    single_scatter_albedo,
    surface_albedo,
    unity_hdrp_diffusion_profile,
    unreal_subsurface_profile,
)
from sssbake.pipeline.core.materials import Material, preset
from sssbake.pipeline.core.profile import profile_for, total_reflectance


def _numbers(value):
    """Every number in a JSON-like value."""
    if isinstance(value, dict):
        for v in value.values():
            yield from _numbers(v)
    elif isinstance(value, (list, tuple)):
        for v in value:
            yield from _numbers(v)
    elif isinstance(value, (int, float)) and not isinstance(value, bool):
        yield float(value)


def test_surface_albedo_is_the_profiles_total_reflectance_of_the_half_space():
    skin = preset("skin1")
    gained = Material("g", skin.sigma_s_prime, skin.sigma_a, skin.eta, escape_gain=(2.0, 2.0, 2.0))
    np.testing.assert_array_equal(surface_albedo(gained), total_reflectance(profile_for(skin)))
    assert 0.0 < surface_albedo(skin).min() < surface_albedo(skin).max() < 1.0


def test_burley_s_at_known_points():
    # 1.85 - A + 7|A - 0.8|^3: 0.8 -> 1.05 exactly, 0 -> 1.85 + 7 * 0.512, 1 -> 0.85 + 7 * 0.008
    np.testing.assert_allclose(burley_s([0.0, 0.8, 1.0]), [5.434, 1.05, 0.906], rtol=1e-12)


def test_openpbr_radius_in_file_units_scales_with_the_asset():
    skin = preset("skin1")
    one, ten = openpbr_subsurface(skin, 1.0), openpbr_subsurface(skin, 10.0)
    assert one["subsurface_radius"] == pytest.approx(skin.mean_free_path_mm.max(), rel=1e-15)
    assert one["subsurface_radius"] == pytest.approx(10.0 * ten["subsurface_radius"], rel=1e-15)
    np.testing.assert_allclose(np.multiply(one["subsurface_radius"], one["subsurface_radius_scale"]),
                               skin.mean_free_path_mm, rtol=1e-15)
    assert one["subsurface_radius_scale"] == ten["subsurface_radius_scale"]
    assert one["subsurface_color"] == surface_albedo(skin).tolist()
    assert one["subsurface_weight"] == 1.0 and one["subsurface_scatter_anisotropy"] == 0.0


def test_unreal_distances_are_centimetres_and_the_unit_scale_follows_the_asset():
    skin = preset("skin1")
    u1, u10 = unreal_subsurface_profile(skin, 1.0), unreal_subsurface_profile(skin, 10.0)
    assert u1["meanFreePathDistanceCm"] == pytest.approx(skin.mean_free_path_mm.max() / 10.0, rel=1e-15)
    np.testing.assert_allclose(np.multiply(u1["meanFreePathDistanceCm"], u1["meanFreePathColor"]),
                               skin.mean_free_path_mm / 10.0, rtol=1e-15)
    np.testing.assert_allclose(u1["burleyShapeDistanceCm"], burley_shape_distance_mm(skin) / 10.0, rtol=1e-15)
    # a physical distance: the same at every scale; the unit scale (cm per Unreal unit) grows 10x
    assert u10["meanFreePathDistanceCm"] == u1["meanFreePathDistanceCm"]
    assert u10["worldUnitScaleCm"] == pytest.approx(10.0 * u1["worldUnitScaleCm"], rel=1e-15)
    assert u1["worldUnitScaleCm"] == pytest.approx(1e-3) and u1["clamped"] == []


def test_hdrp_uses_burleys_shape_distance_in_millimetres():
    marble = preset("marble")
    h = unity_hdrp_diffusion_profile(marble, 1000.0, 25.0)
    d = marble.mean_free_path_mm / burley_s(surface_albedo(marble))
    np.testing.assert_allclose(np.multiply(h["multiplierMm"], h["scatteringColor"]), d, rtol=1e-15)
    assert max(h["scatteringColor"]) == 1.0
    assert h["worldScaleM"] == 1.0 and h["thicknessRemapMm"] == [0.0, 25.0]
    assert unity_hdrp_diffusion_profile(marble, 1.0)["thicknessRemapMm"] is None


def test_godot_depth_matches_the_diffusion_length_in_world_units():
    skin = preset("skin1")
    g1, g10 = godot4_subsurface(skin, 1.0), godot4_subsurface(skin, 10.0)
    least = skin.sigma_tr.min()
    assert g1["subsurfScatterTransmittanceDepth"] == pytest.approx(8.25 / least, rel=1e-15)
    assert g1["subsurfScatterTransmittanceDepth"] == pytest.approx(10.0 * g10["subsurfScatterTransmittanceDepth"])
    np.testing.assert_allclose(g1["subsurfScatterTransmittanceColor"], np.exp(1.0 - skin.sigma_tr / least), rtol=1e-15)
    # a metre-unit asset: the blur is a small share of Godot's default 0.05-unit scale
    g = godot4_subsurface(skin, 1000.0)
    assert g["subsurfScatterStrength"] == pytest.approx(burley_shape_distance_mm(skin).max() / 1000.0 / 0.05)
    assert g["clamped"] == [] and g1["clamped"] == ["subsurfScatterStrength"]


def test_multiscatter_inversion_round_trips():
    alpha = np.concatenate([np.linspace(1e-5, 1.0 - 1e-10, 2001), preset("skin1").albedo_prime,
                            preset("marble").albedo_prime])
    np.testing.assert_allclose(single_scatter_albedo(multiscatter_albedo(alpha)), alpha, atol=1e-12)
    # ρ_ss is flat at ρ_ms = 1 (its derivative vanishes there): the inverse is well posed below
    m = np.linspace(0.0, 0.99, 100)
    np.testing.assert_allclose(multiscatter_albedo(single_scatter_albedo(m)), m, atol=1e-6)
    # outside the fit's range: clamped to its ends
    assert multiscatter_albedo(0.0) == pytest.approx(0.0, abs=1e-15) and multiscatter_albedo(1.0) == pytest.approx(1.0)


def test_khr_volume_scatter_gives_back_the_medium():
    skin = preset("skin1")
    k = khr_materials_volume_scatter(skin, 2.0)
    sigma_t = -np.log(k["attenuationColor"]) / k["attenuationDistance"] / 2.0  # 1/mm
    np.testing.assert_allclose(sigma_t, skin.sigma_t_prime, rtol=1e-12)
    rho = single_scatter_albedo(k["multiscatterColor"])
    np.testing.assert_allclose(rho * sigma_t, skin.s, rtol=1e-9)
    np.testing.assert_allclose((1.0 - rho) * sigma_t, skin.a, rtol=1e-9)


def test_more_scattering_gives_larger_distances():
    thin = Material("thin", (1.0,) * 3, (0.1,) * 3, 1.3)
    dense = Material("dense", (1.0,) * 3, (0.01,) * 3, 1.3)  # less absorption: light goes further
    for f, key in ((openpbr_subsurface, "subsurface_radius"), (unity_hdrp_diffusion_profile, "multiplierMm"),
                   (godot4_subsurface, "subsurfScatterTransmittanceDepth")):
        assert f(dense, 1000.0)[key] > f(thin, 1000.0)[key], key
    assert surface_albedo(dense)[0] > surface_albedo(thin)[0]


@pytest.mark.parametrize("s, a", [(1e4, 0.0), (0.0, 1e4), (1e-6, 0.0), (0.0, 1e-6), (1e4, 1e-300),
                                  ((1e4, 1e-6, 5.0), (0.0, 0.0, 1e4))])
@pytest.mark.parametrize("scale", [1e-9, 1.0, 1e9])
def test_every_number_is_finite_at_the_extremes(s, a, scale):
    record = engine_materials(Material("x", s, a, 1.3), scale, 1e6)
    values = list(_numbers(record))
    assert values and all(math.isfinite(v) for v in values)
    assert GODOT_MIN_DEPTH <= record["godot4"]["subsurfScatterTransmittanceDepth"] <= FAR
    json.dumps(record, allow_nan=False)


def test_bad_scale_is_refused():
    with pytest.raises(ValueError, match="mm_per_unit"):
        openpbr_subsurface(preset("marble"), 0.0)


def test_a_bake_writes_the_materials_json(tmp_path):
    """A real small bake (samples/sphere.obj at 1 mm per unit) writes <stem>.materials.json beside the
    .glb, listed in its outputs, with the functions' values for its one translucent material."""
    from pathlib import Path

    from sssbake.pipeline.bake.asset import bake_asset
    from sssbake.pipeline.bake.cache import StageCache
    from sssbake.pipeline.options import BakeOptions

    sample = Path(__file__).resolve().parents[2] / "samples" / "sphere.obj"
    options = BakeOptions(scale_mm=1.0, techniques=(), validate=False, atlas_resolution=64)
    (tmp_path / "out").mkdir()
    result = bake_asset(sample, options, tmp_path / "out" / "ball", StageCache(tmp_path / "cache"))
    written = tmp_path / "out" / "ball.materials.json"
    assert written in result.outputs and written.is_file()
    doc = json.loads(written.read_text())
    assert doc["schema"] == 1 and doc["asset"] == "ball" and doc["scaleMm"] == 1.0
    ((name, record),) = doc["materials"].items()
    assert set(record) == {"measured", "unreal", "unityHdrp", "godot4", "openpbr", "khrMaterialsVolumeScatter"}
    marble = preset("marble")  # the default material
    expected = json.loads(json.dumps(engine_materials(marble, 1.0, record["unityHdrp"]["thicknessRemapMm"][1])))
    assert record == expected
    assert record["measured"]["sigmaSPrimePerMm"] == list(marble.sigma_s_prime)
    assert 15.0 < record["unityHdrp"]["thicknessRemapMm"][1] <= 20.0 + 1e-9  # the 20 mm sphere's thickest chord


def test_a_given_scale_overrides_the_files_unit_everywhere(tmp_path):
    """samples/candle.glb (glTF: metres) baked with scale_mm = 10: the mesh's scale, the .usdc's
    metersPerUnit and the materials JSON's lengths all take the given 10 mm per unit (the file's 1 m
    per unit in the .usdc and the JSON, beside 10 mm in the .glb, was a contradiction)."""
    from pathlib import Path

    from pxr import Usd, UsdGeom

    from sssbake.pipeline.bake.asset import bake_asset
    from sssbake.pipeline.bake.cache import StageCache
    from sssbake.pipeline.options import BakeOptions

    sample = Path(__file__).resolve().parents[2] / "samples" / "candle.glb"
    options = BakeOptions(scale_mm=10.0, techniques=(), validate=False, atlas_resolution=64)
    (tmp_path / "out").mkdir()
    bake_asset(sample, options, tmp_path / "out" / "candle", StageCache(tmp_path / "cache"))
    doc = json.loads((tmp_path / "out" / "candle.materials.json").read_text())
    assert doc["scaleMm"] == 10.0
    stage = Usd.Stage.Open(str(tmp_path / "out" / "candle.usdc"))
    assert UsdGeom.GetStageMetersPerUnit(stage) == pytest.approx(0.01, rel=1e-12)
    for record in doc["materials"].values():
        mfp = np.asarray(record["measured"]["meanFreePathMm"])
        # OpenPBR's radius is the longest mean free path in file units: mm / 10
        assert record["openpbr"]["subsurface_radius"] == pytest.approx(mfp.max() / 10.0, rel=1e-9)
