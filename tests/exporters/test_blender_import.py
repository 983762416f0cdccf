"""sssbake's vertex attributes survive Blender's glTF importer with their values: every one is a
float32 VEC3 (the one kind Blender keeps exactly at one width), checked here on a bake with every
per-vertex attribute; and, where Blender's Python module is installed (`bpy` in its own virtual
environment, see benchmarks/blender_import.py), imported under several hash seeds and decoded
through sssbake's own layouts; runtime_blender/sssbake_blender.py gives the materials subsurface."""

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pygltflib
import pytest
from fixtures import bake_screen_sphere

from sssbake.exporters.gltf import FLOAT
from sssbake.pipeline.techniques.kernels.layout import VERTEX_ATTRIBUTE, vertex_ids_from_layout
from sssbake.pipeline.techniques.kernels.reader import read_kernels_glb
from sssbake.pipeline.techniques.prt.layout import prt_from_layout, prt_tables
from sssbake.pipeline.techniques.prt.reader import read_prt_glb
from sssbake.pipeline.techniques.spectral.reader import read_spectral_glb

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))
import blender_import  # noqa: E402

EVERY_ATTRIBUTE = ["_SSS_KERNELS_VERTEX", "_SSS_NORMAL", "_SSS_PRT_DQ0", "_SSS_PRT_REF", "_SSS_SPECTRAL_VERTEX",
                   "_THICKNESS"]


@pytest.fixture(scope="module")
def glb(tmp_path_factory):
    """A bake with every per-vertex attribute: prt with Δq, kernels, spectral with its basis."""
    result, _ = bake_screen_sphere(tmp_path_factory.mktemp("blender"), techniques=("prt", "kernels", "spectral"),
                                   prt_sh_order=1, spectral_basis=True)
    return next(path for path in result.outputs if path.name == "ball.glb")


def bpy_python() -> str:
    python = blender_import.default_python()
    if python is None:
        pytest.skip("no bpy interpreter (.bpy/bin/python or SSSBAKE_BPY_PYTHON; see benchmarks/blender_import.py)")
    return python


def test_every_attribute_is_float32_vec3(glb):
    gltf = pygltflib.GLTF2.load(glb)
    for mesh in gltf.meshes:
        for prim in mesh.primitives:
            custom = {k: v for k, v in vars(prim.attributes).items() if k.startswith("_") and v is not None}
            assert sorted(custom) == EVERY_ATTRIBUTE
            for index in custom.values():
                acc = gltf.accessors[index]
                assert (acc.type, acc.componentType, bool(acc.normalized)) == ("VEC3", FLOAT, False)


def test_blender_keeps_every_value_and_the_layouts_decode_them(glb):
    python = bpy_python()
    expected = blender_import.expected_attributes(glb)
    prt = read_prt_glb(glb)[(0, 0)]
    kernels, kernel_ids = read_kernels_glb(glb)[(0, 0)]
    normals = read_spectral_glb(glb)[(0, 0)]
    # Blender keeps the vertices faces use, in order: all of them here, so its rows are the file's
    assert all(len(values) == prt.vertex_count for _, values in expected.values())
    # the importer's attribute set changes order with the hash seed; some orders crashed or mixed data up
    for seed in range(4):
        imported = blender_import.blender_attributes(glb, python, seed)
        assert not isinstance(imported, str), imported
        rows = blender_import.compare(expected, imported)
        assert {key[1] for key in rows} == set(EVERY_ATTRIBUTE)
        assert all(status == "ok" and error == 0.0 for status, _, error in rows.values()), (seed, rows)
        values = {attr: got for (_, attr), (_, _, got) in imported.items()}
        decoded = prt_from_layout(prt_tables(prt), values)
        np.testing.assert_array_equal(decoded.vertex_triangle, prt.vertex_triangle)
        np.testing.assert_array_equal(decoded.weight_codes, prt.weight_codes)
        np.testing.assert_array_equal(decoded.dq_codes, prt.dq_codes)
        ids = vertex_ids_from_layout({"attributes": {"vertex": VERTEX_ATTRIBUTE},
                                      "surfaceVertexCount": kernels.surface_vertex_count}, values)
        np.testing.assert_array_equal(ids, kernel_ids)
        np.testing.assert_array_equal(values["_SSS_NORMAL"], normals.astype(np.float32))


def test_blender_materials_get_the_subsurface_of_the_baked_material(glb):
    runtime = Path(__file__).resolve().parents[2] / "runtime_blender"
    code = (f"import sys, json; sys.path.insert(0, {str(runtime)!r}); import sssbake_blender, bpy; "
            f"bpy.ops.wm.read_factory_settings(use_empty=True); sssbake_blender.import_glb({str(glb)!r}); "
            "p = {m.name: next(n for n in m.node_tree.nodes if n.type == 'BSDF_PRINCIPLED') "
            "for m in bpy.data.materials}; "
            "print('RESULT', json.dumps({name: [n.inputs['Subsurface Weight'].default_value, "
            "list(n.inputs['Subsurface Radius'].default_value), n.subsurface_method] for name, n in p.items()}))")
    run = subprocess.run([bpy_python(), "-c", code], capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr[-2000:]
    shown = json.loads(next(line for line in run.stdout.splitlines() if line.startswith("RESULT"))[7:])
    gltf = pygltflib.GLTF2.load(glb)
    material = gltf.materials[0].extensions["SSSBAKE_subsurface"]["material"]
    mm_per_unit = gltf.extensions["SSSBAKE_subsurface"]["scaleMmPerUnit"]
    weight, radius, method = shown[gltf.materials[0].name]
    # the mean free path 1 / (σ_s' + σ_a) per channel, in file units (marble: ~0.46, 0.38, 0.33 mm)
    expected = 1.0 / ((np.array(material["sigma_s_prime"]) + material["sigma_a"]) * mm_per_unit)
    assert weight == 1.0 and method == "RANDOM_WALK"
    np.testing.assert_allclose(radius, expected, rtol=1e-6)
