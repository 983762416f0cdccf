"""The three.js runtime (``runtime_three/sssbake-three.js``) in headless Chromium against the
moderngl runtime: the bundled samples baked with prt, spectral and screen (and two prt variants
that exercise the decoder's other paths), drawn by both with the same camera, light and size,
compared by image RMSE of linear float images; the plugin finds tables by name and refuses stale
data in the browser."""

from __future__ import annotations

import base64
import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pygltflib
import pytest

from sssbake.pipeline.mesh.load import load_scene
from sssbake.pipeline.render.renderer import DEFAULT_LIGHT, Renderer, RenderLight, _bounding_sphere, fit_camera
from sssbake.pipeline.techniques.prt.reader import read_prt_glb
from sssbake.pipeline.techniques.screen.reader import read_screen_glb
from sssbake.pipeline.techniques.spectral.reader import read_spectral_glb
from tests.browser import have_chromium, open_page, static_server

REPO = Path(__file__).resolve().parents[2]
SIZE = 160
FOV = 35.0
VIEW_DIR = (0.3, -0.4, -1.0)  # fit_camera's default
EXTENSION = "SSSBAKE_subsurface"
MODES = ["prt", "spectral", "screen", "plain"]
#: A light that grazes the torus from the side: its inner ring lies in the outer one's shadow.
GRAZING = (1.0, 0.15, 0.2)
#: Bakes of the samples: folder -> (sample files, extra bake options). The defaults (shared tables,
#: 8-bit weights, no SH); SH order 2 with RGB tables and 16-bit weights; detail terms.
BAKES = {
    "default": (("sphere.obj", "torus.ply", "candle.glb"), ["--techniques", "prt,spectral,screen"]),
    "sh_rgb16": (("sphere.obj",), ["--techniques", "prt", "--prt-sh-order", "2", "--prt-tables", "rgb",
                                   "--prt-weight-bits", "16"]),
    "detail": (("sphere.obj",), ["--techniques", "prt", "--prt-detail-order", "2"]),
}
#: What is compared: label -> (file under the bakes, modes, light direction). The candle has a mesh
#: without sssbake data and several nodes.
CASES = {
    "sphere": ("default/sphere.glb", MODES, DEFAULT_LIGHT),
    "torus": ("default/torus.glb", MODES, DEFAULT_LIGHT),
    "candle": ("default/candle.glb", MODES, DEFAULT_LIGHT),
    "torus_grazing": ("default/torus.glb", ["screen", "prt"], GRAZING),
    "sh_rgb16": ("sh_rgb16/sphere.glb", ["prt"], DEFAULT_LIGHT),
    "detail": ("detail/sphere.glb", ["prt"], DEFAULT_LIGHT),
}
BLOCK, TRIM = 4, 0.01
#: Largest `relative_rmse` of the three.js image against the moderngl one, per mode. Measured
#: (SwiftShader vs llvmpipe, same shaders and data): prt <= 0.0009, spectral and plain <= 0.0007,
#: screen <= 0.006 (torus: per-pixel sampling noise). A wrong table or dropped term, drawn by
#: moderngl with the data altered, scores: prt with flattened refScale 0.02-0.05, swapped weights
#: 0.11-0.13; spectral with the file's normals instead 0.0056 (candle), 0.15 (torus); screen
#: without the Jacobian 0.0135-0.06, without the resolve 0.018-0.03, without the fill 0.04-0.3.
TOLERANCE = {"prt": 0.003, "spectral": 0.003, "plain": 0.003, "screen": 0.01}
#: Cases held to another limit. Screen under `GRAZING`: the same noise over a darker image, 0.011
#: measured, 0.069 with the shadow map left empty. The SH terms (sh_rgb16) add little to the
#: sphere's image: 0.0029 with them dropped, 0.0004 with the colour channels of their codes
#: swapped (0.037 for the RGB tables'); measured 0.00033. (The detail terms, 0.00016 when dropped,
#: are below what an image comparison can hold to.)
TOLERANCE_CASES = {("torus_grazing", "screen"): 0.025, ("sh_rgb16", "prt"): 0.001}

pytestmark = pytest.mark.skipif(not have_chromium(), reason="needs chromium, node and puppeteer-core (.ci/setup)")


@pytest.fixture(scope="session")
def baked(tmp_path_factory) -> Path:
    """`BAKES` (at once: each is a batch of its own) under one folder."""
    out = tmp_path_factory.mktemp("three_baked")
    runs = [subprocess.Popen([sys.executable, "-m", "sssbake.pipeline.cli", "bake",
                              *(str(REPO / "samples" / f) for f in files), "-o", str(out / name),
                              "--config", str(REPO / "samples" / "sssbake.toml"), *options],
                             stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, cwd=REPO)
            for name, (files, options) in BAKES.items()]
    for run in runs:
        _, err = run.communicate()
        assert run.returncode == 0, err.decode()[-2000:]
    return out


def served_root(tmp: Path, files: dict[str, Path]) -> Path:
    """A folder to serve: the repository's three.js, runtime and shaders, the test page, `files`."""
    root = tmp / "site"
    root.mkdir()
    for name in ("node_modules", "runtime_three", "runtime_shaders"):
        (root / name).symlink_to(REPO / name)
    (root / "page").symlink_to(REPO / "tests" / "runtime_three")
    for name, path in files.items():
        shutil.copy(path, root / name)
    return root


def camera_json(points: np.ndarray, view_dir=VIEW_DIR) -> dict:
    """The three.js camera of `fit_camera(points, view_dir)`: eye, target, fov, near, far (same formulas)."""
    centre, radius = _bounding_sphere(points)
    forward = np.asarray(view_dir) / np.linalg.norm(view_dir)
    distance = radius / np.sin(np.radians(FOV) / 2.0) * 1.05
    eye = centre - forward * distance
    assert np.allclose(eye, fit_camera(points, view_dir).eye)
    return {"eye": eye.tolist(), "target": (eye + forward).tolist(), "fov": FOV,
            "near": max(distance - radius * 1.5, distance * 1e-3), "far": distance + radius * 1.5}


def world_points(scene) -> np.ndarray:
    return np.concatenate([(w[:3, :3] @ p.positions.T).T + w[:3, 3] for mi, ws in scene.mesh_instances().items()
                           for w in ws for p in scene.meshes[mi].primitives])


def moderngl_images(path: Path, modes: list[str], light_dir=DEFAULT_LIGHT) -> dict[str, np.ndarray]:
    """(SIZE, SIZE, 3) linear images of `path` per mode by the moderngl runtime, row 0 at the top:
    each primitive with the mode's data drawn by it, every other one plain (as the three.js runtime
    draws them): Lambert of its base colour (spectral: with the subsurface normals)."""
    gltf = pygltflib.GLTF2.load(str(path))
    scene = load_scene(str(path))
    readers = {"prt": read_prt_glb, "spectral": read_spectral_glb, "screen": read_screen_glb}
    data = {mode: readers[mode](path) for mode in modes if mode in readers}
    renderer = Renderer((SIZE, SIZE), dialect="essl300")
    camera = fit_camera(world_points(scene))
    light = RenderLight(False, tuple(light_dir), 1.0)
    out = {}
    try:
        for mode in modes:
            items = []
            for mi, worlds in sorted(scene.mesh_instances().items()):
                mesh_block = (gltf.meshes[mi].extensions or {}).get(EXTENSION, {})
                for pi, prim in enumerate(scene.meshes[mi].primitives):
                    material = gltf.materials[gltf.meshes[mi].primitives[pi].material]
                    block = (material.extensions or {}).get(EXTENSION, {})
                    eta = block.get("material", {}).get("eta", 1.5)
                    colour = tuple(material.pbrMetallicRoughness.baseColorFactor[:3])
                    base = dict(positions=prim.positions, normals=prim.normals, faces=prim.faces, eta=eta)
                    held = data.get(mode, {}).get((mi, pi))
                    for world in worlds:
                        item = {**base, "model": world}
                        if held is None:
                            item["albedo"] = colour
                        elif mode == "spectral":
                            item.update(normals=held, albedo=colour)
                        elif mode == "screen":
                            item.update(screen=held, mm_per_unit=float(mesh_block["scaleMm"]))
                        else:
                            item[mode] = held
                        items.append(item)
            out[mode] = renderer.render(items, camera, light)[0]
    finally:
        renderer.release()
    return out


def three_results(tmp: Path, files: dict[str, Path], jobs: list[dict]) -> list[dict]:
    """Each job's result from the test page: ``images`` decoded to (SIZE, SIZE, 3) float32, row 0
    at the top, or ``error``."""
    root = served_root(tmp, files)
    (root / "jobs.json").write_text(json.dumps({"size": SIZE, "jobs": jobs}))
    with static_server(root) as url:
        page = open_page(f"{url}page/render.html?jobs=/jobs.json", tmp / "page.png", SIZE, SIZE, timeout_s=240)
    assert not [line for line in page.logs if "GL_INVALID" in line], page.logs
    for result in page.result:
        for mode, text in result.get("images", {}).items():
            rgba = np.frombuffer(base64.b64decode(text), np.float32).reshape(SIZE, SIZE, 4)
            result["images"][mode] = np.ascontiguousarray(rgba[::-1, :, :3])
    return page.result


def relative_rmse(image: np.ndarray, reference: np.ndarray) -> float:
    """RMSE of `BLOCK`² block means over the blocks both images cover fully, the `TRIM` share of
    largest differences left out (intersections that two rasterisers resolve differently), over
    the reference's RMS there. Block means average out screen's per-pixel sampling noise (its
    interleave tile is 4²), which moves with any sample that lands on a neighbouring pixel."""
    h, w, _ = image.shape

    def blocks(x: np.ndarray) -> np.ndarray:
        return x[: h // BLOCK * BLOCK, : w // BLOCK * BLOCK].reshape(h // BLOCK, BLOCK, w // BLOCK, BLOCK, -1).mean(
            axis=(1, 3))

    full = (blocks((image.sum(axis=-1) > 0)[..., None].astype(float))[..., 0] == 1) & (
        blocks((reference.sum(axis=-1) > 0)[..., None].astype(float))[..., 0] == 1)
    a, b = blocks(image)[full], blocks(reference)[full]
    squared = np.sort(np.sum((a - b) ** 2, axis=-1))
    kept = squared[: len(squared) - int(TRIM * len(squared))]
    return float(np.sqrt(np.mean(kept) / np.mean(np.sum(b ** 2, axis=-1))))


def test_three_runtime_matches_moderngl(baked, tmp_path):
    files = {f"{label}.glb": baked / path for label, (path, _, _) in CASES.items()}
    # screen's transmission is the three.js runtime's own (test_runtime_three_surface.py): off here
    jobs = [{"glb": f"/{label}.glb", "modes": modes + ["fallback"], "options": {"screen": {"transmission": False}},
             "camera": camera_json(world_points(load_scene(str(baked / path)))), "light": list(light)}
            for label, (path, modes, light) in CASES.items()]
    results = three_results(tmp_path, files, jobs)
    figures, over = {}, {}
    for (label, (path, modes, light)), result in zip(CASES.items(), results):
        assert "error" not in result, result
        reference = moderngl_images(baked / path, modes, light)
        for mode in modes:
            figures[label, mode] = relative_rmse(result["images"][mode], reference[mode])
            limit = TOLERANCE_CASES.get((label, mode), TOLERANCE[mode])
            if not figures[label, mode] < limit:
                over[label, mode] = (figures[label, mode], limit)
        # the fallback (three.js's own materials) draws the object, not a black or empty image
        fallback = result["images"]["fallback"]
        assert np.mean(fallback.sum(axis=-1) > 0) > 0.05 and np.all(np.isfinite(fallback)), label
    assert results[0]["techniques"] == ["prt", "spectral", "screen"]
    print("relative RMSE three.js vs moderngl:", {f"{n}/{m}": round(v, 5) for (n, m), v in figures.items()})
    assert not over, f"over the tolerance: {over}"


def edited(source: Path, out: Path, edit) -> Path:
    """A copy of .glb `source` at `out` after `edit(gltf, blob: bytearray)` changed it in place."""
    gltf = pygltflib.GLTF2.load(str(source))
    blob = bytearray(gltf.binary_blob())
    edit(gltf, blob)
    gltf.set_binary_blob(bytes(blob))
    gltf.save_binary(str(out))
    return out


def test_three_plugin_finds_tables_by_name_and_refuses_stale_data(baked, tmp_path):
    """Tables are found by name after accessors moved; a file whose table bytes changed, that lost
    a vertex attribute, or that predates the extension is refused in one line naming the file and
    what is wrong, never drawn."""
    sphere = baked / "default" / "sphere.glb"
    prt = pygltflib.GLTF2.load(str(sphere)).meshes[0].extensions[EXTENSION]["prt"]

    def flip_bit(gltf, blob):  # one bit of the first direction, as a bad copy would
        accessor = gltf.accessors[prt["directions"]["accessor"]]
        blob[(gltf.bufferViews[accessor.bufferView].byteOffset or 0) + (accessor.byteOffset or 0) + 1] ^= 0x40

    def move_accessors(gltf, blob):  # two tables trade places, the extension's indices untouched
        a, b = prt["directions"]["accessor"], prt["lut"]["accessor"]
        gltf.accessors[a], gltf.accessors[b] = gltf.accessors[b], gltf.accessors[a]

    def drop_attribute(gltf, blob):  # what gltfpack does to `_` attributes
        del gltf.meshes[0].primitives[0].attributes._SSS_PRT_REF

    def schema_1(gltf, blob):
        gltf.extras = {"sssbake": {"schemaVersion": "1.8.0"}}
        gltf.extensions, gltf.extensionsUsed = {}, [e for e in gltf.extensionsUsed if e != EXTENSION]
        for item in gltf.meshes + gltf.materials:
            (item.extensions or {}).pop(EXTENSION, None)

    files = {"sphere.glb": sphere}
    for edit in (flip_bit, move_accessors, drop_attribute, schema_1):
        files[f"{edit.__name__}.glb"] = edited(sphere, tmp_path / f"{edit.__name__}.glb", edit)
    camera = camera_json(world_points(load_scene(str(sphere))))
    results = three_results(tmp_path, files, [{"glb": f"/{name}", "modes": ["prt"], "camera": camera,
                                               "light": list(DEFAULT_LIGHT)} for name in files])
    by_name = dict(zip(files, results))
    assert np.array_equal(by_name["move_accessors.glb"]["images"]["prt"], by_name["sphere.glb"]["images"]["prt"])
    expected = {
        "flip_bit.glb": "sssbake table 'sssbake/mesh0/prt/directions' "
                        f"(meshes[0].extensions.{EXTENSION}.prt.directions): accessor {prt['directions']['accessor']}'s "
                        "data has CRC-32",
        "drop_attribute.glb": "mesh 0 primitive 0 lacks vertex attribute _SSS_PRT_REF; likely broken by",
        "schema_1.glb": "written by sssbake schema 1.x (extras.sssbake); rebake it with this version",
    }
    for name, start in expected.items():
        result = by_name[name]
        assert result.get("kind") == "SSSBakeDataError", (name, result)
        assert result["error"].startswith(f"/{name}: {start}") and "\n" not in result["error"], result["error"]
    assert "; likely broken by a tool that did not keep the SSSBAKE_subsurface extension (asset.generator 'sssbake" in (
        by_name["flip_bit.glb"]["error"])
