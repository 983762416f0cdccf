"""The three.js runtime's surface terms beyond the moderngl runtime, in headless Chromium: every mode
keeps the glTF material's base-colour texture; screen adds the light a thin part transmits from
behind (the slab transmittance the bake writes); the fallback mode draws what three.js draws of the
file without the plugin. One page renders every job (``render.js``); the figures are printed."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pygltflib
import pytest

from sssbake.pipeline.bake.fallback import slab_totals
from sssbake.pipeline.core.materials import Material
from sssbake.pipeline.mesh.load import load_scene
from sssbake.pipeline.render.renderer import DEFAULT_LIGHT
from tests.browser import have_chromium
from tests.gltf_corpus import GltfBuilder, _material, _mesh, _scene, box24, png
from tests.runtime_three.test_runtime_three import REPO, camera_json, three_results, world_points

#: sRGB bytes of the checker's light and dark texels and their decoded (linear) albedos.
TEXELS = (230, 40)
ALBEDOS = tuple(((b / 255 + 0.055) / 1.055) ** 2.4 for b in TEXELS)  # 0.7913, 0.0212
NEAREST = 9728
#: Seen from above, lit from below and to the side: the thin slab's visible face is back-lit.
SLAB_VIEW = (0.3, -1.0, 0.2)
SLAB_LIGHT = (0.3, -1.0, -0.4)
TEXTURED_MODES = ["prt", "spectral", "screen", "plain", "fallback"]
#: Largest relative RMSE of the runtime's fallback mode against three's own render of the file.
#: Both are MeshPhysicalMaterial under the same DirectionalLight in one renderer; the runtime only
#: swaps materials and geometry on and off around its draws, so anything above float rounding
#: means it left state behind (a geometry, a light, a material). Measured 0 for the textured cube and the thin slab.
STOCK_TOLERANCE = 1e-4

pytestmark = pytest.mark.skipif(not have_chromium(), reason="needs chromium, node and puppeteer-core (.ci/setup)")


def textured_cube(path) -> None:
    """A 10 mm box (BoxTextured's layout) whose base-colour texture is a 2 × 2 grey checker of
    `TEXELS`, sampled NEAREST: every pixel of a face lies under one texel."""
    texels = np.array([[TEXELS[0], TEXELS[1]], [TEXELS[1], TEXELS[0]]], np.uint8)
    b = GltfBuilder()
    image = b.add("images", {"bufferView": b.view(png(np.repeat(texels[..., None], 3, axis=-1))), "mimeType": "image/png"})
    sampler = b.add("samplers", {"magFilter": NEAREST, "minFilter": NEAREST})
    _material(b, texture=b.add("textures", {"sampler": sampler, "source": image}))
    _mesh(b, box24(10.0))
    _scene(b, [{"name": "Box", "mesh": 0}])
    path.write_bytes(b.glb())


def untextured(source, out):
    """`source` without its base-colour texture (its factor kept)."""
    gltf = pygltflib.GLTF2.load(str(source))
    for material in gltf.materials:
        material.pbrMetallicRoughness.baseColorTexture = None
    gltf.save_binary(str(out))
    return out


@pytest.fixture(scope="module")
def rendered(tmp_path_factory):
    """The baked cube (textured and not) and thin slab, and the page's images of each job."""
    tmp = tmp_path_factory.mktemp("three_surface")
    textured_cube(tmp / "cube.glb")
    run = subprocess.run([sys.executable, "-m", "sssbake.pipeline.cli", "bake", str(tmp / "cube.glb"),
                          str(REPO / "samples" / "thin_slab.stl"), "-o", str(tmp / "out"), "--config",
                          str(REPO / "samples" / "sssbake.toml"), "--techniques", "prt,spectral,screen"],
                         capture_output=True, cwd=REPO)
    assert run.returncode == 0, run.stderr.decode()[-2000:]
    files = {"cube.glb": tmp / "out" / "cube.glb", "plain_cube.glb": untextured(tmp / "out" / "cube.glb", tmp / "plain.glb"),
             "slab.glb": tmp / "out" / "thin_slab.glb"}
    cube = camera_json(world_points(load_scene(str(files["cube.glb"]))))
    slab = camera_json(world_points(load_scene(str(files["slab.glb"]))), SLAB_VIEW)
    jobs = {
        "cube": {"glb": "/cube.glb", "modes": TEXTURED_MODES, "camera": cube, "light": list(DEFAULT_LIGHT), "stock": True},
        "plain_cube": {"glb": "/plain_cube.glb", "modes": TEXTURED_MODES, "camera": cube, "light": list(DEFAULT_LIGHT)},
        "slab": {"glb": "/slab.glb", "modes": ["screen", "plain", "fallback"], "camera": slab, "light": list(SLAB_LIGHT),
                 "stock": True},
        "slab_reflection": {"glb": "/slab.glb", "modes": ["screen"], "camera": slab, "light": list(SLAB_LIGHT),
                            "options": {"screen": {"transmission": False}}},
    }
    results = three_results(tmp, files, list(jobs.values()))
    for result in results:
        assert "error" not in result, result
    return files, {name: result["images"] for name, result in zip(jobs, results)}


def test_every_mode_keeps_the_base_colour_texture(rendered):
    """Textured over untextured, pixel by pixel: the decoded texel under the pixel, exactly, in every
    sssbake mode (the texture multiplies the scattered and the Lambertian term where light leaves,
    and the lighting is otherwise the same); the fallback's ratio is three's own (its specular lobe
    is not textured) and must still separate the two texels."""
    _, images = rendered
    figures = {}
    for mode in TEXTURED_MODES:
        textured, plain = images["cube"][mode], images["plain_cube"][mode]
        lit = plain.min(axis=-1) > 0.02 * plain.max()
        ratio = textured[lit] / plain[lit]
        light = np.all(ratio > 0.3, axis=-1)
        figures[mode] = (float(np.median(ratio[light])), float(np.median(ratio[~light])), float(light.mean()))
        # both texels are on screen (the checker covers each face half and half)
        assert 0.3 < light.mean() < 0.7, (mode, figures[mode])
        if mode == "fallback":
            assert figures[mode][0] / figures[mode][1] > 5, figures
            continue
        # sRGB decoded: undecoded bytes would give 0.902 and 0.157
        assert np.allclose(ratio[light], ALBEDOS[0], rtol=0.01), (mode, figures[mode])
        assert np.allclose(ratio[~light], ALBEDOS[1], rtol=0.01), (mode, figures[mode])
    print("texture ratio (light, dark, share light) per mode:", {m: tuple(round(v, 4) for v in f) for m, f in figures.items()})


def fallback_transmittance(path) -> tuple[np.ndarray, np.ndarray, float, np.ndarray]:
    """The slab transmittance T(d) the file carries (checked against the multipole model at the
    median d here), σ_tr = sqrt(3 σ_a σ'_t) (1/mm) of its medium, the median baked thickness d (mm)
    and the per-vertex thickness, as read back with pygltflib."""
    gltf = pygltflib.GLTF2.load(str(path))
    sss = gltf.materials[0].extensions["SSSBAKE_subsurface"]
    medium = sss["material"]
    absorb, scatter = np.asarray(medium["sigma_a"]), np.asarray(medium["sigma_s_prime"])
    sigma = np.sqrt(3 * absorb * (absorb + scatter))
    transmit = np.asarray(sss["slabTransmittance"])
    thickness = load_scene(str(path)).meshes[0].primitives[0]
    accessor = gltf.accessors[gltf.meshes[0].primitives[0].attributes._THICKNESS]
    view = gltf.bufferViews[accessor.bufferView]
    blob = gltf.binary_blob()
    start = (view.byteOffset or 0) + (accessor.byteOffset or 0)
    values = np.frombuffer(blob[start:start + 12 * accessor.count], np.float32).reshape(-1, 3)[:, 0]
    assert len(values) == len(thickness.positions)
    material = Material(medium["name"], scatter, absorb, medium["eta"], medium["profile"])
    np.testing.assert_allclose(transmit, slab_totals(material, float(np.median(values)))[1], rtol=1e-5)
    return transmit, sigma, float(np.median(values)), values


def test_screen_transmits_through_the_back_lit_thin_slab(rendered):
    """The slab (2 mm of skin1) lit from behind: screen with its transmission is brighter than plain
    (black: Lambert sees no light) and than screen without it; what it adds at the visible face is
    the fallback's diffuse transmission T(d) cos / π with cos = -n·l (the face's thickness is the
    median d, where e^(-σ_tr (x - d)) = 1), per channel, red passing most."""
    files, images = rendered
    screen, plain, reflection = images["slab"]["screen"], images["slab"]["plain"], images["slab_reflection"]["screen"]
    covered = screen.sum(axis=-1) > 0
    transmit, sigma, median, thickness = fallback_transmittance(files["slab.glb"])
    assert np.mean(np.abs(thickness - 2.0) < 1e-3) > 0.5 and abs(median - 2.0) < 1e-3  # the faces' vertices: 2 mm
    added = (screen - reflection)[covered]
    cos = -np.dot((0.0, 1.0, 0.0), SLAB_LIGHT) / np.linalg.norm(SLAB_LIGHT)
    measured = np.median(added, axis=0) * np.pi / cos
    means = {name: float(image[covered].mean()) for name, image in
             (("screen", screen), ("plain", plain), ("screen without transmission", reflection))}
    print("back-lit slab mean linear radiance:", {k: round(v, 5) for k, v in means.items()},
          "T measured", measured.round(4), "fallback T(d)", transmit.round(4), "σ_tr", sigma.round(3))
    assert means["screen"] > 2 * means["screen without transmission"] and means["screen"] > 2 * means["plain"]
    assert np.allclose(measured, transmit, rtol=0.01), (measured, transmit)
    assert measured[0] > measured[1] > measured[2]


def test_fallback_mode_matches_three_without_the_plugin(rendered):
    """The runtime's fallback mode against three.js's GLTFLoader + MeshPhysicalMaterial render of
    the same file (no plugin), same page, camera and light: relative RMSE of the linear images."""
    _, images = rendered
    figures = {}
    for name in ("cube", "slab"):
        fallback, stock = images[name]["fallback"], images[name]["stock"]
        assert stock.sum(axis=-1).astype(bool).mean() > 0.05  # three drew the object
        figures[name] = float(np.sqrt(np.mean((fallback - stock) ** 2) / np.mean(stock ** 2)))
    print("fallback vs three.js without the plugin, relative RMSE:", figures)
    assert max(figures.values()) < STOCK_TOLERANCE, figures
