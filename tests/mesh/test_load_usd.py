"""USD reader: our own output reads back; hand-written stages triangulate; bad files are one-line AssetErrors."""

from pathlib import Path

import numpy as np
import pytest
from test_usd import FALLBACK, icosphere_asset

from sssbake.exporters.usd import write_usdc
from sssbake.pipeline.core.errors import AssetError
from sssbake.pipeline.mesh.load import load_scene
from sssbake.pipeline.mesh.load_usd import load_usd

QUADS = """#usda 1.0
(
    defaultPrim = "World"
    metersPerUnit = 0.001
    upAxis = "Z"
)

def Xform "World"
{
    double3 xformOp:translate = (0, 0, 5)
    uniform token[] xformOpOrder = ["xformOp:translate"]

    def Mesh "Box" (
        prepend apiSchemas = ["MaterialBindingAPI"]
    )
    {
        point3f[] points = [(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0), (0, 0, 1), (1, 0, 1), (1, 1, 1), (0, 1, 1), (0.5, 0, 1.5)]
        int[] faceVertexCounts = [4, 4, 5, 2]
        int[] faceVertexIndices = [0, 3, 2, 1, 4, 5, 6, 7, 0, 1, 5, 8, 4, 2, 3]
        normal3f[] normals = [(0, 0, -1), (0, 0, -1), (0, 0, -1), (0, 0, -1), (0, 0, 1), (0, 0, 1), (0, 0, 1), (0, 0, 1), (0, -1, 0), (0, -1, 0), (0, -1, 0), (0, -1, 0), (0, -1, 0), (1, 0, 0), (1, 0, 0)] (
            interpolation = "faceVarying"
        )
        texCoord2f[] primvars:st = [(0, 0), (1, 0), (1, 1), (0, 1)] (
            interpolation = "faceVarying"
        )
        int[] primvars:st:indices = [0, 1, 2, 3, 0, 1, 2, 3, 0, 1, 2, 3, 0, 0, 1]
        rel material:binding = </World/Looks/Jade>

        def GeomSubset "top" (
            prepend apiSchemas = ["MaterialBindingAPI"]
        )
        {
            uniform token elementType = "face"
            uniform token familyName = "materialBind"
            int[] indices = [1]
            rel material:binding = </World/Looks/Wax>
        }
    }

    def Mesh "Tri"
    {
        point3f[] points = [(0, 0, 0), (1, 0, 0), (0, 1, 0)]
        int[] faceVertexCounts = [3]
        int[] faceVertexIndices = [0, 1, 2]
        uniform token orientation = "leftHanded"
        color3f[] primvars:displayColor = [(0.5, 0.25, 1)]
    }

    def Mesh "Guide"
    {
        uniform token purpose = "guide"
        point3f[] points = [(0, 0, 0), (1, 0, 0), (0, 1, 0)]
        int[] faceVertexCounts = [3]
        int[] faceVertexIndices = [0, 1, 2]
    }

    def Scope "Looks"
    {
        def Material "Jade"
        {
            token outputs:surface.connect = </World/Looks/Jade/Surface.outputs:surface>

            def Shader "Surface"
            {
                uniform token info:id = "UsdPreviewSurface"
                color3f inputs:diffuseColor = (0.25, 0.5, 0.75)
                float inputs:roughness = 0.25
                float inputs:metallic = 0
                float inputs:ior = 1.625
                token outputs:surface
            }
        }

        def Material "Wax"
        {
        }
    }
}
"""


TRIANGLE = """#usda 1.0
def Mesh "M"
{{
    point3f[] points = [{points}]
    int[] faceVertexCounts = [{counts}]
    int[] faceVertexIndices = [{indices}]
}}
"""

GUIDE_TRIANGLE = TRIANGLE.format(points="(0, 0, 0), (1, 0, 0), (0, 1, 0)", counts="3", indices="0, 1, 2").replace(
    "{\n", '{\n    uniform token purpose = "guide"\n')


def write(tmp_path: Path, name: str, text: str) -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


def one_line_error(path: Path, needle: str) -> str:
    with pytest.raises(AssetError) as info:
        load_scene(path)
    message = str(info.value)
    assert message.startswith(f"{path}: ") and "\n" not in message and needle in message, message
    return message


def test_round_trip_of_our_own_output(tmp_path):
    asset = icosphere_asset()
    write_usdc(asset, tmp_path / "ico.usdc")
    scene = load_scene(tmp_path / "ico.usdc")
    assert scene.source == str(tmp_path / "ico.usdc")
    assert scene.up_axis == "Y" and scene.meters_per_unit == 0.01
    assert [m.name for m in scene.meshes] == ["sphere", "plate"]

    prim_in = asset.scene.meshes[0].primitives[0]
    prim = scene.meshes[0].primitives[0]
    np.testing.assert_array_equal(prim.positions, prim_in.positions.astype(np.float32))
    np.testing.assert_array_equal(prim.faces, prim_in.faces)
    normals = prim_in.normals / np.linalg.norm(prim_in.normals, axis=1, keepdims=True)
    np.testing.assert_array_equal(prim.normals, normals.astype(np.float32))
    assert len(prim.uvs) == 2
    for uv, uv_in in zip(prim.uvs, prim_in.uvs):
        np.testing.assert_allclose(uv, uv_in, atol=1e-7)
    np.testing.assert_allclose(prim.colors, prim_in.colors, atol=1e-7)

    worlds = scene.world_matrices()
    worlds_in = asset.scene.world_matrices()
    for m in range(2):
        (world,) = scene.mesh_instances()[m]
        (world_in,) = [worlds_in[i] for i, node in enumerate(asset.scene.nodes) if node.mesh == m]
        np.testing.assert_array_equal(world, world_in)
    assert len(worlds) == len(scene.nodes) == 5

    marble, steel = (scene.materials[p.material] for m in scene.meshes for p in m.primitives)
    np.testing.assert_allclose(marble.base_color_factor, (*FALLBACK.base_color, 1.0), atol=1e-7)
    assert marble.ior == 1.5 and marble.roughness_factor == pytest.approx(0.3)
    assert marble.volume["thicknessFactor"] == 2.0 and marble.volume["attenuationDistance"] == 4.0
    assert marble.diffuse_transmission["diffuseTransmissionFactor"] == pytest.approx(0.4)
    assert steel.double_sided and steel.metallic_factor == 1.0 and steel.volume is None
    assert steel.base_color_factor[3] == pytest.approx(0.8)


def test_quads_subsets_and_z_up(tmp_path):
    scene = load_usd(write(tmp_path, "quads.usda", QUADS))
    assert scene.up_axis == "Z" and scene.meters_per_unit == 0.001
    assert [m.name for m in scene.meshes] == ["Box", "Tri"]
    assert [n.name for n in scene.nodes] == ["World", "Box", "Tri"]
    assert scene.roots == (0,) and scene.nodes[0].children == (1, 2)
    np.testing.assert_array_equal(scene.nodes[0].matrix[:, 3], [0, 0, 5, 1])

    jade, wax = scene.meshes[0].primitives
    # quad + pentagon (2 + 3 triangles) bound to Jade, the top quad (subset) to Wax; the 2-gon is dropped.
    assert len(jade.faces) == 5 and len(wax.faces) == 2
    assert scene.materials[jade.material].name == "Jade" and scene.materials[wax.material].name == "Wax"
    src = scene.materials[jade.material]
    assert src.base_color_factor == (0.25, 0.5, 0.75, 1.0) and src.roughness_factor == 0.25 and src.ior == 1.625
    assert scene.materials[wax.material].base_color_factor == (0.18, 0.18, 0.18, 1.0)

    # faceVarying normals split the box's corners: bottom and pentagon corners share no normal.
    assert len(jade.positions) == 4 + 5 and len(wax.positions) == 4
    np.testing.assert_array_equal(wax.normals, np.tile([0.0, 0.0, 1.0], (4, 1)))
    np.testing.assert_array_equal(wax.positions[:, 2], np.ones(4))
    for prim in (jade, wax):
        corners = prim.positions[prim.faces]
        face_normals = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
        vertex_normals = prim.normals[prim.faces].mean(axis=1)
        assert np.all(np.einsum("ij,ij->i", face_normals, vertex_normals) > 0)
    np.testing.assert_array_equal(np.sort(wax.uvs[0], axis=0), [[0, 0], [0, 0], [1, 1], [1, 1]])

    tri = scene.meshes[1].primitives[0]
    np.testing.assert_array_equal(tri.faces, [[0, 2, 1]])
    assert scene.materials[tri.material].base_color_factor == (0.5, 0.25, 1.0, 1.0)


def test_whole_stage_without_default_prim(tmp_path):
    text = QUADS.replace('    defaultPrim = "World"\n', "")
    scene = load_usd(write(tmp_path, "nodefault.usda", text))
    assert scene.roots == (0,) and scene.nodes[0].name == "World" and len(scene.meshes) == 2


@pytest.mark.parametrize(
    "name, text, needle",
    [
        ("corrupt.usda", '#usda 1.0\ndef Mesh "M" {\n    point3f[] points = [(0, 0 }\n', "corrupt USD file: line 3:"),
        ("garbage.usda", "this is not USD", "corrupt USD file"),
        ("text.usdc", "this is not a crate file either, just text", "corrupt USD file"),
        ("no_meshes.usda", '#usda 1.0\n(\n    defaultPrim = "A"\n)\n\ndef Xform "A"\n{\n}\n',
         "no meshes: no UsdGeom.Mesh prims under </A>"),
        ("only_guide.usda", GUIDE_TRIANGLE, "no meshes: no UsdGeom.Mesh prims in the stage (1 guide/proxy"),
    ],
)
def test_bad_files(tmp_path, name, text, needle):
    one_line_error(write(tmp_path, name, text), needle)


def test_empty_file(tmp_path):
    path = write(tmp_path, "empty.usda", "")
    with pytest.raises(AssetError, match="empty file"):
        load_usd(path)
    one_line_error(path, "empty file")


def test_truncated_crate(tmp_path):
    write_usdc(icosphere_asset(), tmp_path / "full.usdc")
    path = tmp_path / "cut.usdc"
    path.write_bytes((tmp_path / "full.usdc").read_bytes()[:2000])
    one_line_error(path, "corrupt USD file: Sdf crate file corrupt")


@pytest.mark.parametrize(
    "points, counts, indices, needle",
    [
        ("(0, 0, 0), (nan, 0, 0), (0, 1, 0)", "3", "0, 1, 2", "non-finite vertex positions (1 of 3) in mesh '/M'"),
        ("(0, 0, 0), (1, 0, 0), (0, 1, 0)", "3", "0, 1, 57", "face index 57 out of range for 3 vertices in mesh '/M'"),
        ("(0, 0, 0), (1, 0, 0), (0, 1, 0)", "3", "0, -1, 2", "negative face index -1"),
        ("(0, 0, 0), (1, 0, 0), (0, 1, 0)", "4", "0, 1, 2", "faceVertexCounts sum to 4 but faceVertexIndices has 3"),
        ("(0, 0, 0), (1, 0, 0), (0, 1, 0)", "2", "0, 1", "no triangles (3 vertices, 0 faces)"),
    ],
)
def test_bad_geometry(tmp_path, points, counts, indices, needle):
    path = write(tmp_path, "bad.usda", TRIANGLE.format(points=points, counts=counts, indices=indices))
    with pytest.raises(AssetError) as info:
        load_usd(path)
    assert needle in str(info.value) and str(info.value).startswith(str(path))


def test_primvar_length_must_fit_interpolation(tmp_path):
    text = TRIANGLE.format(points="(0, 0, 0), (1, 0, 0), (0, 1, 0)", counts="3", indices="0, 1, 2").replace(
        "}\n", '    texCoord2f[] primvars:st = [(0, 0), (1, 0)] (\n        interpolation = "vertex"\n    )\n}\n')
    one_line_error(write(tmp_path, "st.usda", text), "primvars:st has 2 values, vertex interpolation needs 3")


def test_reset_xform_stack_and_instances(tmp_path):
    text = """#usda 1.0

def Xform "A"
{
    double3 xformOp:translate = (10, 0, 0)
    uniform token[] xformOpOrder = ["xformOp:translate"]

    def Xform "B"
    {
        double3 xformOp:translate = (0, 5, 0)
        uniform token[] xformOpOrder = ["!resetXformStack!", "xformOp:translate"]

        def Mesh "M"
        {
            point3f[] points = [(0, 0, 0), (1, 0, 0), (0, 1, 0)]
            int[] faceVertexCounts = [3]
            int[] faceVertexIndices = [0, 1, 2]
        }
    }
}

def Xform "C" (
    instanceable = true
    references = </A>
)
{
    double3 xformOp:translate = (0, 0, 3)
    uniform token[] xformOpOrder = ["xformOp:translate"]
}
"""
    scene = load_usd(write(tmp_path, "reset.usda", text))
    assert [n.name for n in scene.nodes] == ["A", "B", "M", "C", "B", "M"] and scene.roots == (0, 3)
    # B ignores its parents' transforms, also inside the instance of A under C.
    for worlds in scene.mesh_instances().values():
        np.testing.assert_array_equal(worlds[0][:3, 3], [0, 5, 0])


@pytest.mark.parametrize("meters", ["0", "-0.01", "nan", "inf"])
def test_meters_per_unit_must_be_a_finite_positive_number(tmp_path, meters):
    good = QUADS.replace("metersPerUnit = 0.001", "metersPerUnit = 0.01")
    assert load_scene(write(tmp_path, "good.usda", good)).meters_per_unit == 0.01
    bad = QUADS.replace("metersPerUnit = 0.001", f"metersPerUnit = {meters}")
    message = one_line_error(write(tmp_path, "bad.usda", bad), "metersPerUnit is ")
    assert "finite number > 0" in message
