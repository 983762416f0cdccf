"""The three.js runtime applies the glTF material's normal map in its modes, in headless Chromium,
against closed forms.

A flat 20 mm quad (normal +z, u along +x, v along -y: an isotropic UV map, so the derivative tangent
frame of surface_maps_frag.glsl is orthonormal) is baked with prt, spectral and screen, then given
a constant normal map after the bake (the baked data of every variant is the same bytes): one that
tilts the normal by +THETA about y (towards the light), one by -THETA, and the texel nearest to the
flat (0.5, 0.5, 1). Each is drawn by ``render.js`` under a directional light at THETA_LIGHT from
the normal in the x-z plane, and divided pixel by pixel by the quad without a normal map. With the
texel's decoded tangent-space normal m (bytes / 255 * 2 - 1, as the sampler reads them; glTF's
tangent space is u, up the image, n: here x, y, z) the mapped normal is n' = m / |m| and the ratios
are, per mode (directional light, constant normals: no other term changes):

- plain, spectral (Lambert, specular 0; the quad's baked spectral normals are +z):
  max(0, n'.l) / max(0, n.l), which is cos(THETA_LIGHT - THETA) / cos(THETA_LIGHT) for an exact tilt;
- prt (the scattered light is per vertex; the map changes the Fresnel transmittance out towards
  the eye): F_t(eta, n'.v) / F_t(eta, n.v), v per pixel;
- screen (the G-buffer's irradiance entering is F_t(eta, n'.l) n'.l, the same factor at every
  pixel, so the gathered light scales by it; then the way out as prt):
  F_t(eta, n'.l) n'.l / (F_t(eta, n.l) n.l) * F_t(eta, n'.v) / F_t(eta, n.v).

The fallback mode is three.js' own MeshPhysicalMaterial (its normal map is three's): not held here.
"""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pygltflib
import pytest

from sssbake.pipeline.core.fresnel import fresnel_transmittance
from sssbake.pipeline.mesh.load import load_scene
from tests.browser import have_chromium
from tests.gltf_corpus import GltfBuilder, _material, _mesh, _scene, png
from tests.runtime_three.test_runtime_three import REPO, SIZE, camera_json, three_results, world_points

THETA = 25.0        # degrees the maps tilt the normal, about y
THETA_LIGHT = 40.0  # the light's angle from the quad's normal, towards +x
VIEW_ANGLE = 45.0   # the camera looks at the quad from -x, this far from its normal
HALF = 10.0         # mm
MODES = ["plain", "spectral", "prt", "screen"]
#: Largest |measured / closed form - 1| over the quad's pixels. The two images differ only in the
#: normal the fragment shader builds from the map, rendered into float targets: plain and spectral
#: measured <= 1.6e-5 (float rounding of the screen derivatives). prt and screen also carry the
#: closed form's v, the ray through the pixel's centre: 2.2e-4 measured at the +THETA map, where
#: n'.v = cos 70 deg and F_t is steepest (elsewhere <= 2e-5). 1e-3 stays below the 0.33 % that
#: the flat texel's 1/255 offset from (0.5, 0.5, 1) makes in plain, so the test resolves that offset.
TOLERANCE = 1e-3

pytestmark = pytest.mark.skipif(not have_chromium(), reason="needs chromium, node and puppeteer-core (.ci/setup)")


def texel(theta_deg: float | None) -> np.ndarray:
    """The RGB bytes of a tangent-space normal tilted by `theta_deg` about y (None: the flat (0.5, 0.5, 1))."""
    if theta_deg is None:
        return np.array([128, 128, 255], np.uint8)
    t = np.radians(theta_deg)
    return np.round((np.array([np.sin(t), 0.0, np.cos(t)]) + 1) / 2 * 255).astype(np.uint8)


def decoded(rgb: np.ndarray) -> np.ndarray:
    """The unit normal the runtime builds from texel `rgb` on this quad: m = bytes / 255 * 2 - 1 in
    (u, up, n) = (x, y, z), normalised."""
    m = rgb.astype(np.float64) / 255 * 2 - 1
    return m / np.linalg.norm(m)


def quad(path) -> None:
    """The 9 x 9 vertex quad, z = 0, facing +z."""
    xs = np.linspace(-HALF, HALF, 9)
    x, y = np.meshgrid(xs, xs, indexing="xy")
    positions = np.stack([x.ravel(), y.ravel(), np.zeros(x.size)], -1).astype(np.float32)
    uvs = np.stack([(positions[:, 0] + HALF) / (2 * HALF), (HALF - positions[:, 1]) / (2 * HALF)], -1)
    faces = [[a, a + 1, a + 10] for a in (i * 9 + j for i in range(8) for j in range(8))]
    faces += [[a, a + 10, a + 9] for a in (i * 9 + j for i in range(8) for j in range(8))]
    b = GltfBuilder()
    _material(b)
    _mesh(b, {"positions": positions, "normals": np.tile(np.float32([0, 0, 1]), (len(positions), 1)),
              "uvs": uvs.astype(np.float32), "faces": np.array(faces, np.uint16)})
    _scene(b, [{"name": "Quad", "mesh": 0}])
    path.write_bytes(b.glb())


def with_normal_map(source, out, rgb: np.ndarray) -> None:
    """`source` (baked) whose material gets a 4 x 4 normal map of the constant texel `rgb`."""
    gltf = pygltflib.GLTF2.load(str(source))
    blob = bytearray(gltf.binary_blob())
    blob += b"\0" * (-len(blob) % 4)
    data = png(np.tile(rgb, (4, 4, 1)))
    gltf.bufferViews.append(pygltflib.BufferView(buffer=0, byteOffset=len(blob), byteLength=len(data)))
    blob += data
    gltf.buffers[0].byteLength = len(blob)
    gltf.images.append(pygltflib.Image(bufferView=len(gltf.bufferViews) - 1, mimeType="image/png"))
    gltf.samplers.append(pygltflib.Sampler(magFilter=9729, minFilter=9987))
    gltf.textures.append(pygltflib.Texture(sampler=len(gltf.samplers) - 1, source=len(gltf.images) - 1))
    gltf.materials[0].normalTexture = pygltflib.NormalMaterialTexture(index=len(gltf.textures) - 1)
    gltf.set_binary_blob(bytes(blob))
    gltf.save_binary(str(out))


def pixel_views(camera: dict) -> np.ndarray:
    """(SIZE, SIZE, 3) unit vectors from the quad (z = 0) towards the eye through each pixel's
    centre, row 0 at the top (three's PerspectiveCamera.lookAt with up +y, square, vertical fov)."""
    eye, target = np.asarray(camera["eye"]), np.asarray(camera["target"])
    forward = (target - eye) / np.linalg.norm(target - eye)
    right = np.cross(forward, (0.0, 1.0, 0.0))
    right /= np.linalg.norm(right)
    up = np.cross(right, forward)
    ndc = (np.arange(SIZE) + 0.5) / SIZE * 2 - 1
    half = np.tan(np.radians(camera["fov"]) / 2)
    rays = forward + half * (ndc[None, :, None] * right + -ndc[:, None, None] * up)
    hits = eye - rays * (eye[2] / rays[..., 2])[..., None]
    towards = eye - hits
    return towards / np.linalg.norm(towards, axis=-1, keepdims=True)


def closed_form(mode: str, normal: np.ndarray, light: np.ndarray, views: np.ndarray, eta: float) -> np.ndarray:
    """The mapped / unmapped ratio of `mode` per pixel (see the module's docstring)."""
    flat = np.array([0.0, 0.0, 1.0])
    cos_l, cos_l_mapped = float(flat @ light), float(normal @ light)
    lambert = max(cos_l_mapped, 0.0) / cos_l
    out = fresnel_transmittance(eta, np.clip(views @ normal, 0, 1)) / fresnel_transmittance(eta, views @ flat)
    if mode in ("plain", "spectral"):
        return np.full(views.shape[:2], lambert)
    if mode == "prt":
        return out
    return lambert * fresnel_transmittance(eta, cos_l_mapped) / fresnel_transmittance(eta, cos_l) * out


MAPS = {"tilt_plus": THETA, "tilt_minus": -THETA, "flat": None}


@pytest.fixture(scope="module")
def rendered(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("three_normal_map")
    quad(tmp / "quad.glb")
    run = subprocess.run([sys.executable, "-m", "sssbake.pipeline.cli", "bake", str(tmp / "quad.glb"), "-o",
                          str(tmp / "out"), "--config", str(REPO / "samples" / "sssbake.toml"), "--techniques",
                          "prt,spectral,screen", "-q"], capture_output=True, cwd=REPO)
    assert run.returncode == 0, run.stderr.decode()[-2000:]
    baked = tmp / "out" / "quad.glb"
    gltf = pygltflib.GLTF2.load(str(baked))
    # the runtime draws a normal map only where the primitive has its texture coordinates
    assert gltf.meshes[0].primitives[0].attributes.TEXCOORD_0 is not None
    eta = gltf.materials[0].extensions["SSSBAKE_subsurface"]["material"]["eta"]
    files = {"none.glb": baked}
    for name, theta in MAPS.items():
        with_normal_map(baked, tmp / f"{name}.glb", texel(theta))
        files[f"{name}.glb"] = tmp / f"{name}.glb"
    t, v = np.radians(THETA_LIGHT), np.radians(VIEW_ANGLE)
    light = np.array([np.sin(t), 0.0, np.cos(t)])
    camera = camera_json(world_points(load_scene(str(baked))), (np.sin(v), 0.0, -np.cos(v)))
    jobs = [{"glb": f"/{name}", "modes": MODES, "camera": camera, "light": light.tolist()} for name in files]
    results = three_results(tmp, files, jobs)
    for result in results:
        assert "error" not in result, result
    images = {name.removesuffix(".glb"): result["images"] for name, result in zip(files, results)}
    return images, light, pixel_views(camera), eta


def test_the_normal_map_tilts_the_shading_as_the_closed_form(rendered):
    images, light, views, eta = rendered
    table = {}
    for name, theta in MAPS.items():
        normal = decoded(texel(theta))
        for mode in MODES:
            mapped, plain = images[name][mode], images["none"][mode]
            # the quad's pixels, lit in both (the screen technique's shadow-map edge aside)
            covered = (plain.min(axis=-1) > 1e-3 * plain.max()) & (mapped.min(axis=-1) > 1e-3 * mapped.max())
            assert covered.mean() > 0.2, (name, mode, covered.mean())
            ratio = mapped[covered] / plain[covered]
            expected = closed_form(mode, normal, light, views, eta)[covered][:, None]
            error = np.abs(ratio / expected - 1)
            table[name, mode] = (float(np.median(ratio)), float(np.median(expected)), float(error.max()))
            assert error.max() < TOLERANCE, (name, mode, table[name, mode])
    print(f"\nnormal map, mapped / unmapped (median over the quad) vs closed form, max relative error; "
          f"light {THETA_LIGHT} deg, tilt +-{THETA} deg, texels {[texel(t).tolist() for t in MAPS.values()]}")
    for (name, mode), (measured, expected, worst) in table.items():
        print(f"| {name} | {mode} | {measured:.5f} | {expected:.5f} | {worst:.2e} |")
    # the exact tilt's Lambert ratio, for the record: the quantised texel is within a degree of it
    exact = np.cos(np.radians(THETA_LIGHT - THETA)) / np.cos(np.radians(THETA_LIGHT))
    assert abs(table["tilt_plus", "plain"][0] / exact - 1) < 0.01, (table["tilt_plus", "plain"], exact)


def test_the_flat_texel_leaves_the_image_unchanged(rendered):
    """(128, 128, 255) is the byte nearest to (0.5, 0.5, 1): 1/255 off flat, it may change a
    pixel by at most tan(THETA_LIGHT) / 255 = 0.33 % (plain); nothing else may move."""
    images, *_ = rendered
    for mode in MODES:
        mapped, plain = images["flat"][mode], images["none"][mode]
        covered = plain.min(axis=-1) > 1e-3 * plain.max()
        assert np.array_equal(covered, mapped.min(axis=-1) > 1e-3 * mapped.max()), mode
        change = np.abs(mapped[covered] / plain[covered] - 1)
        assert change.max() < np.tan(np.radians(THETA_LIGHT)) / 255 + TOLERANCE / 10, (mode, change.max())
