"""The standard fallback's values (`pipeline.bake.fallback`) and how the glTF writer stores them."""

import io
import json
import shutil
from pathlib import Path

import numpy as np
import pygltflib
import pytest
from PIL import Image

from sssbake.pipeline.bake.batch import run_batch
from sssbake.pipeline.bake.fallback import diffuse_transmission_share, make_fallback, slab_totals
from sssbake.pipeline.config import load_config
from sssbake.pipeline.core.profile import classical_dipole, profile_for, total_reflectance
from sssbake.pipeline.core.materials import Material, preset


@pytest.mark.parametrize("model", ["montecarlo", "dipole"])
@pytest.mark.parametrize("name", ["marble", "skin1", "cream", "ketchup"])
def test_slab_limits(name, model):
    m = preset(name, model)
    p = profile_for(m)
    rd = total_reflectance(p)  # a thick slab reflects what the model's semi-infinite medium does
    thick = 200.0 / p.sigma_tr.min()
    r, t = slab_totals(m, thick)
    np.testing.assert_allclose(r, rd, rtol=1e-9)
    np.testing.assert_allclose(t, 0.0, atol=1e-12)
    r0, t0 = slab_totals(m, 0.0)  # nothing there: everything passes
    np.testing.assert_allclose(r0, 0.0, atol=1e-12)
    np.testing.assert_allclose(t0, 1.0, rtol=1e-12)
    ds = np.geomspace(0.01, 100.0, 40)
    rs, ts = np.array([slab_totals(m, d) for d in ds]).transpose(1, 0, 2)
    # thicker: transmits less; reflects at most a little over R_d (a source shallower than z_r
    # where d < 2 z_r); never more than comes in
    assert np.all(np.diff(ts, axis=0) <= 1e-12)
    assert np.all(rs <= rd + 0.01) and np.all(rs + ts <= 1.0 + 1e-12)


def test_slab_without_absorption_conserves_energy():
    # the closed-form image sums' σ → 0 limit: no loss, R + T = 1 at every thickness
    m = Material("white", (1.0, 2.0, 4.0), (0.0, 0.0, 0.0), 1.4, "dipole")
    for d in (0.05, 0.3, 1.0, 10.0, 1e3):
        r, t = slab_totals(m, d)
        np.testing.assert_allclose(r + t, 1.0, rtol=1e-9)
        assert np.all(t > 0)


def test_slab_matches_the_truncated_image_series():
    # the closed form against the multipole's image sum, truncated far out (absorbing medium)
    m = preset("skin1", "dipole")
    p = classical_dipole(m.sigma_s_prime, m.sigma_a, m.eta)
    (z_r, z_v), d = p.depth, 1.7
    z_b = 0.5 * (z_v - z_r)
    z_s = np.minimum(z_r, d / 2)
    period = 2 * (d + 2 * z_b)
    i = np.arange(-4000, 4001)[:, None]

    def pair(real, virtual):
        a, b = real + i * period, virtual + i * period
        return (np.sign(a) * np.exp(-p.sigma_tr * np.abs(a)) - np.sign(b) * np.exp(-p.sigma_tr * np.abs(b))).sum(0)

    w = -np.expm1(-d / z_r)
    r = w * 0.5 * p.alpha_prime * pair(z_s, -z_s - 2 * z_b)
    t = (1 - w) + w * 0.5 * p.alpha_prime * pair(d - z_s, d + z_s + 2 * z_b)
    got = slab_totals(m, d)
    np.testing.assert_allclose(got[0], r, rtol=1e-10)
    np.testing.assert_allclose(got[1], t, rtol=1e-10)


def test_fallback_matches_physics():
    m = preset("marble")
    fb = make_fallback(m, mm_per_unit=10.0, thickness_mm=np.array([10.0, 20.0, 30.0]), thickness_texture=None,
                       thickness_max_units=3.0)
    # Beer's law with σ_tr per file unit: -ln(c)/d = σ_tr · mm_per_unit; lengths in file units
    np.testing.assert_allclose(-np.log(fb.attenuation_color) / fb.attenuation_distance, m.sigma_tr * 10.0, rtol=1e-12)
    assert min(fb.attenuation_color) >= np.exp(-1) - 1e-12
    assert fb.ior == 1.5 and fb.thickness_factor == 3.0
    rd = total_reflectance(profile_for(m))
    np.testing.assert_allclose(fb.base_color, rd)
    # (1 - t) R_d is the least-squares fit of the median slab's reflectance
    r, t = slab_totals(m, 20.0)
    assert fb.transmission_factor == pytest.approx(1 - rd @ r / (rd @ rd), rel=1e-12)
    ts = np.linspace(0, 1, 2001)
    assert abs(ts[np.argmin([np.sum(((1 - x) * rd - r) ** 2) for x in ts])] - fb.transmission_factor) < 1e-3
    # the slab's transmittance is carried whole for sssbake's runtime, the diffuse lobe the share
    # `diffuse_transmission_share` picks: min(T, (1 - t) f) per channel
    np.testing.assert_allclose(fb.slab_transmittance, t, rtol=1e-12)
    keep, f = 1 - fb.transmission_factor, fb.diffuse_transmission_factor
    np.testing.assert_allclose(keep * f * np.asarray(fb.diffuse_transmission_color), np.minimum(t, keep * f),
                               rtol=1e-12)
    no_abs = make_fallback(preset("spectralon"), 1.0, np.array([1.0]), None, 1.0)
    assert all(np.isfinite(no_abs.attenuation_color)) and np.isfinite(no_abs.attenuation_distance)


def stops_error(f: float, transmit: np.ndarray, keep: float) -> float:
    """J(f) of `diffuse_transmission_share`, written out independently: per channel, the lit side
    a diffuse-transmission viewer shows over three.js' (1 - f) and the far side's keep·f·c over T
    with c ≤ 1, each in stops, squared and summed."""
    lit = np.full(3, np.log(1 - f))
    far = np.log(np.minimum(keep * f, transmit[transmit > 0]) / transmit[transmit > 0])
    return float(np.sum(lit ** 2) + np.sum(far ** 2))


def test_diffuse_transmission_share_minimises_the_error_in_stops():
    grid = np.linspace(1e-4, 1 - 1e-4, 20001)
    cases = [(np.array([0.531, 0.304, 0.098]), 0.769), (np.array([0.242, 0.443, 0.317]), 0.812),
             (np.array([0.9, 0.0, 0.0]), 1.0), (np.array([1e-6, 1e-6, 1e-6]), 0.5), (np.array([1.0, 1.0, 1.0]), 1.0)]
    for transmit, keep in cases:
        f, c = diffuse_transmission_share(transmit, keep)
        best = grid[np.argmin([stops_error(x, transmit, keep) for x in grid])]
        assert abs(f - best) < 1e-4, (transmit, keep, f, best)
        assert stops_error(f, transmit, keep) <= min(stops_error(f + e, transmit, keep) for e in (-1e-6, 1e-6))
        assert np.all((0 <= c) & (c <= 1)) and 0 < f < 1
        np.testing.assert_allclose(keep * f * c, np.minimum(transmit, keep * f), rtol=1e-12)
    # 2 mm of skin1 (the docstring's figures): the lit side keeps 0.64, red's far side 0.52 of T
    f, _ = diffuse_transmission_share(np.array([0.531, 0.304, 0.098]), 0.769)
    assert f == pytest.approx(0.359, abs=1e-3) and 0.769 * f / 0.531 == pytest.approx(0.52, abs=0.01)
    # nothing to carry, or nothing kept: no lobe
    assert diffuse_transmission_share(np.zeros(3), 0.8)[0] == 0.0
    assert diffuse_transmission_share(np.full(3, 0.5), 0.0)[0] == 0.0


def test_transmission_follows_thickness_not_units():
    m = preset("skin1")
    thin = make_fallback(m, 1.0, np.array([1.0]), None, 1.0)
    thick = make_fallback(m, 1.0, np.array([30.0]), None, 30.0)
    assert thin.transmission_factor > 0.3 and thick.transmission_factor < 1e-3
    # the same object in metres: the same transmission, lengths 1000 times smaller
    metres = make_fallback(m, 1000.0, np.array([1.0]), None, 0.001)
    assert metres.transmission_factor == pytest.approx(thin.transmission_factor, rel=1e-12)
    assert metres.attenuation_distance == pytest.approx(thin.attenuation_distance / 1000.0, rel=1e-12)
    # nothing baked: a semi-infinite medium, opaque
    none = make_fallback(m, 1.0, np.zeros(0), None, 1.0)
    assert none.transmission_factor == 0.0 and none.diffuse_transmission_factor == 0.0


def test_fallback_values_stay_in_range():
    rng = np.random.default_rng(3)
    for _ in range(200):
        st = rng.uniform(0.01, 50.0, 3)
        albedo = rng.uniform(0.0, 1.0, 3)
        m = Material("random", albedo * st, (1 - albedo) * st, float(rng.uniform(1.0, 2.0)))
        fb = make_fallback(m, float(rng.uniform(0.001, 1000.0)), rng.uniform(0.0, 50.0, 7), None, 1.0)
        values = [fb.transmission_factor, fb.diffuse_transmission_factor, *fb.diffuse_transmission_color,
                  *fb.base_color, *fb.attenuation_color]
        assert all(np.isfinite(v) and 0.0 <= v <= 1.0 for v in values), fb
        assert np.isfinite(fb.attenuation_distance) and fb.attenuation_distance > 0


def test_baked_file_carries_the_fallback(tmp_path):
    samples = Path(__file__).resolve().parents[2] / "samples"
    src = tmp_path / "in"
    src.mkdir()
    shutil.copy(samples / "thin_slab.stl", src)
    summary = run_batch([src], tmp_path / "out", load_config(samples / "sssbake.toml"),
                        {"techniques": ("none",), "atlas_resolution": 128}, cache_dir=None, progress=False)
    assert not summary["failed"], summary
    gltf = pygltflib.GLTF2.load(str(tmp_path / "out" / "thin_slab.glb"))
    report = json.loads((tmp_path / "out" / "thin_slab.report.json").read_text())
    validation = report["validation"]["gltf"]
    assert (validation["errors"], validation["warnings"]) == (0, 0), validation["messages"]
    assert "KHR_materials_transmission" in gltf.extensionsUsed
    assert "KHR_materials_transmission" not in (gltf.extensionsRequired or [])
    ext = gltf.materials[0].extensions
    fb = make_fallback(preset("skin1"), 1.0, np.array([2.0]), None, 1.0)  # the slab is 2 mm thick
    assert ext["KHR_materials_transmission"]["transmissionFactor"] == pytest.approx(fb.transmission_factor, rel=0.05)
    texture = gltf.textures[ext["KHR_materials_volume"]["thicknessTexture"]["index"]]
    sampler = gltf.samplers[texture.sampler]
    assert (sampler.magFilter, sampler.minFilter) == (9729, 9729)  # LINEAR / LINEAR: no mips to blend charts
    view = gltf.bufferViews[gltf.images[texture.source].bufferView]
    blob = gltf.binary_blob()[view.byteOffset or 0:][:view.byteLength]
    width, height = Image.open(io.BytesIO(blob)).size
    atlas = report["atlas"]["thin_slab.stl"]
    assert (width, height) == (atlas["width"], atlas["height"]) and width % 4 == 0 and height % 4 == 0
