"""glTF export: geometry, sssbake attributes, materials and the SSSBAKE_subsurface extension survive a
round trip."""

import io
import json
from dataclasses import replace
from importlib import resources

import jsonschema
import numpy as np
import pygltflib
import pytest
import trimesh
from fixtures import FALLBACK
from PIL import Image as PILImage

from sssbake.exporters.gltf import (
    ARRAY_BUFFER,
    BYTE,
    ELEMENT_ARRAY_BUFFER,
    EXTENSION,
    FLOAT,
    UNSIGNED_INT,
    UNSIGNED_SHORT,
    dequantize,
    quantization_step,
    read_accessor,
    to_glb,
    write_glb,
)
from sssbake.exporters.gltf_tables import load_sssbake_gltf, technique_tables
from sssbake.pipeline.core.materials import preset
from sssbake.pipeline.mesh.baked import SCHEMA_VERSION, BakedAsset, ScatteringMaterial, VertexAttribute
from sssbake.pipeline.mesh.scene import Image, Mesh, Node, Primitive, Scene, SourceMaterial, Texture, TextureRef


def png_bytes(width: int = 4, height: int = 4) -> bytes:
    rgb = (np.random.default_rng(1).random((height, width, 3)) * 255).astype(np.uint8)
    buf = io.BytesIO()
    PILImage.fromarray(rgb).save(buf, "PNG")
    return buf.getvalue()


def icosphere_asset(subdivisions: int = 1, double_sided: bool = False, extras: dict | None = None) -> BakedAsset:
    """A marble icosphere (mesh 0, translucent material 0, thickness texture on TEXCOORD_1) with four
    sssbake attributes, and an opaque textured triangle (mesh 1, material 1, child node)."""
    sphere = trimesh.creation.icosphere(subdivisions=subdivisions)
    v = np.asarray(sphere.vertices, dtype=np.float64)
    n = len(v)
    uv0 = np.c_[0.5 + np.arctan2(v[:, 1], v[:, 0]) / (2 * np.pi), 0.5 - np.arcsin(np.clip(v[:, 2], -1, 1)) / np.pi]
    uv1 = uv0 * 0.5 + 0.25
    colors = np.c_[np.abs(v), np.ones(n)]
    sphere_prim = Primitive(v, np.asarray(sphere.faces), normals=np.asarray(sphere.vertex_normals) * 3.0,
                            uvs=(uv0, uv1), colors=colors, material=0)
    tri = Primitive(np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]]), np.array([[0, 1, 2]]),
                    normals=np.array([[0.0, 0, 1]] * 3), uvs=(np.array([[0.0, 0], [1, 0], [0, 1]]),), material=1)
    scene = Scene(
        source="memory",
        meshes=(Mesh("sphere", (sphere_prim,)), Mesh("plate", (tri,))),
        nodes=(
            Node("root", np.diag([2.0, 2.0, 2.0, 1.0]), mesh=0, children=(1,)),
            Node("plate", np.eye(4), mesh=1),
        ),
        roots=(0,),
        materials=(
            SourceMaterial("Marble", base_color_factor=(0.2, 0.3, 0.4, 1.0), roughness_factor=0.3,
                           double_sided=double_sided),
            SourceMaterial("Steel", base_color_factor=(0.5, 0.5, 0.5, 1.0), metallic_factor=1.0,
                           occlusion_texture=TextureRef(0, 0), emissive_factor=(0.1, 0.2, 0.3),
                           emissive_texture=TextureRef(0, 0), double_sided=True),
        ),
        textures=(Texture(0, mag_filter=9729, min_filter=9987), Texture(1)),
        images=(Image("glow", "image/png", png_bytes()), Image("thickness", "image/png", png_bytes(8, 8))),
    )
    fallback = replace(FALLBACK, thickness_texture=TextureRef(1, 1))
    t = np.linspace(0.0, 1.0, n)
    attrs = (
        VertexAttribute("thickness", 2.0 * np.sin(7 * t) ** 2, "mm", "float32", "thickness along -n"),
        VertexAttribute("sss:w", np.c_[np.cos(5 * t), -np.sin(3 * t), t * 2 - 1], "", "snorm8", "weights"),
        VertexAttribute("sss:u16", np.c_[t, 1 - t], "", "unorm16", "unsigned pair"),
        VertexAttribute("sss:ref", np.c_[v, t], "mm", "float32", "reference"),
    )
    return BakedAsset(
        scene=scene,
        vertex_attributes={(0, 0): attrs},
        scattering={0: ScatteringMaterial(preset("marble"), fallback, "Marble", keep_base_color_texture=True)},
        scale_mm={0: 10.0},
        extras={"warnings": [], "note": ""} if extras is None else extras,
    )


def load(path) -> pygltflib.GLTF2:
    return pygltflib.GLTF2.load(str(path))


def test_geometry_and_attributes_round_trip(tmp_path):
    asset = icosphere_asset()
    summary = write_glb(asset, tmp_path / "a.glb")
    gltf = load(tmp_path / "a.glb")
    prim_in = asset.scene.meshes[0].primitives[0]
    prim = gltf.meshes[0].primitives[0]
    attrs = prim.attributes

    pos = read_accessor(gltf, attrs.POSITION)
    np.testing.assert_array_equal(pos, prim_in.positions.astype(np.float32))
    acc = gltf.accessors[attrs.POSITION]
    assert acc.min == pos.min(axis=0).tolist() and acc.max == pos.max(axis=0).tolist()
    normals = read_accessor(gltf, attrs.NORMAL)
    np.testing.assert_allclose(np.linalg.norm(normals, axis=1), 1.0, atol=1e-6)
    np.testing.assert_allclose(normals, prim_in.normals / 3.0, atol=1e-6)
    np.testing.assert_array_equal(read_accessor(gltf, attrs.TEXCOORD_1), prim_in.uvs[1].astype(np.float32))
    np.testing.assert_array_equal(read_accessor(gltf, attrs.COLOR_0), prim_in.colors.astype(np.float32))
    indices = read_accessor(gltf, prim.indices)
    assert gltf.accessors[prim.indices].componentType == UNSIGNED_SHORT
    np.testing.assert_array_equal(indices.reshape(-1, 3), prim_in.faces)
    assert prim.material == 0

    for attr in asset.vertex_attributes[(0, 0)]:
        acc = gltf.accessors[getattr(attrs, attr.gltf_name)]
        stored = read_accessor(gltf, getattr(attrs, attr.gltf_name))
        decoded = dequantize(stored, bool(acc.normalized)).reshape(attr.data.shape)
        if attr.encoding == "float32":
            assert acc.componentType == FLOAT and not acc.normalized
            np.testing.assert_array_equal(decoded, attr.data.astype(np.float32))
        else:
            assert acc.normalized
            assert np.max(np.abs(decoded - attr.data)) <= quantization_step(attr.encoding) + 1e-12
    assert gltf.accessors[attrs._SSS_W].componentType == BYTE

    for view in gltf.bufferViews:
        assert view.byteOffset % 4 == 0
        if view.target == ARRAY_BUFFER:
            assert view.byteStride % 4 == 0
    assert gltf.bufferViews[gltf.accessors[prim.indices].bufferView].target == ELEMENT_ARRAY_BUFFER
    assert summary["bytes"] == (tmp_path / "a.glb").stat().st_size


def test_materials_extensions_and_extras(tmp_path):
    asset = icosphere_asset(double_sided=True)
    write_glb(asset, tmp_path / "a.glb")
    gltf = load(tmp_path / "a.glb")
    fb = asset.scattering[0].fallback

    marble = gltf.materials[0]
    assert marble.pbrMetallicRoughness.baseColorFactor == [*fb.base_color, 1.0]
    assert marble.pbrMetallicRoughness.roughnessFactor == 0.3
    # a volume is meaningless (and a validator warning) on a double-sided material
    assert not marble.doubleSided
    ext = marble.extensions
    assert ext["KHR_materials_volume"] == {
        "thicknessFactor": 2.0,
        "thicknessTexture": {"index": 1, "texCoord": 1},
        "attenuationDistance": 4.0,
        "attenuationColor": [0.9, 0.8, 0.7],
    }
    assert ext["KHR_materials_diffuse_transmission"] == {
        "diffuseTransmissionFactor": 0.4, "diffuseTransmissionColorFactor": [1.0, 0.95, 0.9],
    }
    assert ext["KHR_materials_ior"] == {"ior": 1.5}
    assert {EXTENSION, "KHR_materials_volume", "KHR_materials_diffuse_transmission",
            "KHR_materials_ior"} <= set(gltf.extensionsUsed)
    assert not gltf.extensionsRequired  # a viewer that ignores sssbake still shows the fallback
    assert marble.extras == {}
    assert marble.extensions[EXTENSION] == {
        "schemaVersion": SCHEMA_VERSION,
        "material": {**preset("marble").to_json(), "units": "1/mm"},
        "sourceName": "Marble",
    }

    steel = gltf.materials[1]
    assert steel.extensions == {} and steel.extras == {}
    assert steel.pbrMetallicRoughness.metallicFactor == 1.0
    assert steel.occlusionTexture.index == 0 and steel.emissiveTexture.index == 0 and steel.doubleSided
    assert steel.emissiveFactor == [0.1, 0.2, 0.3]

    assert [(t.sampler, t.source) for t in gltf.textures] == [(0, 0), (1, 1)]
    assert (gltf.samplers[0].magFilter, gltf.samplers[0].minFilter) == (9729, 9987)
    blob = gltf.binary_blob()
    for image, source in zip(gltf.images, asset.scene.images):
        view = gltf.bufferViews[image.bufferView]
        assert image.mimeType == "image/png"
        assert blob[view.byteOffset:view.byteOffset + view.byteLength] == source.data


def test_base_color_texture_kept_only_when_asked():
    base = icosphere_asset()
    src = base.scene.materials[0]
    textured = SourceMaterial(src.name, base_color_factor=(0.2, 0.3, 0.4, 1.0), base_color_texture=TextureRef(0, 0))
    scene = Scene(base.scene.source, base.scene.meshes, base.scene.nodes, base.scene.roots,
                  (textured, base.scene.materials[1]), base.scene.textures, base.scene.images)
    for keep, factor, texture in [(True, [0.2, 0.3, 0.4, 1.0], 0), (False, [0.83, 0.79, 0.75, 1.0], None)]:
        sm = ScatteringMaterial(preset("marble"), base.scattering[0].fallback, "Marble", keep_base_color_texture=keep)
        data, _ = to_glb(BakedAsset(scene, base.vertex_attributes, {0: sm}, base.scale_mm))
        pbr = pygltflib.GLTF2.load_from_bytes(data).materials[0].pbrMetallicRoughness
        assert pbr.baseColorFactor == factor
        assert (pbr.baseColorTexture.index if pbr.baseColorTexture else None) == texture


def test_normal_and_metallic_roughness_textures_keep_their_texcoord():
    base = icosphere_asset()
    steel = SourceMaterial("Steel", normal_texture=TextureRef(0, 1), metallic_roughness_texture=TextureRef(1, 0))
    scene = Scene(base.scene.source, base.scene.meshes, base.scene.nodes, base.scene.roots,
                  (base.scene.materials[0], steel), base.scene.textures, base.scene.images)
    material = pygltflib.GLTF2.load_from_bytes(to_glb(BakedAsset(scene))[0]).materials[1]
    assert (material.normalTexture.index, material.normalTexture.texCoord) == (0, 1)
    mr = material.pbrMetallicRoughness.metallicRoughnessTexture
    assert (mr.index, mr.texCoord) == (1, 0)


def test_nodes_hierarchy_and_matrices():
    asset = icosphere_asset()
    gltf = pygltflib.GLTF2.load_from_bytes(to_glb(asset)[0])
    assert gltf.scenes[gltf.scene].nodes == [0]
    root, plate = gltf.nodes
    assert root.mesh == 0 and root.children == [1] and root.name == "root"
    np.testing.assert_array_equal(np.array(root.matrix).reshape(4, 4).T, asset.scene.nodes[0].matrix)
    assert plate.matrix is None and plate.mesh == 1


def test_translation_is_written_column_major():
    base = icosphere_asset()
    m = np.eye(4)
    m[:3, 3] = [1.0, 2.0, 3.0]
    scene = Scene(base.scene.source, base.scene.meshes, (Node("root", m, mesh=0, children=(1,)), base.scene.nodes[1]),
                  base.scene.roots, base.scene.materials, base.scene.textures, base.scene.images)
    gltf = pygltflib.GLTF2.load_from_bytes(to_glb(BakedAsset(scene))[0])
    assert gltf.nodes[0].matrix[12:15] == [1.0, 2.0, 3.0]


def test_asset_extras_and_tables():
    table = np.arange(12.0).reshape(4, 3) / 7.0
    matrices = np.stack([np.arange(16.0).reshape(4, 4), np.eye(4)])
    asset = icosphere_asset(extras={"warnings": [], "note": "", "profile": {"radii": table, "ids": np.array([3, 1])},
                                    "m": matrices, "count": np.int64(5)})
    gltf = pygltflib.GLTF2.load_from_bytes(to_glb(asset)[0])
    assert gltf.extras == {}
    root = gltf.extensions[EXTENSION]
    assert root["schemaVersion"] == SCHEMA_VERSION
    assert root["warnings"] == [] and root["note"] == "" and root["count"] == 5
    assert root["scaleMm"] == {"sphere": 10.0}
    assert [a["name"] for a in root["attributes"]] == ["_THICKNESS", "_SSS_W", "_SSS_U16", "_SSS_REF"]
    assert root["attributes"][1] == {"name": "_SSS_W", "key": "sss:w", "unit": "", "encoding": "snorm8",
                                     "description": "weights"}
    np.testing.assert_array_equal(read_accessor(gltf, root["profile"]["radii"]["accessor"]), table.astype(np.float32))
    ids = read_accessor(gltf, root["profile"]["ids"]["accessor"])
    assert ids.dtype == np.uint32 and ids.tolist() == [3, 1]
    assert gltf.accessors[root["m"]["accessor"]].type == "MAT4"
    np.testing.assert_array_equal(read_accessor(gltf, root["m"]["accessor"]), matrices)
    # Table references name their accessor and describe it.
    radii = root["profile"]["radii"]
    assert radii["name"] == "sssbake/asset/profile/radii" == gltf.accessors[radii["accessor"]].name
    assert (radii["count"], radii["type"], radii["componentType"]) == (4, "VEC3", FLOAT)
    assert root["m"]["name"] == "sssbake/asset/m" and root["m"]["type"] == "MAT4"
    assert gltf.meshes[0].extensions[EXTENSION] == {
        "schemaVersion": SCHEMA_VERSION, "scaleMm": 10.0, "vertexCounts": [42],
        "attributeTypes": {"_SSS_REF": "VEC4", "_SSS_U16": "VEC2", "_SSS_W": "VEC3", "_THICKNESS": "SCALAR"}}
    assert gltf.meshes[1].extras == {} and gltf.meshes[1].extensions == {}
    assert gltf.asset.generator.startswith("sssbake ")


def test_extras_match_the_documented_schema():
    schema = json.loads(resources.files("sssbake.exporters").joinpath("schema/sssbake.schema.json").read_text())
    jsonschema.Draft202012Validator.check_schema(schema)
    assert schema["version"] == SCHEMA_VERSION
    gltf = pygltflib.GLTF2.load_from_bytes(to_glb(icosphere_asset())[0])
    validator = jsonschema.Draft202012Validator(schema)
    validator.validate(gltf.extensions[EXTENSION])
    sub = {"$schema": schema["$schema"], "$defs": schema["$defs"]}
    jsonschema.Draft202012Validator({**sub, "$ref": "#/$defs/material"}).validate(
        gltf.materials[0].extensions[EXTENSION])
    jsonschema.Draft202012Validator({**sub, "$ref": "#/$defs/mesh"}).validate(gltf.meshes[0].extensions[EXTENSION])


def test_uint32_indices_from_65536_vertices():
    n = 65536
    positions = np.c_[np.arange(n, dtype=np.float64), np.zeros(n), np.zeros(n)]
    positions[1::2, 1] = 1.0
    faces = np.array([[0, 1, n - 1]])
    scene = Scene("memory", (Mesh("big", (Primitive(positions, faces),)),), (Node("n", mesh=0),), (0,))
    gltf = pygltflib.GLTF2.load_from_bytes(to_glb(BakedAsset(scene))[0])
    idx = gltf.meshes[0].primitives[0].indices
    assert gltf.accessors[idx].componentType == UNSIGNED_INT
    assert read_accessor(gltf, idx).tolist() == [0, 1, n - 1]


def test_summary_accounts_for_every_byte():
    data, summary = to_glb(icosphere_asset())
    assert summary["bytes"] == len(data)
    assert sum(summary["kinds"].values()) == summary["bin_bytes"]
    assert summary["bytes"] == 12 + 8 + summary["json_bytes"] + 8 + summary["bin_bytes"]
    n = summary["vertices"]
    assert n == 42 + 3
    per_vertex = summary["bytes_per_vertex"]
    # float32 scalar, snorm8 VEC3 padded to 4, unorm16 VEC2, float32 VEC4
    assert (per_vertex["_THICKNESS"], per_vertex["_SSS_W"], per_vertex["_SSS_U16"], per_vertex["_SSS_REF"]) == (
        4.0, 4.0, 4.0, 16.0)
    assert per_vertex["POSITION"] == 12.0 and per_vertex["COLOR_0"] == 16.0
    assert per_vertex["sssbake"] == pytest.approx(28.0 * 42 / n)
    assert summary["blocks"]["images"] == sum(len(i.data) for i in icosphere_asset().scene.images)


@pytest.mark.parametrize("where", ["attribute", "position", "extras"])
def test_non_finite_data_raises_and_leaves_nothing(tmp_path, where):
    asset = icosphere_asset()
    if where == "attribute":
        attrs = list(asset.vertex_attributes[(0, 0)])
        bad = attrs[0].data.copy()
        bad[3] = np.nan
        attrs[0] = VertexAttribute("thickness", bad, "mm")
        asset = BakedAsset(asset.scene, {(0, 0): tuple(attrs)}, asset.scattering, asset.scale_mm)
        needle = "_THICKNESS"
    elif where == "position":
        prim = asset.scene.meshes[1].primitives[0]
        pos = prim.positions.copy()
        pos[0, 0] = np.inf
        meshes = (asset.scene.meshes[0], Mesh("plate", (Primitive(pos, prim.faces, material=1),)))
        scene = Scene("memory", meshes, asset.scene.nodes, asset.scene.roots, asset.scene.materials,
                      asset.scene.textures, asset.scene.images)
        asset = BakedAsset(scene, asset.vertex_attributes, asset.scattering)
        needle = "POSITION"
    else:
        asset = icosphere_asset(extras={"table": np.array([1.0, np.nan])})
        needle = "extras.table"
    with pytest.raises(ValueError, match=needle):
        write_glb(asset, tmp_path / "bad.glb")
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("encoding,values", [("unorm8", [-0.1, 0.5]), ("snorm16", [0.0, 1.5])])
def test_normalized_data_out_of_range_raises(encoding, values):
    asset = icosphere_asset()
    n = len(asset.scene.meshes[0].primitives[0].positions)
    data = np.resize(np.array(values, dtype=np.float64), n)
    bad = BakedAsset(asset.scene, {(0, 0): (VertexAttribute("x", data, "", encoding),)})
    with pytest.raises(ValueError, match=f"_X: {encoding} needs values"):
        to_glb(bad)


def test_attribute_of_wrong_length_raises():
    asset = icosphere_asset()
    bad = BakedAsset(asset.scene, {(0, 0): (VertexAttribute("x", np.zeros(5)),)})
    with pytest.raises(ValueError, match="_X has shape"):
        to_glb(bad)


def _with_plate(asset: BakedAsset, plate: Primitive) -> BakedAsset:
    """`asset` with mesh 1's triangle replaced by `plate`."""
    scene = Scene("memory", (asset.scene.meshes[0], Mesh("plate", (plate,))), asset.scene.nodes, asset.scene.roots,
                  asset.scene.materials, asset.scene.textures, asset.scene.images)
    return BakedAsset(scene, asset.vertex_attributes, asset.scattering, asset.scale_mm)


def test_tangents_are_written_as_unit_float_vec4():
    asset = icosphere_asset()
    tri = asset.scene.meshes[1].primitives[0]
    # Not quite unit and not quite ±1, as data read from a file can be.
    given = np.array([[2.0, 0.0, 0.0, 1.0], [0.0, 0.5, 0.0, -0.999], [0.6, 0.8, 0.0, 1.0]])
    data, summary = to_glb(_with_plate(asset, Primitive(tri.positions, tri.faces, tri.normals, tri.uvs,
                                                        material=1, tangents=given)))
    gltf = pygltflib.GLTF2.load_from_bytes(data)
    attrs = gltf.meshes[1].primitives[0].attributes
    acc = gltf.accessors[attrs.TANGENT]
    assert (acc.componentType, acc.type) == (FLOAT, "VEC4") and not acc.normalized
    assert gltf.bufferViews[acc.bufferView].target == ARRAY_BUFFER
    np.testing.assert_allclose(read_accessor(gltf, attrs.TANGENT),
                               [[1.0, 0.0, 0.0, 1.0], [0.0, 1.0, 0.0, -1.0], [0.6, 0.8, 0.0, 1.0]], atol=1e-7)
    assert summary["bytes_per_vertex"]["TANGENT"] == 16.0
    assert gltf.meshes[0].primitives[0].attributes.TANGENT is None


@pytest.mark.parametrize("tangents,needle", [
    (np.ones((4, 4)), r"TANGENT has shape \(4, 4\), expected \(3, 4\)"),
    (np.array([[1.0, 0, 0, 1]] * 2 + [[np.nan, 0, 0, 1]]), "TANGENT has non-finite"),
    (np.array([[1.0, 0, 0, 1]] * 2 + [[0.0, 0, 0, 1]]), "TANGENT has zero-length"),
])
def test_bad_tangents_raise(tangents, needle):
    asset = icosphere_asset()
    tri = asset.scene.meshes[1].primitives[0]
    with pytest.raises(ValueError, match=needle):
        to_glb(_with_plate(asset, Primitive(tri.positions, tri.faces, tri.normals, tri.uvs, material=1,
                                            tangents=tangents)))


def test_scattering_materials_are_dielectric():
    asset = icosphere_asset()
    metal = SourceMaterial("Marble", metallic_factor=1.0, metallic_roughness_texture=TextureRef(0, 0))
    scene = Scene("memory", asset.scene.meshes, asset.scene.nodes, asset.scene.roots,
                  (metal, asset.scene.materials[1]), asset.scene.textures, asset.scene.images)
    data, _ = to_glb(BakedAsset(scene, asset.vertex_attributes, asset.scattering, asset.scale_mm))
    doc = json.loads(data[20:20 + int.from_bytes(data[12:16], "little")])
    # Written explicitly: an absent metallicFactor means 1.
    assert doc["materials"][0]["pbrMetallicRoughness"]["metallicFactor"] == 0.0
    assert doc["materials"][1]["pbrMetallicRoughness"]["metallicFactor"] == 1.0


def test_mesh_extras_and_integer_encodings_round_trip():
    codes = (np.arange(30) % 256).astype(np.uint8).reshape(10, 3)
    signed = np.array([[-128, 127], [0, -1]], dtype=np.int8)
    asset = icosphere_asset()
    n = len(asset.scene.meshes[0].primitives[0].positions)
    index = VertexAttribute("sss:prt:ref", np.c_[np.arange(n) % 7, np.full(n, 65535)], "", "uint16", "indices")
    asset = replace(asset, vertex_attributes={(0, 0): asset.vertex_attributes[(0, 0)] + (index,)},
                    mesh_extras={0: {"prt": {"codes": codes, "signed": signed, "order": 3}}})
    gltf = pygltflib.GLTF2.load_from_bytes(to_glb(asset)[0])
    mesh = gltf.meshes[0].extensions[EXTENSION]
    assert mesh["scaleMm"] == 10.0 and mesh["prt"]["order"] == 3
    assert mesh["prt"]["codes"]["name"] == "sssbake/mesh0/prt/codes"
    stored = read_accessor(gltf, mesh["prt"]["codes"]["accessor"])
    assert stored.dtype == np.uint8 and gltf.accessors[mesh["prt"]["codes"]["accessor"]].type == "VEC3"
    np.testing.assert_array_equal(stored, codes)
    np.testing.assert_array_equal(read_accessor(gltf, mesh["prt"]["signed"]["accessor"]), signed)
    ref = gltf.meshes[0].primitives[0].attributes._SSS_PRT_REF
    assert gltf.accessors[ref].componentType == UNSIGNED_SHORT and not gltf.accessors[ref].normalized
    np.testing.assert_array_equal(read_accessor(gltf, ref), index.data)


def test_uint16_attributes_must_be_integers_in_range():
    asset = icosphere_asset()
    n = len(asset.scene.meshes[0].primitives[0].positions)
    for bad in (np.full(n, 65536.0), np.full(n, 0.5), np.full(n, -1.0)):
        attr = VertexAttribute("sss:prt:ref", bad, "", "uint16", "")
        with pytest.raises(ValueError, match="uint16 needs integers"):
            to_glb(replace(asset, vertex_attributes={(0, 0): (attr,)}))
    with pytest.raises(ValueError, match="reserved keys"):
        to_glb(replace(asset, mesh_extras={0: {"scaleMm": 1.0}}))


def spectral_parts(prim: Primitive, m: int = 5) -> tuple[np.ndarray, tuple[VertexAttribute, ...], dict]:
    """Tilted unit normals of `prim`'s vertices (welded one to one), their spectral attributes and
    tables over a random basis of m harmonics."""
    from sssbake.pipeline.techniques.spectral.layout import spectral_tables, spectral_vertex_attributes
    from sssbake.pipeline.techniques.spectral.normals import normal_spectrum

    n = len(prim.positions)
    normals = prim.normals + 0.3 * np.sin(3 * prim.positions)
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    rng = np.random.default_rng(3)
    spectrum = normal_spectrum(rng.normal(size=(n, m)), np.sort(rng.uniform(0, 2, m)), 5.0, rng.uniform(0.5, 1, n),
                               normals)
    return normals, spectral_vertex_attributes(normals, np.arange(n), True), spectral_tables(spectrum, 0.7, 0.4)


def test_spectral_normals_and_tables_round_trip_and_validate(tmp_path):
    from sssbake.exporters.gltf import ENCODINGS
    from sssbake.exporters.gltf_validator import ValidatorUnavailable, validate_glb

    asset = icosphere_asset()
    normals, attrs, tables = spectral_parts(asset.scene.meshes[0].primitives[0])
    asset = replace(asset, vertex_attributes={(0, 0): asset.vertex_attributes[(0, 0)] + attrs},
                    mesh_extras={0: {"spectral": tables}})
    data, summary = to_glb(asset)
    gltf = pygltflib.GLTF2.load_from_bytes(data)
    index = gltf.meshes[0].primitives[0].attributes._SSS_NORMAL
    acc = gltf.accessors[index]
    (encoding,) = [a.encoding for a in attrs if a.gltf_name == "_SSS_NORMAL"]
    component, dtype, normalized = ENCODINGS[encoding]
    assert (acc.componentType, acc.type, bool(acc.normalized)) == (component, "VEC3", normalized)
    stride = -(-3 * np.dtype(dtype).itemsize // 4) * 4
    assert gltf.bufferViews[acc.bufferView].byteStride == stride == summary["bytes_per_vertex"]["_SSS_NORMAL"]
    decoded = dequantize(read_accessor(gltf, index), normalized)
    assert np.abs(decoded - normals).max() <= quantization_step(encoding) + 1e-7  # float32: relative 2^-24
    (tmp_path / "a.glb").write_bytes(data)
    read = technique_tables(load_sssbake_gltf(tmp_path / "a.glb"), "meshes", 0, "spectral")
    for name, value in tables.items():
        np.testing.assert_array_equal(read[name], value)
    schema = json.loads(resources.files("sssbake.exporters").joinpath("schema/sssbake.schema.json").read_text())
    sub = {"$schema": schema["$schema"], "$defs": schema["$defs"]}
    jsonschema.Draft202012Validator({**sub, "$ref": "#/$defs/mesh"}).validate(gltf.meshes[0].extensions[EXTENSION])
    try:
        report = validate_glb(data)
    except ValidatorUnavailable as exc:
        pytest.skip(str(exc))
    assert (report.num_errors, report.num_warnings) == (0, 0), report.to_json()


def test_screen_tables_on_the_material_round_trip_and_validate(tmp_path):
    from fixtures import bake_screen_sphere, baked_material

    from sssbake.exporters.gltf_validator import ValidatorUnavailable, validate_glb
    from sssbake.pipeline.techniques.screen.samples import screen_samples

    result, options = bake_screen_sphere(tmp_path, screen_samples=12, screen_uniform=4)
    data = (tmp_path / "ball.glb").read_bytes()
    gltf = pygltflib.GLTF2.load_from_bytes(data)
    (index,) = [i for i, m in enumerate(gltf.materials) if EXTENSION in m.extensions]
    material = gltf.materials[index]
    assert "screen" not in gltf.meshes[0].extensions[EXTENSION]
    tables = technique_tables(load_sssbake_gltf(tmp_path / "ball.glb"), "materials", index, "screen")
    expected = screen_samples(baked_material(result), options.technique_options("screen").samples_options())
    assert (tables["technique"], tables["samples"], tables["uniform"], tables["driver"]) == (
        "screen", 12, 4, expected.driver)
    assert tables["tableReachMm"] == pytest.approx(expected.table_reach_mm, rel=1e-12)
    for name, value in (("offsets", expected.offsets), ("weights", expected.weights), ("rdTable", expected.table.T)):
        acc = gltf.accessors[material.extensions[EXTENSION]["screen"][name]["accessor"]]
        assert acc.componentType == FLOAT and acc.bufferView is not None
        np.testing.assert_array_equal(tables[name], value.astype(np.float32))
    assert tables["offsets"].shape == (16, 2) and tables["rdTable"].shape[1] == 3
    report = result.report["screen"]
    (entry,) = report.values()
    assert entry["samples"] == 12 and entry["tableSize"] == len(tables["rdTable"])
    assert entry["bytes"]["total"] == 4 * (32 + 16 + 3 * len(tables["rdTable"]))
    assert result.report["stages"]["screen"]["runs"] == 1
    schema = json.loads(resources.files("sssbake.exporters").joinpath("schema/sssbake.schema.json").read_text())
    sub = {"$schema": schema["$schema"], "$defs": schema["$defs"]}
    jsonschema.Draft202012Validator({**sub, "$ref": "#/$defs/material"}).validate(material.extensions[EXTENSION])
    try:
        checked = validate_glb(data)
    except ValidatorUnavailable as exc:
        pytest.skip(str(exc))
    assert (checked.num_errors, checked.num_warnings) == (0, 0), checked.to_json()


def test_material_extras_need_a_scattering_material():
    asset = icosphere_asset()
    with pytest.raises(ValueError, match=r"material_extras of materials \[1\]"):
        to_glb(replace(asset, material_extras={1: {"screen": {"weights": np.ones(3)}}}))
    with pytest.raises(ValueError, match=r"material_extras refers to materials \[7\]"):
        to_glb(replace(asset, material_extras={7: {}}))
