"""Loader strictness (issue 19, second round): PLY face lists, ASCII STL with a NUL byte, glTF
byteStride on index data, extensionsRequired ⊆ extensionsUsed, accessor count, morph-target kinds,
texture decompression bombs; each refused with its exact one-line message."""

import struct
import zlib
from pathlib import Path

import numpy as np
import pytest
from bad_inputs import TRIANGLE, TRIANGLE_FACES, _binary_ply
from test_load_gltf_hostile import _load_error, _quad
from test_load_confinement_usd_obj import obj_with, png

from sssbake.pipeline.core.errors import AssetError
from sssbake.pipeline.mesh.load import load_scene

PLY_HEAD = ("ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\nproperty float z\n"
            "element face 2\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n1 1 0\n")


def message(path: Path) -> str:
    with pytest.raises(AssetError) as info:
        load_scene(path)
    text = str(info.value)
    assert text.startswith(f"{path}: ") and "\n" not in text, text
    return text[len(f"{path}: "):]


@pytest.mark.parametrize("faces, problem", [
    ("3 0 1 2\n2 1 3\n", "face 1 (line 15) has 2 vertices; a face needs at least 3"),
    ("0\n3 0 1 2\n", "face 0 (line 14) has 0 vertices; a face needs at least 3"),
    ("3 0 1 2\n1 3\n", "face 1 (line 15) has 1 vertices; a face needs at least 3"),
    ("3 0 1 2\n3 1 nan 2\n", "face index 'nan' on face 1 (line 15) is not a whole number"),
    ("3 0 1 2\n3 1 3 1.5\n", "face index '1.5' on face 1 (line 15) is not a whole number"),
    ("3 0 1 2\n3 1 1e30 2\n", "face index '1e30' on face 1 (line 15) does not fit the face list's int type"),
    ("3 0 1 2\n2.5 1 3 2\n", "vertex count '2.5' on face 1 (line 15) is not a whole number"),
])
def test_ascii_ply_face_lists(tmp_path, faces, problem):
    path = tmp_path / "f.ply"
    path.write_text(PLY_HEAD + faces)
    assert message(path) == problem


def test_ascii_ply_mixed_polygons_and_truncation_still_read(tmp_path):
    path = tmp_path / "quad.ply"
    path.write_text(PLY_HEAD.replace("face 2", "face 1") + "4 0 1 3 2\n")
    assert len(load_scene(path).meshes[0].primitives[0].faces) == 2
    path.write_text(PLY_HEAD + "3 0 1 2\n3 1 3\n")  # the last line cut short: truncation, not a short face
    assert message(path).startswith("truncated file: header declares 4 'vertex', 2 'face' elements")


def binary_faces(*faces: tuple[int, ...]) -> bytes:
    head = _binary_ply(TRIANGLE, TRIANGLE_FACES)
    head = head[: head.index(b"end_header") + 11].replace(b"element face 2", f"element face {len(faces)}".encode())
    body = b"".join(bytes([len(f)]) + np.array(f, "<i4").tobytes() for f in faces)
    return head + TRIANGLE.astype("<f4").tobytes() + body


@pytest.mark.parametrize("faces, problem", [
    (((0, 1, 2), (1, 3)), "face 1 has 2 vertices; a face needs at least 3"),
    (((), (0, 1, 2)), "face 0 has 0 vertices; a face needs at least 3"),
    (((0, 1, 2), (1, 3, 2), (0, 1, 3, 2)),
     "face 2 has 4 vertices and face 0 has 3: a binary PLY's faces must all have one vertex count here (triangulate it)"),
])
def test_binary_ply_face_lists(tmp_path, faces, problem):
    path = tmp_path / "b.ply"
    path.write_bytes(binary_faces(*faces))
    assert message(path) == problem


def test_binary_ply_float_face_index(tmp_path):
    path = tmp_path / "f.ply"
    data = _binary_ply(TRIANGLE, TRIANGLE_FACES).replace(b"list uchar int", b"list uchar float")
    cut = data.index(b"end_header") + 11 + TRIANGLE.size * 4
    records = np.zeros(2, dtype=[("n", "u1"), ("v", "<f4", 3)])
    records["n"], records["v"] = 3, [[0, 1, 2], [1, np.nan, 2]]
    path.write_bytes(data[:cut] + records.tobytes())
    assert message(path) == "face index nan on face 1 is not a whole number"
    records["v"][1, 1] = 3
    path.write_bytes(data[:cut] + records.tobytes())
    np.testing.assert_array_equal(load_scene(path).meshes[0].primitives[0].faces, TRIANGLE_FACES)


def test_ascii_stl_with_a_nul_byte_is_text_not_binary(tmp_path):
    path = tmp_path / "nul.stl"
    path.write_bytes(b"solid t\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 1 0\0 0\nvertex 0 1 0\n"
                     b"endloop\nendfacet\nendsolid t\n")
    assert message(path) == "ASCII STL holds a NUL byte on line 5: the text is damaged; re-export the file"
    path.write_bytes(path.read_bytes().replace(b"\0", b" "))
    assert len(load_scene(path).meshes[0].primitives[0].faces) == 1


def _morph(component: int, kind: str = "VEC3", normalized: bool = False, count: int = 4, *extensions) -> dict:
    doc = _quad(("meshes/0/primitives/0/targets", [{"POSITION": 2}]))
    doc["accessors"].append({"bufferView": 0, "componentType": component, "count": count, "type": kind,
                             "normalized": normalized})
    if extensions:
        doc["extensionsUsed"] = list(extensions)
    return doc


@pytest.mark.parametrize("doc, problem", [
    (_quad(("bufferViews/1/byteStride", 4)),
     "mesh 0 primitive 0: indices accessor 1 uses buffer view 1, which has byteStride 4; glTF 2.0 allows byteStride "
     "only on vertex attribute data"),
    (_quad(("extensionsRequired", ["KHR_mesh_quantization"])),
     "KHR_mesh_quantization is in extensionsRequired but not in extensionsUsed; glTF 2.0 lists every required "
     "extension as used too"),
    (_quad(("accessors/0/count", 0)),
     "mesh 0 primitive 0 POSITION (accessor 0) count is 0; glTF 2.0 requires a whole number >= 1"),
    (_morph(5125), "mesh 0 primitive 0 target 0: POSITION accessor 2 is UNSIGNED_INT; glTF 2.0 allows FLOAT "
                   "(KHR_mesh_quantization allows more)"),
    (_morph(5126, "VEC4"), "mesh 0 primitive 0 target 0: POSITION accessor 2 has type VEC4, expected VEC3"),
    (_morph(5121, "VEC3", False, 4, "KHR_mesh_quantization"),
     "mesh 0 primitive 0 target 0: POSITION accessor 2 is UNSIGNED_BYTE; glTF 2.0 allows FLOAT, BYTE, "
     "normalized BYTE, SHORT, normalized SHORT"),
    (_morph(5126, "VEC3", False, 3), "mesh 0 primitive 0 target 0: POSITION accessor 2 has count 3 but POSITION has 4"),
])
def test_gltf_index_strides_extensions_counts_and_morph_targets(tmp_path, doc, problem):
    assert _load_error(tmp_path, doc) == problem


def test_gltf_sparse_views_refuse_a_stride(tmp_path):
    doc = _quad()
    doc["bufferViews"].append({"buffer": 0, "byteOffset": 48, "byteLength": 4, "byteStride": 4})
    doc["accessors"][0]["sparse"] = {"count": 1, "indices": {"bufferView": 2, "componentType": 5121},
                                     "values": {"bufferView": 0}}
    assert _load_error(tmp_path, doc) == ("mesh 0 primitive 0 POSITION (accessor 0): sparse indices uses buffer view 2, "
                                          "which has byteStride 4; glTF 2.0 allows byteStride only on vertex attribute "
                                          "data")


def test_gltf_valid_morph_targets_load(tmp_path):
    path = tmp_path / "m.gltf"
    for doc in (_morph(5126), _morph(5122, "VEC3", True, 4, "KHR_mesh_quantization")):
        path.write_text(__import__("json").dumps(doc))
        assert load_scene(path).meshes[0].deforming


def bomb_png(width: int, height: int) -> bytes:
    """A PNG header declaring width × height pixels and a token IDAT: never decoded."""
    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))
    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0))
            + chunk(b"IDAT", zlib.compress(b"\0" * 64)) + chunk(b"IEND", b""))


def test_texture_decompression_bombs_are_refused_before_decoding(tmp_path):
    (tmp_path / "skin.png").write_bytes(bomb_png(100_000, 100_000))
    asset = obj_with(tmp_path, "newmtl skin\nmap_Kd skin.png\n")
    assert message(asset) == ("texture 'skin.png' is over the 89 M pixel limit of PIL.Image.MAX_IMAGE_PIXELS (Image "
                              "size (10000000000 pixels) exceeds limit of 178956970 pixels, could be decompression "
                              "bomb DOS attack.)")
    (tmp_path / "skin.png").write_bytes(bomb_png(10_000, 10_000))
    assert message(asset) == "texture 'skin.png' is 10000 × 10000 pixels, over the 89 M pixel limit of " \
                             "PIL.Image.MAX_IMAGE_PIXELS"
    png(tmp_path / "skin.png", 90)
    scene = load_scene(asset)
    assert len(scene.images) == 1
