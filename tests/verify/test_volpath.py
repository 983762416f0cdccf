"""verify --reference volpath: Mitsuba 3's volumetric path tracer as the physical ground truth.

The tests that render need Mitsuba (the ``physics`` extra, which CI installs) and skip only where it
cannot be imported; the others run everywhere.
"""

import json
import sys
from pathlib import Path

import numpy as np
import pytest
import trimesh
from generate import generate

from sssbake.pipeline.bake.cache import StageCache
from sssbake.pipeline.cli import main
from sssbake.pipeline.core.fresnel import fresnel_transmittance
from sssbake.pipeline.core.materials import Material, preset
from sssbake.pipeline.core.profile import exit_normalisation, profile_for, total_reflectance
from sssbake.pipeline.render.renderer import Renderer, fit_camera
from sssbake.pipeline.verify import volpath
from sssbake.pipeline.verify.volpath import Body, Lobe, View, lobe_image, render_truth, truth_key


@pytest.fixture
def mitsuba():
    """Mitsuba in the truth's variant; the test skips where the package cannot be imported."""
    volpath.prefer_debian_llvm()  # before drjit's import picks a libLLVM
    pytest.importorskip("mitsuba")
    return volpath.load_mitsuba()


def box_body(material: Material, width: float, thickness: float) -> Body:
    """A width × width × thickness box of `material` with its top face at z = 0, flat-shaded
    (each face its own vertices and normal: interpolated corner normals would tilt the faces)."""
    box = trimesh.creation.box(extents=(width, width, thickness))
    box.apply_translation((0.0, 0.0, -thickness / 2))
    box.unmerge_vertices()
    return Body(np.asarray(box.vertices), np.repeat(box.face_normals, 3, axis=0), np.asarray(box.faces), material, 1.0)


def test_without_mitsuba_verify_says_how_to_install_it(tmp_path, monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, "mitsuba", None)  # `import mitsuba` raises ImportError
    assert main(["verify", str(tmp_path / "x.glb"), "--reference", "volpath"]) == 1
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err
    assert "pip install 'sssbake[physics]'" in err and "apt-get install libllvm19" in err


def test_lobe_quadrature_holds_the_lobe():
    lobe = Lobe(tuple(np.array([0.4, 0.8, 0.45]) / np.linalg.norm([0.4, 0.8, 0.45])))
    directions, weights = lobe.quadrature()
    assert directions.shape == (48, 3) and np.allclose(np.linalg.norm(directions, axis=1), 1.0)
    mu = directions @ np.asarray(lobe.direction)
    assert np.all(mu > 0)
    assert np.isclose(weights.sum(), 6 / 5)  # ∫ L dω = 2π L0 / (n+1), L0 = (n+2)/(2π)
    # unit irradiance on a surface facing the lobe, as verify's directional light gives
    assert np.isclose(np.sum(weights * mu), 1.0)
    # Mitsuba's envmap layout: texel (u, v) looks along (sin 2πu sin πv, cos πv, -cos 2πu sin πv)
    image = lobe.envmap(64)
    assert image.shape == (64, 128) and image.dtype == np.float32 and np.all(image >= 0)
    v, u = np.unravel_index(np.argmax(image), image.shape)
    theta, phi = np.pi * (v + 0.5) / 64, 2 * np.pi * (u + 0.5) / 128
    peak = np.array([np.sin(phi) * np.sin(theta), np.cos(theta), -np.cos(phi) * np.sin(theta)])
    assert peak @ np.asarray(lobe.direction) > np.cos(np.radians(4))


def test_view_is_verify_camera():
    points = np.random.default_rng(1).normal(size=(50, 3)) * [3.0, 1.0, 2.0] + [10.0, -4.0, 2.0]
    camera = fit_camera(points)
    view = View.of(camera, 64)
    # project with the GL matrix and with the pinhole: the same image coordinates
    clip = np.c_[points, np.ones(len(points))] @ camera.view_projection.T
    ndc = clip[:, :2] / clip[:, 3:]
    forward, up = np.asarray(view.forward), np.asarray(view.up)
    right = np.cross(forward, up)
    rel = points - np.asarray(view.eye)
    depth = rel @ forward
    tan = np.tan(np.radians(view.fov_degrees) / 2)
    assert np.allclose(np.c_[rel @ right, rel @ up] / (depth[:, None] * tan), ndc, atol=1e-9)
    assert 0 < view.near < depth.min() and depth.max() < view.far


def test_truth_key_follows_what_the_truth_depends_on():
    marble = preset("marble")
    body = box_body(marble, 10.0, 5.0)
    view = View((0.0, 0.0, 30.0), (0.0, 0.0, -1.0), (0.0, 1.0, 0.0), 30.0, 1.0, 100.0, 16)
    lobe = Lobe((0.0, 0.0, 1.0))
    key = truth_key([body], view, lobe, 64, "3.9.1")
    renamed = Body(body.positions, body.normals, body.faces, Material("stone", marble.sigma_s_prime, marble.sigma_a,
                                                                     marble.eta), 1.0)
    assert truth_key([renamed], view, lobe, 64, "3.9.1") == key  # names do not change the physics
    moved = Body(body.positions + 1e-6, body.normals, body.faces, marble, 1.0)
    changed = [truth_key([body], view, lobe, 32, "3.9.1"), truth_key([body], view, lobe, 64, "3.9.2"),
               truth_key([body], view, Lobe((0.0, 0.6, 0.8)), 64, "3.9.1"),
               truth_key([moved], view, lobe, 64, "3.9.1"),
               truth_key([Body(body.positions, body.normals, body.faces, marble, 2.0)], view, lobe, 64, "3.9.1"),
               truth_key([Body(body.positions, body.normals, body.faces, preset("skin1"), 1.0)], view, lobe, 64,
                         "3.9.1")]
    assert len({key, *changed}) == 7


def test_semi_infinite_slab_reflects_the_profiles_total(mitsuba, tmp_path):
    """A flat skin1 box, 200 mm wide and 60 mm deep (16 diffusion lengths: semi-infinite), lit by the
    cos⁴ lobe around its normal and seen at 30° from it, against the profile's closed form

        L_o = E_t · R_tot · F_t(η, cos θ_o) / (π c(η)),   E_t = ∫ L(ω) F_t(η, cos θ) cos θ dω,

    R_tot = `total_reflectance` (the share of the entered light that leaves) and c(η) =
    `exit_normalisation`. Tolerance: three standard errors of the truth's mean (from its two halves,
    ~1 % per channel) plus 5 % for the directional model: the exit radiance of a random walk at 30°
    is 2-6 % under F_t/c's shape at skin1's albedos, and the lobe's oblique light, which enters
    shallower, gives 1-5 % back (measured against the walk: 0.99 in all three channels).
    """
    skin = preset("skin1")
    theta = np.radians(30.0)
    eye = 50.0 * np.array([np.sin(theta), 0.0, np.cos(theta)])
    view = View(tuple(eye), tuple(-eye / 50.0), (0.0, 1.0, 0.0), 4.0, 1.0, 1000.0, 8)
    lobe = Lobe((0.0, 0.0, 1.0))
    cache = StageCache(tmp_path / "cache")
    truth, cached = render_truth([box_body(skin, 200.0, 60.0)], view, lobe, 512, cache)
    assert not cached and truth.halves.shape == (2, 8, 8, 3) and np.all(np.isfinite(truth.halves))
    measured = truth.image.reshape(-1, 3).mean(axis=0)
    a, b = truth.halves
    error = (a - b).reshape(-1, 3).std(axis=0) / 2 / np.sqrt(64)  # standard error of the pixels' mean
    directions, weights = lobe.quadrature(64, 16)
    mu = directions[:, 2]
    entered = np.sum(weights * fresnel_transmittance(skin.eta, mu) * mu)
    predicted = (entered * total_reflectance(profile_for(skin)) * fresnel_transmittance(skin.eta, np.cos(theta))
                 / (np.pi * exit_normalisation(skin.eta)))
    assert np.all(np.abs(measured / predicted - 1.0) < 0.05 + 3 * error / predicted), (measured, predicted, error)
    # the mirror reflection was taken out: F(η, 30°) ≈ 3 % of the lobe's radiance there
    assert np.allclose(truth.specular.mean(axis=(0, 1)), truth.specular.mean(), rtol=1e-6)
    assert 0.3 * lobe.radiance(eye / 50.0) * (1 - fresnel_transmittance(skin.eta, np.cos(theta))) \
        < truth.specular.mean() < 3 * lobe.radiance(eye / 50.0) * (1 - fresnel_transmittance(skin.eta, np.cos(theta)))
    again, cached = render_truth([box_body(skin, 200.0, 60.0)], view, lobe, 512, cache)
    assert cached and np.array_equal(again.halves, truth.halves)


def test_truth_lines_up_with_verify_camera(mitsuba):
    """A sphere lit from the side: volpath's image and verify's (GL) Lambert under the same lobe
    have their light in the same place (a mirrored or turned camera would move it across)."""
    sphere = trimesh.creation.icosphere(subdivisions=3, radius=10.0)
    body = Body(np.asarray(sphere.vertices), np.asarray(sphere.vertex_normals), np.asarray(sphere.faces),
                preset("skin1"), 1.0)
    camera = fit_camera(body.positions)
    lobe = Lobe(tuple(np.array([1.0, 0.5, 0.3]) / np.linalg.norm([1.0, 0.5, 0.3])))
    truth, _ = render_truth([body], View.of(camera, 32), lobe, 16)
    directions, weights = lobe.quadrature()
    q = np.clip(body.normals @ directions.T, 0.0, None) @ weights  # a convex body: no shadows
    item = {"positions": body.positions, "normals": body.normals, "faces": body.faces, "model": np.eye(4),
            "eta": 1.0, "q": np.repeat(q[:, None], 3, axis=1)}
    lambert, covered = lobe_image(Renderer((32, 32)), [item], camera, directions, weights)
    rows, cols = np.mgrid[:32, :32]

    def centroid(image):
        weight = np.where(covered, image.sum(axis=-1), 0.0)
        return np.array([(weight * rows).sum(), (weight * cols).sum()]) / weight.sum()

    assert np.linalg.norm(centroid(truth.image) - centroid(lambert)) < 1.0
    assert np.linalg.norm(centroid(lambert) - [15.5, 15.5]) > 3.0  # the light is off-centre


def test_sphere_against_volpath_end_to_end(mitsuba, tmp_path, capsys):
    src = tmp_path / "in"
    generate(src)
    out = tmp_path / "out"
    assert main(["bake", str(src / "sphere.obj"), "-o", str(out), "--config", str(src / "sssbake.toml"),
                 "--techniques", "prt", "--prt-directions", "100", "-q"]) == 0
    capsys.readouterr()
    glb = str(out / "sphere.glb")
    args = ["verify", glb, "--reference", "volpath", "--size", "40", "--spp", "8", "--cache-dir", str(tmp_path / "c")]
    assert main([*args, "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert result["reference"] == "volpath" and result["specular"] == "subtracted from the truth"
    assert result["lobe_exponent"] == 4 and result["lobe_directions"] == 48 and not result["truth_cached"]
    assert result["pixels"] > 250 and result["image_size"] == [40, 40]
    assert 0 < result["noise_floor"] < 1 and 0 < result["specular_share"] < 0.2
    for key in ("rmse_relative", "rmse_relative_fitted", "rmse_relative_lambert", "rmse_relative_lambert_fitted"):
        assert result["noise_floor"] * 0.9 < result[key] < 1.0, key  # nothing beats the truth's own noise
        assert 0 <= result["rmse_relative_denoised"][key] < result[key]
    # the level is within reason: millimetres, the lobe's irradiance and the exit Fresnel line up
    assert all(0.6 < s < 1.6 for s in result["technique_scale"] + result["lambert_scale"])
    assert set(result["lambert_albedo"]) == {"marble"}
    # the fallback's figure, and every error read per block and per visible vertex with its own floor
    assert result["noise_floor"] * 0.9 < result["rmse_relative_fallback"] < 1.0
    block, vertex = result["measures"]["block"], result["measures"]["vertex"]
    assert 0 < block["noise_floor"] < result["noise_floor"]  # blocks average the truth's noise down
    assert 0 < block["samples"] < result["pixels"] and 0 < vertex["samples"] < 642
    for m in (block, vertex):
        assert set(m["rmse_relative"]) == {"rmse_relative", "rmse_relative_fitted", "rmse_relative_lambert",
                                           "rmse_relative_lambert_fitted", "rmse_relative_fallback"}
        assert all(0 <= m["rmse_relative_denoised"][k] <= v < 1.0 for k, v in m["rmse_relative"].items())
    assert np.allclose(result["lambert_albedo"]["marble"], total_reflectance(profile_for(preset("marble"))))
    assert all(Path(p).stat().st_size > 0 for p in result["pngs"].values())
    # the truth comes from the cache the second time; the text output says what was done
    assert main(args) == 0
    line = capsys.readouterr().out
    assert "from the cache" in line and "mirror reflection subtracted from the truth" in line
    assert f"relative RMSE (beyond the noise) {result['rmse_relative']:.3g} (" in line
    assert main([*args, "--light-pos", "20,20,20"]) == 1
    assert "not a point light" in capsys.readouterr().err
