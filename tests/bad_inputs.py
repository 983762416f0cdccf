"""A corpus of broken asset files, written by code so the repository ships no binary junk.

`write_bad_inputs(folder)` writes every file and returns, per file name, a substring the loader's
error message must contain (compare case-insensitively). Used by the loader tests and by the
end-to-end batch tests.
"""

from __future__ import annotations

import base64
import json
import struct
from pathlib import Path

import numpy as np

TRIANGLE = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [1.0, 1.0, 0.0]])
TRIANGLE_FACES = np.array([[0, 1, 2], [1, 3, 2]])


def _obj(vertices: np.ndarray, faces_one_based: np.ndarray) -> str:
    v = "".join(f"v {x} {y} {z}\n" for x, y, z in vertices)
    return v + "".join("f " + " ".join(str(i) for i in f) + "\n" for f in faces_one_based)


def _binary_ply(vertices: np.ndarray, faces: np.ndarray, declared_vertices: int | None = None) -> bytes:
    header = (
        "ply\nformat binary_little_endian 1.0\n"
        f"element vertex {declared_vertices or len(vertices)}\nproperty float x\nproperty float y\nproperty float z\n"
        f"element face {len(faces)}\nproperty list uchar int vertex_indices\nend_header\n"
    ).encode()
    face_records = np.zeros(len(faces), dtype=[("n", "u1"), ("v", "<i4", 3)])
    face_records["n"], face_records["v"] = 3, faces
    return header + vertices.astype("<f4").tobytes() + face_records.tobytes()


def _binary_stl(vertices: np.ndarray, faces: np.ndarray) -> bytes:
    records = np.zeros(len(faces), dtype=[("normal", "<f4", 3), ("v", "<f4", (3, 3)), ("attr", "<u2")])
    records["v"] = vertices[faces]
    return b"\0" * 80 + struct.pack("<I", len(faces)) + records.tobytes()


def _gltf(positions: np.ndarray, indices: np.ndarray, *, position_type: str = "VEC3", buffer_uri: str | None = None,
          indices_accessor: int = 1, truncate_buffer: int = 0, signed_indices: bool = False, mode: int = 4) -> dict:
    """A one-mesh glTF with its buffer as a data URI (or `buffer_uri`); `truncate_buffer` bytes cut off its end."""
    pos = positions.astype("<f4").tobytes()
    idx = indices.astype("<i2" if signed_indices else "<u2").tobytes()
    blob = pos + idx + b"\0" * (-len(idx) % 4)
    width = {"VEC2": 2, "VEC3": 3}[position_type]
    data = blob[: len(blob) - truncate_buffer]
    return {
        "asset": {"version": "2.0"},
        "buffers": [{"byteLength": len(data),
                     "uri": buffer_uri or "data:application/octet-stream;base64," + base64.b64encode(data).decode()}],
        "bufferViews": [{"buffer": 0, "byteOffset": 0, "byteLength": len(pos)},
                        {"buffer": 0, "byteOffset": len(pos), "byteLength": len(idx)}],
        "accessors": [
            {"bufferView": 0, "componentType": 5126, "count": positions.size // width, "type": position_type},
            {"bufferView": 1, "componentType": 5122 if signed_indices else 5123, "count": indices.size, "type": "SCALAR"},
        ],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}, "indices": indices_accessor, "mode": mode}]}],
        "nodes": [{"mesh": 0}],
        "scenes": [{"nodes": [0]}],
        "scene": 0,
    }


def _glb(gltf: dict) -> bytes:
    text = json.dumps(gltf).encode()
    text += b" " * (-len(text) % 4)
    return struct.pack("<4sII", b"glTF", 2, 12 + 8 + len(text)) + struct.pack("<II", len(text), 0x4E4F534A) + text


def _set(doc: dict, *edits: tuple[str, object]) -> dict:
    """`doc` with each ``("accessors/0/componentType", value)`` edit applied (slash-separated keys and list indices)."""
    for pointer, value in edits:
        *parents, last = pointer.split("/")
        node = doc
        for key in parents:
            node = node[int(key) if isinstance(node, list) else key]
        node[int(last) if isinstance(node, list) else last] = value
    return doc


def _glb_plus(gltf: dict, *chunks: tuple[int, bytes]) -> bytes:
    """`_glb(gltf)` followed by `chunks` (chunk type, data), the header's total length updated."""
    data = _glb(gltf) + b"".join(struct.pack("<II", len(d), kind) + d for kind, d in chunks)
    return data[:8] + struct.pack("<I", len(data)) + data[12:]


def write_bad_inputs(folder: Path) -> dict[str, str]:
    """Write the broken files into `folder` (which must exist).

    Returns
    -------
    dict of str to str
        File name → substring expected in the `AssetError` message for that file. The zero-byte
        ``empty.usda`` is refused by the generic size check before any USD reader runs.
    """
    folder = Path(folder)
    nan_quad = TRIANGLE.copy()
    nan_quad[1, 0] = np.nan
    good_ply = _binary_ply(TRIANGLE, TRIANGLE_FACES)
    good_stl = _binary_stl(TRIANGLE, TRIANGLE_FACES)
    text_files = {
        "empty.obj": ("", "empty file"),
        "vertices_only.obj": (_obj(TRIANGLE, np.zeros((0, 3), int)), "no triangles"),
        "nan_vertex.obj": (_obj(nan_quad, TRIANGLE_FACES + 1), "non-finite vertex positions (1 of 4)"),
        "index_out_of_range.obj": (_obj(TRIANGLE, np.array([[1, 2, 57]])), "face index 57 out of range for 4 vertices"),
        "negative_index.obj": (_obj(TRIANGLE, np.array([[1, 2, -50]])), "face index -50 out of range"),
        "garbage.obj": ("this is not a mesh\n{\"json\": true}\n<xml/>\n", "no triangles"),
        "face_index_zero.obj": (_obj(TRIANGLE, np.array([[1, 2, 3], [0, 2, 3]])), "face index 0 on line 6: OBJ indices start at 1"),
        "mtllib_outside.obj": ("mtllib ../../../../../../etc/passwd\n" + _obj(TRIANGLE, TRIANGLE_FACES + 1),
                               "material library '../../../../../../etc/passwd' resolves to /etc/passwd, outside"),
        "missing_reference.usda": ('#usda 1.0\ndef "A" (\n    references = @./gone.usda@\n)\n{\n}\n',
                                   "reference './gone.usda' (from missing_reference.usda) not found"),
        "sublayer_outside.usda": ("#usda 1.0\n(\n    subLayers = [@/etc/passwd@]\n)\n",
                                  "sublayer '/etc/passwd' (from sublayer_outside.usda) resolves to /etc/passwd, outside"),
        "overstated_count.ply": (
            "ply\nformat ascii 1.0\nelement vertex 1200\nproperty float x\nproperty float y\nproperty float z\n"
            "element face 2\nproperty list uchar int vertex_indices\nend_header\n"
            "0 0 0\n1 0 0\n0 1 0\n1 1 0\n3 0 1 2\n3 1 3 2\n",
            "truncated file: header declares 1200",
        ),
        "index_out_of_range.ply": (
            "ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\nproperty float z\n"
            "element face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n1 1 0\n3 0 1 9\n",
            "face index 9 out of range for 4 vertices",
        ),
        "short_face.ply": (
            "ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\nproperty float z\n"
            "element face 2\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n1 1 0\n"
            "3 0 1 2\n2 1 3\n",
            "face 1 (line 15) has 2 vertices; a face needs at least 3",
        ),
        "nan_face_index.ply": (
            "ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\nproperty float z\n"
            "element face 2\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n1 1 0\n"
            "3 0 1 2\n3 1 nan 2\n",
            "face index 'nan' on face 1 (line 15) is not a whole number",
        ),
        "truncated_ascii.stl": ("solid t\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 1 0 0\n", "endsolid"),
        "invalid_json.gltf": ('{"asset": {"version": "2.0"}, "meshes": [', "invalid JSON"),
        "missing_buffer.gltf": (json.dumps(_gltf(TRIANGLE, TRIANGLE_FACES, buffer_uri="missing.bin")), "missing file 'missing.bin'"),
        "accessor_out_of_range.gltf": (json.dumps(_gltf(TRIANGLE, TRIANGLE_FACES, indices_accessor=7)), "accessor index 7 out of range"),
        "nan_position.gltf": (json.dumps(_gltf(nan_quad, TRIANGLE_FACES)), "non-finite vertex positions (1 of 4)"),
        "position_vec2.gltf": (json.dumps(_gltf(TRIANGLE[:, :2], TRIANGLE_FACES[:1], position_type="VEC2")), "expected VEC3"),
        "short_buffer.gltf": (json.dumps(_gltf(TRIANGLE, TRIANGLE_FACES, truncate_buffer=10)), "shorter than buffer view 1 needs"),
        "negative_index.gltf": (json.dumps(_gltf(TRIANGLE, -TRIANGLE_FACES - 1, signed_indices=True)),
                                "indices accessor 1 is SHORT; glTF 2.0 allows UNSIGNED_BYTE, UNSIGNED_SHORT or UNSIGNED_INT"),
        "points_only.gltf": (json.dumps(_gltf(TRIANGLE, TRIANGLE_FACES, mode=0)), "no triangles"),
        # glTF 2.0 rules (pipeline/mesh/load_gltf.py) and confinement of URIs (pipeline/mesh/confine.py)
        "version_1.gltf": (json.dumps(_set(_gltf(TRIANGLE, TRIANGLE_FACES), ("asset/version", "1.0"))),
                           "asset.version is '1.0'; only glTF 2.x is read"),
        "min_version_2_1.gltf": (json.dumps(_set(_gltf(TRIANGLE, TRIANGLE_FACES), ("asset/minVersion", "2.1"))),
                                 "asset.minVersion is '2.1'"),
        "no_asset_version.gltf": (json.dumps(_set(_gltf(TRIANGLE, TRIANGLE_FACES), ("asset", {}))), "no asset.version"),
        "requires_unknown_extension.gltf": (
            json.dumps(_set(_gltf(TRIANGLE, TRIANGLE_FACES), ("extensionsRequired", ["EXT_unheard_of"]))),
            "EXT_unheard_of is required and not supported"),
        "position_uint32.gltf": (json.dumps(_set(_gltf(TRIANGLE, TRIANGLE_FACES), ("accessors/0/componentType", 5125))),
                                 "POSITION accessor 0 is UNSIGNED_INT; glTF 2.0 allows FLOAT"),
        "position_normalized_float.gltf": (
            json.dumps(_set(_gltf(TRIANGLE, TRIANGLE_FACES), ("accessors/0/normalized", True))),
            "POSITION accessor 0 is normalized FLOAT"),
        "joints_vec3.gltf": (
            json.dumps(_set(_gltf(TRIANGLE, TRIANGLE_FACES), ("meshes/0/primitives/0/attributes/JOINTS_0", 0))),
            "JOINTS_0 accessor 0 has type VEC3, expected VEC4"),
        "stride_too_small.gltf": (json.dumps(_set(_gltf(TRIANGLE, TRIANGLE_FACES), ("bufferViews/0/byteStride", 4))),
                                  "byteStride 4 of buffer view 0 is smaller than the 12-byte VEC3 float element"),
        "stride_not_multiple_of_4.gltf": (
            json.dumps(_set(_gltf(TRIANGLE, TRIANGLE_FACES), ("bufferViews/0/byteStride", 14))),
            "buffer view 0 has byteStride 14; glTF 2.0 requires a multiple of 4 from 4 to 252"),
        "unaligned_accessor.gltf": (json.dumps(_set(_gltf(TRIANGLE, TRIANGLE_FACES), ("accessors/0/byteOffset", 2))),
                                    "not a multiple of its 4-byte component"),
        "restart_index.gltf": (json.dumps(_gltf(TRIANGLE, np.array([[0, 1, 65535]]))),
                               "holds 65535, the primitive-restart value of UNSIGNED_SHORT"),
        "index_past_vertices.gltf": (json.dumps(_gltf(TRIANGLE, np.array([[0, 1, 9]]))),
                                     "index 9 out of range for 4 vertices"),
        "huge_byte_length.gltf": (json.dumps(_set(_gltf(TRIANGLE, TRIANGLE_FACES), ("buffers/0/byteLength", 3 << 30))),
                                  "buffer 0 declares byteLength 3221225472, over the 2 GiB"),
        "parent_buffer_uri.gltf": (json.dumps(_gltf(TRIANGLE, TRIANGLE_FACES, buffer_uri="../secret.bin")),
                                   "buffer 0 URI '../secret.bin' resolves to"),
        "etc_passwd_image.gltf": (
            json.dumps(_set(_gltf(TRIANGLE, TRIANGLE_FACES), ("images", [{"uri": "../../etc/passwd"}]))),
            "image 0 URI '../../etc/passwd' resolves to"),
        "absolute_buffer_uri.gltf": (json.dumps(_gltf(TRIANGLE, TRIANGLE_FACES, buffer_uri="/etc/passwd")),
                                     "buffer 0 URI '/etc/passwd' resolves to /etc/passwd, outside the asset's folder"),
        "file_scheme_uri.gltf": (json.dumps(_gltf(TRIANGLE, TRIANGLE_FACES, buffer_uri="file:///etc/passwd")),
                                 "buffer 0 URI 'file:///etc/passwd' resolves to /etc/passwd"),
        "index_stride.gltf": (json.dumps(_set(_gltf(TRIANGLE, TRIANGLE_FACES), ("bufferViews/1/byteStride", 4))),
                              "indices accessor 1 uses buffer view 1, which has byteStride 4"),
        "required_not_used.gltf": (
            json.dumps(_set(_gltf(TRIANGLE, TRIANGLE_FACES), ("extensionsRequired", ["KHR_mesh_quantization"]))),
            "KHR_mesh_quantization is in extensionsRequired but not in extensionsUsed"),
        "zero_count.gltf": (json.dumps(_set(_gltf(TRIANGLE, TRIANGLE_FACES), ("accessors/0/count", 0))),
                            "POSITION (accessor 0) count is 0; glTF 2.0 requires a whole number >= 1"),
        "remote_uri.gltf": (json.dumps(_gltf(TRIANGLE, TRIANGLE_FACES, buffer_uri="https://example.com/a.bin")),
                            "URI 'https://example.com/a.bin' is not a file beside the asset"),
        "model.fbx": ("Kaydara FBX Binary", "unsupported file type '.fbx'"),
        "empty.usda": ("", "empty file"),
    }
    binary_files = {
        "truncated_binary.ply": (good_ply[:-20], "truncated file"),
        "truncated.stl": (good_stl[:-30], "truncated file: header declares 2 triangles"),
        "empty.stl": (b"", "empty file"),
        "nul_in_ascii.stl": (b"solid t\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 1 0\0 0\nvertex 0 1 0\n"
                             b"endloop\nendfacet\nendsolid t\n", "ASCII STL holds a NUL byte on line 5"),
        "undercounted.stl": (good_stl[:80] + struct.pack("<I", 1) + good_stl[84:],
                             "header declares 1 triangle (134 bytes) but the file holds 2 triangles"),
        "bad_magic.glb": (b"gLTF" + _glb(_gltf(TRIANGLE, TRIANGLE_FACES))[4:], "bad magic"),
        "truncated.glb": (_glb(_gltf(TRIANGLE, TRIANGLE_FACES))[:60], "truncated file: GLB header declares"),
        "bin_chunk_third.glb": (_glb_plus(_gltf(TRIANGLE, TRIANGLE_FACES), (0x4B4E554A, b"junk"), (0x004E4942, bytes(4))),
                                "chunk 2 is a BIN chunk"),
        "unaligned_chunk.glb": (_glb_plus(_gltf(TRIANGLE, TRIANGLE_FACES), (0x004E4942, bytes(3))),
                                "chunk 1 is 3 bytes long, not a multiple of 4"),
        "trailing_bytes.glb": (_glb(_gltf(TRIANGLE, TRIANGLE_FACES)) + bytes(8), "8 bytes after the last chunk"),
    }
    expected = {}
    for name, (text, needle) in text_files.items():
        (folder / name).write_text(text)
        expected[name] = needle
    for name, (data, needle) in binary_files.items():
        (folder / name).write_bytes(data)
        expected[name] = needle
    return expected


def deep_json_gltf(depth: int) -> str:
    """A glTF whose ``extras`` nest arrays until the JSON is `depth` levels deep (the root object is level 1)."""
    return '{"asset": {"version": "2.0"}, "extras": ' + "[" * (depth - 1) + "]" * (depth - 1) + "}"


def node_chain_gltf(translations: np.ndarray) -> dict:
    """The one-mesh glTF of `_gltf` with its mesh at the end of a chain of nodes: node i has node i + 1 as its
    only child and translation ``translations[i]``; the scene's root is node 0."""
    doc = _gltf(TRIANGLE, TRIANGLE_FACES)
    doc["nodes"] = [{"children": [i + 1], "translation": t.tolist()} for i, t in enumerate(translations[:-1])]
    doc["nodes"].append({"mesh": 0, "translation": translations[-1].tolist()})
    doc["scenes"] = [{"nodes": [0]}]
    return doc


def bad_node_graphs() -> dict[str, tuple[dict, str]]:
    """File name -> (glTF with a node graph glTF 2.0 forbids, the message's problem part)."""
    base = _gltf(TRIANGLE, TRIANGLE_FACES)
    graphs = {
        # the cycle 1 -> 2 -> 1 is no scene's: a scene-less file's roots are its parentless nodes
        "cycle_no_scene.gltf": ({"nodes": [{"mesh": 0}, {"children": [2]}, {"children": [1]}], "scenes": None,
                                 "scene": None},
                                "the node graph has a cycle through node 1 (2 nodes)"),
        "cycle_in_scene.gltf": ({"nodes": [{"mesh": 0, "children": [1]}, {"children": [2]}, {"children": [0]}],
                                 "scenes": [{"nodes": [0]}]}, "the node graph has a cycle through node 0 (3 nodes)"),
        "cycle_off_scene.gltf": ({"nodes": [{"mesh": 0}, {"children": [1], "mesh": 0}], "scenes": [{"nodes": [0]}]},
                                 "the node graph has a cycle through node 1 (1 node)"),
        "two_parents.gltf": ({"nodes": [{"children": [2]}, {"children": [2]}, {"mesh": 0}]},
                             "node 2 is the child of more than one node (nodes 0 and 1)"),
    }
    out = {}
    for name, (edits, problem) in graphs.items():
        doc = {**base, **edits}
        out[name] = ({k: v for k, v in doc.items() if v is not None}, problem)
    return out


def glb_truncations(data: bytes, steps: int = 48) -> dict[str, bytes]:
    """Cut-short copies of the GLB `data`: each byte length up to the first chunk's data, then `steps`
    lengths spread over the rest; each cut as it is (``cut_N``: the header still claims the whole file)
    and, cut to a multiple of 4 bytes, with the header's and the last chunk's length fields shrunk to
    what is left (``fixed_N``), so that the chunk, JSON and buffer checks behind the header's are
    reached too."""
    out = {}
    lengths = sorted(set(range(21)) | {round(k * len(data) / steps) for k in range(steps)})
    for n in lengths:
        out[f"cut_{n}"] = data[:n]
        n -= n % 4
        if n < 20:
            continue
        fixed, offset = bytearray(data[:n]), 12
        while offset + 8 <= n:  # walk the chunks: the one the cut falls in claims what is left of it
            size = struct.unpack_from("<I", fixed, offset)[0]
            if offset + 8 + size > n:
                struct.pack_into("<I", fixed, offset, n - offset - 8)
                break
            offset += 8 + size
        struct.pack_into("<I", fixed, 8, n)
        out[f"fixed_{n}"] = bytes(fixed)
    return out
