"""The stock-viewer check: pyrender's picture of an export, under verify's camera and light."""

import json
import shutil
from pathlib import Path

import numpy as np
import pygltflib
import pytest
import trimesh
from PIL import Image

from sssbake.pipeline.bake.asset import bake_asset
from sssbake.pipeline.bake.cache import StageCache
from sssbake.pipeline.cli import main
from sssbake.pipeline.mesh.load import load_scene
from sssbake.pipeline.options import BakeOptions
from sssbake.pipeline.render.renderer import Renderer, RenderLight, fit_camera
from sssbake.pipeline.render.stock_viewer import render_stock_viewer
from sssbake.pipeline.techniques.spectral.reader import read_spectral_glb
from sssbake.pipeline.verify.verify import DEFAULT_LIGHT

#: pyrender's dielectric: c_diff = (1 - 0.04) base colour, Schlick F0 = 0.04.
F0 = 0.04


def pyrender_radiance(base, nl, nv, nh, vh, roughness):
    """(3,) radiance per unit irradiance of pyrender 0.1.45's mesh.frag for a metallic 0 material:
    E n·l [(1 - F) 0.96 c / π + F G D / (4 n·l n·v + 0.001)], F = F0 + (1 - F0)(1 - v·h)⁵,
    D = r⁴ / (π ((n·h)² (r⁴ - 1) + 1)²) (GGX with α = r², r the roughness factor), G Smith-Schlick
    with k = (r + 1)² / 8. At r = 1 D = 1/π: facing the light and the eye, 0.9216 c / π + 0.0032,
    8 % below Lambert's c / π."""
    f = F0 + (1 - F0) * (1 - vh) ** 5
    a2 = roughness ** 4
    d = a2 / (np.pi * (nh * nh * (a2 - 1) + 1) ** 2)
    k = (roughness + 1) ** 2 / 8
    g = nv / (nv * (1 - k) + k) * nl / (nl * (1 - k) + k)
    return nl * ((1 - f) * (1 - F0) * np.asarray(base) / np.pi + f * g * d / (4 * nl * nv + 0.001))


def test_a_rough_sphere_shows_pyrender_s_brdf_at_the_pixel_facing_the_eye(tmp_path):
    ball = trimesh.creation.icosphere(subdivisions=4)
    ball.visual = trimesh.visual.TextureVisuals(material=trimesh.visual.material.PBRMaterial(
        baseColorFactor=[204, 153, 102, 255], metallicFactor=0.0, roughnessFactor=1.0))
    base = np.array([0.8, 0.6, 0.4])
    view = np.array([0.2, -0.5, -1.0])
    v = -view / np.linalg.norm(view)  # the centre pixel sees the point whose normal is v
    # and a box between it and the eye, which `only` leaves out as verify leaves out opaque parts
    box = trimesh.creation.box((0.3, 0.3, 0.3))
    box.apply_translation(1.6 * v)
    trimesh.Scene([ball, box]).export(tmp_path / "ball.glb")
    (sphere,) = [p.positions for m in load_scene(str(tmp_path / "ball.glb")).meshes for p in m.primitives
                 if len(p.positions) == len(ball.vertices)]
    camera = fit_camera(ball.vertices, view_dir=view)
    side = np.cross(v, [1.0, 0.0, 0.0])
    side /= np.linalg.norm(side)
    for tilt in (0.0, 60.0):  # the light at `tilt` from the normal: n·l = cos(tilt)
        t = np.radians(tilt)
        towards = v * np.cos(t) + np.cross(side, v) * np.sin(t)
        h = (towards + v) / np.linalg.norm(towards + v)
        want = pyrender_radiance(base, np.cos(t), 1.0, h @ v, h @ v, 1.0)
        # exposure 1: the 8-bit output as a viewer shows it; then exposed so the pixel reads ~0.9
        # (measured within 1.1 % and 0.6 %; plain Lambert c cos / π would be 8 % off)
        for exposure, tolerance in ((1.0, 0.015), (0.9 / (2.0 * want.max()), 0.008)):
            image, covered = render_stock_viewer(tmp_path / "ball.glb", camera, RenderLight(False, tuple(towards), 2.0),
                                                 64, exposure, only=[sphere])
            assert image.shape == (64, 64, 3) and image.dtype == np.float32 and covered[32, 32] and not covered[0, 0]
            assert np.allclose(image[31:33, 31:33].mean(axis=(0, 1)), 2.0 * want, rtol=tolerance)
    everything, _ = render_stock_viewer(tmp_path / "ball.glb", camera, RenderLight(False, tuple(v), 2.0), 64)
    assert not np.allclose(everything[31:33, 31:33].mean(axis=(0, 1)), 2.0 * pyrender_radiance(base, 1, 1, 1, 1, 1),
                           rtol=0.05)
    with pytest.raises(ValueError, match="has none of the primitives"):
        render_stock_viewer(tmp_path / "ball.glb", camera, RenderLight(), 8, only=[sphere[:10]])
    with pytest.raises(ValueError, match="does not exist"):
        render_stock_viewer(tmp_path / "none.glb", camera, RenderLight(), 8)


@pytest.fixture(scope="module")
def bumpy(tmp_path_factory):
    """A bumpy skin ball (as test_verify's) baked with spectral normals and the normals variant."""
    folder = tmp_path_factory.mktemp("bumpy")
    ball = trimesh.creation.icosphere(subdivisions=3)
    v = ball.vertices
    trimesh.Trimesh(v * (1 + 0.04 * np.sin(7 * v[:, 0]) * np.cos(5 * v[:, 1]))[:, None], ball.faces).export(
        folder / "bumpy.obj")
    options = BakeOptions(material="skin1", scale_mm=10.0, atlas_resolution=64, techniques=("spectral",),
                          spectral_variant=True, validate=False)
    bake_asset(folder / "bumpy.obj", options, folder / "bumpy", StageCache(None))
    return folder


def test_the_stock_picture_of_the_fallback_is_lambert_of_its_base_colour_and_the_variant_s_normals(bumpy):
    glb = bumpy / "bumpy.glb"
    prim = load_scene(str(glb)).meshes[0].primitives[0]
    base = np.array(pygltflib.GLTF2.load(str(glb)).materials[0].pbrMetallicRoughness.baseColorFactor[:3])
    camera = fit_camera(prim.positions)
    light = RenderLight(False, tuple(np.asarray(DEFAULT_LIGHT) / np.linalg.norm(DEFAULT_LIGHT)), 1.0)
    renderer = Renderer((96, 96))

    def lambert(normals):
        """verify's plain shader (albedo · cos / π, no shadows) with pyrender's diffuse albedo (1 - F0)² c."""
        item = dict(positions=prim.positions, normals=normals, faces=prim.faces, model=np.eye(4), eta=1.4,
                    albedo=(1 - F0) ** 2 * base)
        return renderer.render([item], camera, light)

    plain, plain_covered = lambert(prim.normals)
    spectral, _ = lambert(read_spectral_glb(glb)[(0, 0)])
    stock, covered = render_stock_viewer(glb, camera, light, 96, 7.0)
    variant, _ = render_stock_viewer(bumpy / "bumpy.sss_normals.glb", camera, light, 96, 7.0)
    # verify's camera: only silhouette pixels differ (pyrender resolves 4x multisampling; 33 of 2009)
    assert (covered ^ plain_covered).sum() < 0.03 * plain_covered.sum()
    # The fallback's base colour, channel by channel: the median ratio within 8 % of Lambert's
    # (measured 1.3, 2.0, 7.1 % with skin1's Monte Carlo totals, 1.1, 2.7, 3.7 % with the dipole's
    # brighter blue: the colourless specular lobe weighs most on the darkest channel; a base colour
    # read as sRGB would be 2-4x off)
    lit = covered & plain_covered & (plain.max(axis=-1) > 0.05)
    for image, model in ((stock, plain), (variant, spectral)):
        assert np.all(np.abs(np.median(image[lit] / model[lit], axis=0) - 1) < 0.08)
    # the moderngl renderer still draws after pyrender's contexts came and went
    assert np.array_equal(lambert(prim.normals)[0], plain)
    # the variant shades with other normals: its picture moves as much as Lambert's does (rms
    # 0.0031 against 0.0019: pyrender's shadow acne and highlight move with them too)
    moved, expected = variant[lit] - stock[lit], spectral[lit] - plain[lit]
    assert np.sqrt(np.mean(moved ** 2)) > 0.5 * np.sqrt(np.mean(expected ** 2)) > 0


def test_verify_reports_the_stock_viewer_beside_the_technique(bumpy, tmp_path, capsys):
    glb = bumpy / "bumpy.glb"
    assert main(["verify", str(glb), "--technique", "spectral", "--size", "96", "--frames", "2", "--stock-viewer",
                 "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert result["stock_variant"] == str(bumpy / "bumpy.sss_normals.glb")
    stock, variant = result["rmse_object_stock"], result["rmse_object_stock_variant"]
    assert np.isfinite(stock) and np.isfinite(variant) and stock != variant
    # unscaled, against the best-fit-scaled technique and Lambert: a viewer shows R_d as it is
    assert stock > result["rmse_object_lambert"] and len(result["stock_scale"]) == 3
    assert result["stock_seconds"] > 0
    with Image.open(result["pngs"]["stock"]) as png:  # reference | fallback | variant
        panels = np.asarray(png.convert("RGB")).reshape(96, 3, 96, 3)
    # the two pictures differ (mean 0.64 of 255 over the whole image, background included)
    assert png.size == (3 * 96, 96) and np.abs(panels[:, 1].astype(int) - panels[:, 2]).mean() > 0.2
    # without the variant: the fallback alone, and the text output says what is missing and why
    glb = Path(shutil.copy(glb, tmp_path))
    assert main(["verify", str(glb), "--technique", "spectral", "--size", "96", "--frames", "2", "--stock-viewer"]) == 0
    out = capsys.readouterr().out
    assert "stock viewer (pyrender, unscaled): RMSE object fallback" in out
    assert "no bumpy.sss_normals.glb (bake with --techniques spectral --spectral-variant)" in out
    assert main(["verify", str(glb), "--technique", "spectral", "--size", "96", "--frames", "2", "--stock-viewer",
                 "--json"]) == 0
    alone = json.loads(capsys.readouterr().out)
    assert alone["stock_variant"] is None and alone["rmse_object_stock_variant"] is None
    assert alone["rmse_object_stock"] == pytest.approx(stock, abs=1e-6)
    with Image.open(alone["pngs"]["stock"]) as png:
        assert png.size == (2 * 96, 96)
