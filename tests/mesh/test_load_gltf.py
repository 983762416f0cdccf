"""glTF/GLB reading: hierarchy and transforms, materials and images, accessor layouts, errors."""

import base64
import io
import json
from pathlib import Path

import numpy as np
import pygltflib
import pytest
from PIL import Image as PILImage

from sssbake.pipeline.core.errors import AssetError
from sssbake.pipeline.mesh.load import load_scene

TRI = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [1.0, 1.0, 0.0]], np.float32)
TRI_FACES = np.array([[0, 1, 2], [1, 3, 2]], np.uint16)
UV = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0], [1.0, 1.0]], np.float32)
NORMALS = np.tile(np.array([0.0, 0.0, 1.0], np.float32), (4, 1))
COLORS = np.array([[255, 0, 0, 255], [0, 255, 0, 128], [0, 0, 255, 0]], np.uint8)
QUARTER_TURN_Z = [0.0, 0.0, np.sqrt(0.5), np.sqrt(0.5)]


def _png() -> bytes:
    buf = io.BytesIO()
    PILImage.new("RGB", (2, 2), (200, 100, 50)).save(buf, format="PNG")
    return buf.getvalue()


def _two_node_gltf(png: bytes) -> pygltflib.GLTF2:
    """Root node (TRS, indexed mesh, material 0 with texture) with a child (matrix, non-indexed mesh)."""
    chunks = [TRI.tobytes(), NORMALS.tobytes(), UV.tobytes(), TRI_FACES.tobytes(),
              TRI[:3].tobytes(), COLORS.tobytes(), png]
    offsets = np.concatenate([[0], np.cumsum([len(c) for c in chunks])])
    blob = b"".join(chunks)
    views = [pygltflib.BufferView(buffer=0, byteOffset=int(o), byteLength=len(c)) for o, c in zip(offsets, chunks)]
    acc = pygltflib.Accessor
    child = np.eye(4)
    child[:3, 3] = [0.0, 0.0, 5.0]
    gltf = pygltflib.GLTF2(
        scene=0,
        scenes=[pygltflib.Scene(nodes=[0])],
        nodes=[
            pygltflib.Node(name="root", mesh=0, children=[1], translation=[1.0, 2.0, 3.0], rotation=QUARTER_TURN_Z,
                           scale=[2.0, 2.0, 2.0]),
            pygltflib.Node(name="child", mesh=1, matrix=child.T.ravel().tolist()),
        ],
        meshes=[
            pygltflib.Mesh(name="body", primitives=[pygltflib.Primitive(
                attributes=pygltflib.Attributes(POSITION=0, NORMAL=1, TEXCOORD_0=2), indices=3, material=0)]),
            pygltflib.Mesh(name="cap", primitives=[pygltflib.Primitive(
                attributes=pygltflib.Attributes(POSITION=4, COLOR_0=5), material=1)]),
        ],
        accessors=[
            acc(bufferView=0, componentType=5126, count=4, type="VEC3"),
            acc(bufferView=1, componentType=5126, count=4, type="VEC3"),
            acc(bufferView=2, componentType=5126, count=4, type="VEC2"),
            acc(bufferView=3, componentType=5123, count=6, type="SCALAR"),
            acc(bufferView=4, componentType=5126, count=3, type="VEC3"),
            acc(bufferView=5, componentType=5121, normalized=True, count=3, type="VEC4"),
        ],
        materials=[
            pygltflib.Material(
                name="Wax",
                pbrMetallicRoughness=pygltflib.PbrMetallicRoughness(
                    baseColorFactor=[0.9, 0.8, 0.7, 1.0], metallicFactor=0.0, roughnessFactor=0.4,
                    baseColorTexture=pygltflib.TextureInfo(index=0, texCoord=0)),
                doubleSided=True,
                extensions={
                    "KHR_materials_ior": {"ior": 1.45},
                    "KHR_materials_volume": {"thicknessFactor": 0.2, "attenuationDistance": 0.01},
                    "KHR_materials_diffuse_transmission": {"diffuseTransmissionFactor": 0.5},
                },
            ),
            pygltflib.Material(name="Brass", emissiveFactor=[0.1, 0.0, 0.0],
                               normalTexture=pygltflib.NormalMaterialTexture(index=0, texCoord=1)),
        ],
        textures=[pygltflib.Texture(sampler=0, source=0)],
        samplers=[pygltflib.Sampler(magFilter=9729, minFilter=9987, wrapS=33071)],
        images=[pygltflib.Image(name="wax_color", bufferView=6, mimeType="image/png")],
        buffers=[pygltflib.Buffer(byteLength=len(blob))],
        bufferViews=views,
        extensionsUsed=["KHR_materials_ior", "KHR_materials_volume", "KHR_materials_diffuse_transmission"],
    )
    gltf.set_binary_blob(blob)
    return gltf


@pytest.fixture(params=["glb", "gltf"])
def two_node_file(request, tmp_path):
    png = _png()
    gltf = _two_node_gltf(png)
    if request.param == "glb":
        path = tmp_path / "scene.glb"
        gltf.save_binary(str(path))
    else:
        gltf.buffers[0].uri = "data:application/octet-stream;base64," + base64.b64encode(gltf.binary_blob()).decode()
        gltf.destroy_binary_blob()
        path = tmp_path / "scene.gltf"
        path.write_text(gltf.gltf_to_json())
    return path, png


def test_two_node_round_trip(two_node_file):
    path, png = two_node_file
    scene = load_scene(path)
    assert scene.meters_per_unit == 1.0 and scene.up_axis == "Y" and scene.roots == (0,)
    assert [n.name for n in scene.nodes] == ["root", "child"] and scene.nodes[0].children == (1,)
    body, cap = (m.primitives[0] for m in scene.meshes)
    assert [m.name for m in scene.meshes] == ["body", "cap"]
    np.testing.assert_array_equal(body.positions, TRI)
    np.testing.assert_array_equal(body.faces, TRI_FACES)
    np.testing.assert_array_equal(body.normals, NORMALS)
    np.testing.assert_array_equal(body.uvs[0], UV)
    assert body.positions.dtype == body.uvs[0].dtype == np.float64 and body.faces.dtype == np.int64
    np.testing.assert_array_equal(cap.faces, [[0, 1, 2]])
    np.testing.assert_allclose(cap.colors, COLORS / 255.0)
    assert cap.normals is None and cap.uvs == () and (body.material, cap.material) == (0, 1)

    rot = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    root = np.eye(4)
    root[:3, :3], root[:3, 3] = 2.0 * rot, [1.0, 2.0, 3.0]
    child = np.eye(4)
    child[2, 3] = 5.0
    world = scene.world_matrices()
    np.testing.assert_allclose(world[0], root, atol=1e-12)
    np.testing.assert_allclose(world[1], root @ child, atol=1e-12)
    np.testing.assert_allclose(world[1][:3, 3], [1.0, 2.0, 13.0], atol=1e-12)

    wax, brass = scene.materials
    assert (wax.name, brass.name) == ("Wax", "Brass")
    assert wax.base_color_factor == pytest.approx((0.9, 0.8, 0.7, 1.0))
    assert (wax.metallic_factor, wax.roughness_factor, wax.double_sided, wax.ior) == (0.0, 0.4, True, 1.45)
    assert wax.base_color_texture.texture == 0 and wax.base_color_texture.tex_coord == 0
    assert wax.volume == {"thicknessFactor": 0.2, "attenuationDistance": 0.01}
    assert wax.diffuse_transmission == {"diffuseTransmissionFactor": 0.5}
    # glTF's own defaults for a material without pbrMetallicRoughness.
    assert (brass.metallic_factor, brass.roughness_factor, brass.ior, brass.volume) == (1.0, 1.0, None, None)
    assert brass.normal_texture.tex_coord == 1 and brass.emissive_factor == pytest.approx((0.1, 0.0, 0.0))
    (tex,) = scene.textures
    assert (tex.image, tex.mag_filter, tex.min_filter, tex.wrap_s, tex.wrap_t) == (0, 9729, 9987, 33071, 10497)
    (image,) = scene.images
    assert (image.name, image.mime_type, image.data) == ("wax_color", "image/png", png)


def _raw_gltf(arrays: list[tuple[np.ndarray, str, dict]], **top) -> tuple[dict, bytes]:
    """glTF JSON with one buffer view + accessor per (array, type, accessor extras) and the blob."""
    component = {np.dtype("float32"): 5126, np.dtype("uint8"): 5121, np.dtype("uint16"): 5123,
                 np.dtype("uint32"): 5125, np.dtype("int16"): 5122}
    views, accessors, blob = [], [], b""
    for values, kind, extra in arrays:
        data = np.ascontiguousarray(values).tobytes()
        views.append({"buffer": 0, "byteOffset": len(blob), "byteLength": len(data)})
        accessors.append({"bufferView": len(views) - 1, "componentType": component[values.dtype],
                          "count": len(values), "type": kind, **extra})
        blob += data + b"\0" * (-len(data) % 4)
    gltf = {"asset": {"version": "2.0"}, "buffers": [{"byteLength": len(blob)}], "bufferViews": views,
            "accessors": accessors, **top}
    return gltf, blob


def _write(path: Path, gltf: dict, blob: bytes) -> Path:
    gltf["buffers"][0]["uri"] = "data:application/octet-stream;base64," + base64.b64encode(blob).decode()
    path.write_text(json.dumps(gltf))
    return path


def test_material_extensions_are_plain_json_the_stage_cache_stores(tmp_path):
    from sssbake.pipeline.bake.cache_codec import dumps, loads

    gltf = _two_node_gltf(_png())
    scatter = {"multiscatterColor": [0.9, 0.5, 0.2], "scatterAnisotropy": 0.0}
    gltf.materials[0].extensions["KHR_materials_volume"]["thicknessTexture"] = {"index": 0, "texCoord": 0}
    gltf.materials[0].extensions["KHR_materials_volume_scatter"] = scatter
    gltf.extensionsUsed.append("KHR_materials_volume_scatter")
    gltf.extensionsRequired = ["KHR_materials_volume_scatter"]  # read, so a file may require it
    gltf.save_binary(str(tmp_path / "a.glb"))
    scene = load_scene(tmp_path / "a.glb")
    wax = scene.materials[0]
    assert wax.volume_scatter == scatter and scene.materials[1].volume_scatter is None
    assert type(wax.volume["thicknessTexture"]) is dict
    # a GltfObject in it was refused: no glTF with a volume thickness texture (any sssbake output) baked
    assert loads(b"".join(dumps(scene))).materials[0] == wax

    gltf.materials[0].extensions["KHR_materials_volume_scatter"] = [0.9, 0.5, 0.2]
    gltf.save_binary(str(tmp_path / "b.glb"))
    with pytest.raises(AssetError, match=r"material 0: KHR_materials_volume_scatter is \[0.9, 0.5, 0.2\], not an object"):
        load_scene(tmp_path / "b.glb")


def test_interleaved_normalized_sparse_and_extra_uv_sets(tmp_path):
    n = 4
    vertex = np.zeros(n, dtype=[("p", "<f4", 3), ("c", "<u2", 3), ("pad", "u1", 2)])
    vertex["p"], vertex["c"] = TRI, [[65535, 0, 0], [0, 65535, 0], [0, 0, 65535], [32768, 32768, 32768]]
    stride = vertex.dtype.itemsize
    gltf, blob = _raw_gltf([
        (vertex.view(np.uint8).reshape(n, stride), "SCALAR", {}),
        (TRI_FACES.ravel(), "SCALAR", {}),
        (UV, "VEC2", {}),
        (UV[::-1].copy(), "VEC2", {}),
        (np.array([3], np.uint16), "SCALAR", {}),
        (np.array([[0.0, 0.0, 7.0]], np.float32), "VEC3", {}),
    ])
    gltf["bufferViews"][0]["byteStride"] = stride
    gltf["accessors"][0].update(componentType=5126, type="VEC3", count=n)
    gltf["accessors"].append({"bufferView": 0, "byteOffset": 12, "componentType": 5123, "normalized": True,
                              "count": n, "type": "VEC3"})
    # Sparse override of vertex 3's position, on top of the interleaved data.
    gltf["accessors"][0]["sparse"] = {"count": 1, "indices": {"bufferView": 4, "componentType": 5123},
                                      "values": {"bufferView": 5}}
    gltf["meshes"] = [{"primitives": [{"attributes": {"POSITION": 0, "COLOR_0": 6, "TEXCOORD_0": 2, "TEXCOORD_1": 3},
                                       "indices": 1}]}]
    gltf["nodes"] = [{"mesh": 0}]
    prim = load_scene(_write(tmp_path / "i.gltf", gltf, blob)).meshes[0].primitives[0]
    expected = TRI.astype(np.float64)
    expected[3] = [0.0, 0.0, 7.0]
    np.testing.assert_array_equal(prim.positions, expected)
    np.testing.assert_allclose(prim.colors[:, :3], vertex["c"] / 65535.0)
    np.testing.assert_array_equal(prim.colors[:, 3], 1.0)
    np.testing.assert_array_equal(prim.uvs[1], UV[::-1])
    assert len(prim.uvs) == 2


def test_strip_fan_and_skipped_lines(tmp_path):
    strip = np.array([0, 1, 2, 3], np.uint16)
    gltf, blob = _raw_gltf([(TRI, "VEC3", {}), (strip, "SCALAR", {})])
    gltf["meshes"] = [{"primitives": [{"attributes": {"POSITION": 0}, "indices": 1, "mode": 5},
                                      {"attributes": {"POSITION": 0}, "indices": 1, "mode": 6},
                                      {"attributes": {"POSITION": 0}, "mode": 1}]}]
    gltf["nodes"] = [{"mesh": 0}]
    strip_prim, fan_prim = load_scene(_write(tmp_path / "s.gltf", gltf, blob)).meshes[0].primitives
    np.testing.assert_array_equal(strip_prim.faces, [[0, 1, 2], [1, 3, 2]])
    np.testing.assert_array_equal(fan_prim.faces, [[1, 2, 0], [2, 3, 0]])
    normals = np.cross(TRI[strip_prim.faces[:, 1]] - TRI[strip_prim.faces[:, 0]],
                       TRI[strip_prim.faces[:, 2]] - TRI[strip_prim.faces[:, 0]])
    assert (normals[:, 2] > 0).all()  # the strip's second triangle keeps the first one's winding


def test_tangents_are_read_when_present(tmp_path):
    tangents = np.array([[1.0, 0.0, 0.0, 1.0], [0.0, 1.0, 0.0, -1.0], [1.0, 0.0, 0.0, 1.0], [0.0, 0.0, 1.0, -1.0]],
                        np.float32)
    gltf, blob = _raw_gltf([(TRI, "VEC3", {}), (TRI_FACES.ravel(), "SCALAR", {}), (tangents, "VEC4", {}),
                            (tangents[:, :3].copy(), "VEC3", {})])
    gltf["meshes"] = [{"primitives": [{"attributes": {"POSITION": 0, "TANGENT": 2}, "indices": 1},
                                      {"attributes": {"POSITION": 0}, "indices": 1}]}]
    gltf["nodes"] = [{"mesh": 0}]
    with_tangents, without = load_scene(_write(tmp_path / "t.gltf", gltf, blob)).meshes[0].primitives
    assert with_tangents.tangents.dtype == np.float64
    np.testing.assert_array_equal(with_tangents.tangents, tangents)
    assert without.tangents is None
    gltf["meshes"][0]["primitives"][0]["attributes"]["TANGENT"] = 3
    with pytest.raises(AssetError, match="TANGENT accessor 3 has type VEC3, expected VEC4"):
        load_scene(_write(tmp_path / "t.gltf", gltf, blob))


def test_external_buffer_and_image_and_parentless_roots(tmp_path):
    png = _png()
    gltf, blob = _raw_gltf([(TRI, "VEC3", {}), (TRI_FACES.ravel(), "SCALAR", {})])
    (tmp_path / "geo data.bin").write_bytes(blob)
    (tmp_path / "tex").mkdir()
    (tmp_path / "tex" / "color.png").write_bytes(png)
    gltf["buffers"][0]["uri"] = "geo%20data.bin"
    gltf["images"] = [{"uri": "tex/color.png"}]
    gltf["textures"] = [{"source": 0}]
    gltf["meshes"] = [{"primitives": [{"attributes": {"POSITION": 0}, "indices": 1}]}]
    gltf["nodes"] = [{"mesh": 0, "children": [2]}, {"mesh": 0, "translation": [1, 0, 0]}, {"scale": [3, 3, 3]}]
    path = tmp_path / "ext.gltf"
    path.write_text(json.dumps(gltf))
    scene = load_scene(path)
    assert scene.roots == (0, 1)
    assert scene.images[0].data == png and scene.images[0].mime_type == "image/png" and scene.images[0].name == "color"
    assert scene.textures[0].image == 0 and scene.textures[0].wrap_s == 10497
    assert len(scene.mesh_instances()[0]) == 2


def _one_mesh(tmp_path, name: str, **edits) -> Path:
    gltf, blob = _raw_gltf([(TRI, "VEC3", {}), (TRI_FACES.ravel(), "SCALAR", {})])
    gltf["meshes"] = [{"primitives": [{"attributes": {"POSITION": 0}, "indices": 1}]}]
    gltf["nodes"] = [{"mesh": 0}]
    gltf.update(edits)
    return _write(tmp_path / name, gltf, blob)


@pytest.mark.parametrize("edits, needle", [
    ({"nodes": [{"mesh": 0, "children": [1]}, {"children": [1]}]},
     "node 1 is the child of more than one node (nodes 0 and 1)"),
    ({"nodes": [{"mesh": 0, "children": [1, 1]}, {}]}, "node 0 lists node 1 as a child twice"),
    ({"nodes": [{"mesh": 0, "children": [1]}, {}], "scenes": [{"nodes": [0, 1]}]},
     "scene root node 1 is also the child of another node"),
    ({"nodes": [{"mesh": 0, "children": [0]}], "scenes": [{"nodes": [0]}]},
     "the node graph has a cycle through node 0"),
    ({"nodes": [{"mesh": 3}]}, "mesh index 3 out of range"),
    ({"scene": 2, "scenes": [{"nodes": [0]}]}, "scene index 2 out of range"),
    ({"nodes": [{"mesh": 0, "matrix": [1, 0, 0]}]}, "malformed transform"),
    ({"materials": [], "meshes": [{"primitives": [{"attributes": {"POSITION": 0}, "material": 0}]}]},
     "material index 0 out of range"),
    ({"meshes": [{"primitives": [{"attributes": {"POSITION": 0}}]}]}, "4 indices is not a multiple of 3"),
    ({"meshes": [{"primitives": [{"attributes": {"NORMAL": 0}, "indices": 1}]}]}, "no POSITION"),
    ({"extensionsRequired": ["EXT_meshopt_compression"]},
     "EXT_meshopt_compression is required and not supported; decompress it first (gltfpack -i in.glb -o out.glb -noq)"),
    ({"extensionsRequired": ["KHR_texture_basisu"]}, "KHR_texture_basisu is required and not supported"),
    ({"textures": [{"extensions": {"KHR_texture_basisu": {"source": 0}}}],
      "images": [{"uri": "data:image/ktx2;base64,q0tUWCAyMLsNChoK"}]},
     "texture 0: its only image is an KHR_texture_basisu one (no PNG/JPEG fallback)"),
    ({"materials": [{"pbrMetallicRoughness": {"baseColorTexture": {
        "index": 0, "extensions": {"KHR_texture_transform": {"offset": [1.0]}}}}}],
      "textures": [{"source": 0}], "images": [{"uri": "data:image/png;base64,iVBORw0KGgo="}]},
     "baseColor texture: malformed KHR_texture_transform"),
    ({"nodes": [{"mesh": 0, "extensions": {"EXT_mesh_gpu_instancing": {"attributes": {}}}}]},
     "node 0 EXT_mesh_gpu_instancing: no instance attributes"),
    ({"nodes": 5}, "nodes is 5, not an array"),
    ({"nodes": [{"mesh": 0, "children": "1"}]}, "node 0: children is '1', not an array"),
    ({"meshes": [{"primitives": [{"attributes": {"POSITION": 0}, "targets": [3]}]}]},
     "mesh 0 primitive 0: morph target 0 is 3, not an object"),
    ({"accessors": [{"sparse": {"count": 1, "indices": [], "values": {}}}]},
     "accessor 0 sparse: indices is [], not an object"),
    ({"extensionsUsed": [["KHR_mesh_quantization"]]}, "extensionsUsed[0] is ['KHR_mesh_quantization'], not a string"),
    ({"nodes": [{"mesh": 0, "extensions": []}]}, "node 0: extensions is [], not an object"),
    ({"nodes": [{"mesh": 0, "rotation": [0, 0, 1]}]},
     "node 0 has a malformed transform (rotation is [0, 0, 1], not 4 numbers)"),
    ({"nodes": [{"mesh": 0, "translation": [0, "x", 1]}]},
     "node 0 has a malformed transform (translation is [0, 'x', 1], not 3 numbers)"),
    ({"nodes": [{}, {"mesh": 0, "scale": [1, 10**400, 1]}]}, "node 1 has a malformed transform (scale is an array, not 3"),
    ({"nodes": [{"mesh": 0, "matrix": [float("nan")] * 16}]}, "node 0 has a non-finite transform"),
])
def test_structural_errors(tmp_path, edits, needle):
    path = _one_mesh(tmp_path, "bad.gltf", **edits)
    with pytest.raises(AssetError) as info:
        load_scene(path)
    assert needle in str(info.value) and str(path) in str(info.value) and "\n" not in str(info.value)


def test_glb_chunk_errors(tmp_path):
    path = _one_mesh(tmp_path, "ok.gltf")
    gltf = pygltflib.GLTF2.load(str(path))
    gltf.convert_buffers(pygltflib.BufferFormat.BINARYBLOB)
    good = tmp_path / "ok.glb"
    gltf.save_binary(str(good))
    assert len(load_scene(good).meshes) == 1
    data = good.read_bytes()
    (tmp_path / "chunk.glb").write_bytes(data[:12] + (10**6).to_bytes(4, "little") + data[16:])
    with pytest.raises(AssetError, match="chunk 0 declares 1000000 bytes"):
        load_scene(tmp_path / "chunk.glb")
    (tmp_path / "v1.glb").write_bytes(data[:4] + (1).to_bytes(4, "little") + data[8:])
    with pytest.raises(AssetError, match="GLB version 1"):
        load_scene(tmp_path / "v1.glb")


def test_skinned_and_morphed_meshes_are_marked_deforming(tmp_path):
    import pygltflib
    import trimesh

    from sssbake.pipeline.mesh.load import load_scene

    path = tmp_path / "two.glb"
    scene = trimesh.Scene([trimesh.creation.box(), trimesh.creation.icosphere(subdivisions=1)])
    scene.export(path)
    gltf = pygltflib.GLTF2.load(str(path))
    assert len(gltf.meshes) == 2
    assert [m.deforming for m in load_scene(str(path)).meshes] == [False, False]
    # the first mesh gets a morph target (its own positions as the displacement), the second's node a skin
    prim = gltf.meshes[0].primitives[0]
    prim.targets = [{"POSITION": prim.attributes.POSITION}]
    node = next(n for n in gltf.nodes if n.mesh == 1)
    gltf.skins = [pygltflib.Skin(joints=[gltf.nodes.index(node)])]
    node.skin = 0
    gltf.save(str(tmp_path / "deforming.glb"))
    assert [m.deforming for m in load_scene(str(tmp_path / "deforming.glb")).meshes] == [True, True]


def test_required_mesh_quantization_is_read(tmp_path):
    """KHR_mesh_quantization (required, as gltfpack writes it): integer positions are their integer
    values (the node's scale dequantizes them), normalized byte normals map to [-1, 1]."""
    positions = (TRI * 1000).astype(np.int16)
    padded = np.zeros((4, 4), np.int16)
    padded[:, :3] = positions
    normals = np.zeros((4, 4), np.int8)
    normals[:, 2] = 127
    gltf, blob = _raw_gltf([(padded, "SCALAR", {}), (normals.view(np.uint8), "SCALAR", {}),
                            (TRI_FACES.ravel(), "SCALAR", {})])
    gltf["bufferViews"][0]["byteStride"] = 8
    gltf["bufferViews"][1]["byteStride"] = 4
    gltf["accessors"][0].update(componentType=5122, type="VEC3", count=4)
    gltf["accessors"][1].update(componentType=5120, normalized=True, type="VEC3", count=4)
    gltf["meshes"] = [{"primitives": [{"attributes": {"POSITION": 0, "NORMAL": 1}, "indices": 2}]}]
    gltf["nodes"] = [{"mesh": 0, "scale": [0.001, 0.001, 0.001]}]
    gltf["extensionsUsed"] = gltf["extensionsRequired"] = ["KHR_mesh_quantization"]
    scene = load_scene(_write(tmp_path / "q.gltf", gltf, blob))
    prim = scene.meshes[0].primitives[0]
    np.testing.assert_array_equal(prim.positions, positions)
    np.testing.assert_array_equal(prim.normals, np.tile([0.0, 0.0, 1.0], (4, 1)))
    np.testing.assert_allclose(scene.world_matrices()[0][:3, :3], 0.001 * np.eye(3))
