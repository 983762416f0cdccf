"""Small valid asset files and byte-level mutations of them, for the readers' fuzz test.

`seed_files()` writes each format the readers take from bytes (GLB, OBJ, binary and ASCII PLY and
STL) from one 42-vertex icosphere with normals and UVs, through the project's own glTF writer and
trimesh's exporters. `mutate(name, data, ops)` applies a list of mutation operations (drawn by
hypothesis in the test from `ops_for(name)`, or by a seeded `random.Random` in `random_ops`) to a
file's bytes.
"""

from __future__ import annotations

import json
import random
import re
import struct

import numpy as np
import trimesh

from sssbake.exporters.gltf import to_glb
from sssbake.pipeline.mesh.baked import BakedAsset
from sssbake.pipeline.mesh.scene import Mesh, Node, Primitive, Scene, SourceMaterial

#: Numbers that break readers which trust their input: overflow, NaN, signed zero, integer limits.
SPECIAL_NUMBERS = ("1e308", "-1e308", "3.5e38", "nan", "-nan", "inf", "-inf", "-0", "0", "4294967295",
                   "2147483648", "-1", "1e-320", "65535", "18446744073709551616", "0x10", "1.5")
#: Values a mutated JSON field is set to: wrong types, out-of-range integers, huge and non-finite numbers.
SPECIAL_JSON = (None, -1, 0, 1, 3, 65535, 4294967295, 2**53, 1e308, float("nan"), float("inf"), -0.0, 0.5,
                "", "x", "../x", True, [], {}, [0], {"x": 1})
#: Values a uint32 length, count or type field (GLB header and chunks, binary STL count) is set to.
SPECIAL_U32 = (0, 1, 3, 4, 7, 8, 12, 0x7FFFFFFF, 0x80000000, 0xFFFFFFFF, 0x4E4F534A, 0x004E4942)
#: Byte offsets of the GLB header's and the JSON chunk header's uint32 fields: version, length,
#: JSON chunk length and type (the BIN chunk header's follow the JSON chunk, found per file).
GLB_FIELDS = (4, 8, 12, 16)

#: Mutations of any file's bytes; `ops_for` adds the format-aware ones.
BYTE_OPS = ("flip", "fill", "truncate", "duplicate", "delete")


def _sphere() -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Positions (42, 3), faces (80, 3), unit normals (42, 3) and UVs (42, 2) of an icosphere of radius 10."""
    m = trimesh.creation.icosphere(subdivisions=1, radius=10.0)
    v = np.asarray(m.vertices, np.float64)
    n = v / np.linalg.norm(v, axis=1, keepdims=True)
    uv = np.column_stack([0.5 + np.arctan2(n[:, 1], n[:, 0]) / (2 * np.pi), np.arccos(np.clip(n[:, 2], -1, 1)) / np.pi])
    return v, np.asarray(m.faces, np.int64), n, uv


def seed_files() -> dict[str, bytes]:
    """File name → bytes of each valid seed: ``seed.glb`` (indexed, NORMAL and TEXCOORD_0),
    ``seed.obj`` (v/vt/vn/f), ``binary.ply``, ``ascii.ply`` (with normals), ``binary.stl``, ``ascii.stl``."""
    v, f, n, uv = _sphere()
    scene = Scene(source="seed.glb", meshes=(Mesh("sphere", (Primitive(v, f, normals=n, uvs=(uv,), material=0),)),),
                  nodes=(Node("sphere", np.eye(4), 0),), roots=(0,), materials=(SourceMaterial("wax"),),
                  meters_per_unit=1.0)
    glb, _ = to_glb(BakedAsset(scene))
    textured = trimesh.Trimesh(v, f, vertex_normals=n, visual=trimesh.visual.TextureVisuals(uv=uv), process=False)
    obj = trimesh.exchange.obj.export_obj(textured, include_normals=True, include_texture=True)
    # The exporter names a material library it would write beside the file; the seed is the OBJ alone.
    obj = "".join(line for line in obj.splitlines(keepends=True) if not line.startswith(("mtllib", "usemtl")))
    mesh = trimesh.Trimesh(v, f, vertex_normals=n, process=False)
    return {
        "seed.glb": glb,
        "seed.obj": obj.encode(),
        "binary.ply": trimesh.exchange.ply.export_ply(mesh, encoding="binary"),
        "ascii.ply": trimesh.exchange.ply.export_ply(mesh, encoding="ascii", vertex_normal=True),
        "binary.stl": trimesh.exchange.stl.export_stl(mesh),
        "ascii.stl": trimesh.exchange.stl.export_stl_ascii(mesh).encode(),
    }


def glb_chunks(data: bytes) -> tuple[bytes, bytes] | None:
    """The JSON chunk's bytes and the BIN chunk of a GLB whose chunk headers are intact, or None."""
    if len(data) < 20 or data[:4] != b"glTF":
        return None
    json_len = struct.unpack_from("<I", data, 12)[0]
    rest = data[20 + json_len :]
    return (data[20 : 20 + json_len], rest[8:]) if len(rest) >= 8 else None


def pack_glb(text: bytes, blob: bytes) -> bytes:
    """A GLB container of JSON `text` and `blob`, both padded to 4 bytes, lengths recomputed."""
    text += b" " * (-len(text) % 4)
    blob += b"\0" * (-len(blob) % 4)
    chunks = struct.pack("<II", len(text), 0x4E4F534A) + text + struct.pack("<II", len(blob), 0x004E4942) + blob
    return struct.pack("<4sII", b"glTF", 2, 12 + len(chunks)) + chunks


def _json_slots(value, path=()) -> list[tuple]:
    """Paths (tuples of keys and indices) to every value inside a JSON document, containers included."""
    out = [path] if path else []
    if isinstance(value, dict):
        for k, v in value.items():
            out += _json_slots(v, path + (k,))
    elif isinstance(value, list):
        for i, v in enumerate(value):
            out += _json_slots(v, path + (i,))
    return out


def _u32_fields(name: str, buf: bytes) -> tuple[int, ...]:
    """Byte offsets of a file's uint32 length, count and type fields (none for text formats)."""
    if name.endswith(".glb") and len(buf) >= 20:
        json_len = struct.unpack_from("<I", buf, 12)[0]
        bin_header = (20 + json_len, 24 + json_len) if 28 + json_len <= len(buf) else ()
        return GLB_FIELDS + bin_header
    if name.endswith(".stl") and not buf.startswith(b"solid") and len(buf) >= 84:
        return (80,)  # the triangle count
    return ()


def _splice_number(text: bytes, a: int, b: int) -> bytes:
    """`text` with its (a mod count)-th number replaced by ``SPECIAL_NUMBERS[b]``."""
    numbers = list(re.finditer(rb"-?\d+(?:\.\d+)?(?:e[-+]?\d+)?", text))
    if not numbers:
        return text
    m = numbers[a % len(numbers)]
    return text[: m.start()] + SPECIAL_NUMBERS[b % len(SPECIAL_NUMBERS)].encode() + text[m.end() :]


def ops_for(name: str) -> tuple[str, ...]:
    """The mutation kinds that change a file of this seed's format (`mutate`)."""
    if name.endswith(".glb"):
        return BYTE_OPS + ("number", "field", "json_value")
    return BYTE_OPS + (("field",) if name == "binary.stl" else ("number",))


def mutate(name: str, data: bytes, ops: list[tuple]) -> bytes:
    """Apply mutation operations in order; each is ``(kind, a, b, c)`` with free integers a, b, c.

    Kinds: ``flip`` bit b % 8 of byte a; ``fill`` b % 16 + 1 bytes at a with 0x00, 0xFF or
    random (c % 3); ``truncate`` at a; ``duplicate`` or ``delete`` the run of b % 64 + 1 bytes at a;
    ``number`` replaces the a-th number of the text (a GLB's JSON chunk, then repacked; a binary
    PLY's header) with ``SPECIAL_NUMBERS[b]``; ``field`` sets uint32 field a (GLB header, chunk
    lengths and types; a binary STL's triangle count) to ``SPECIAL_U32[b]``; ``json_value`` sets
    the a-th value of a GLB's JSON to ``SPECIAL_JSON[b]`` and repacks the container. Offsets and
    choices wrap around the data's size; an operation that does not apply leaves the data as it is.
    """
    buf = bytes(data)
    for kind, a, b, c in ops:
        size = len(buf)
        glb = glb_chunks(buf) if name.endswith(".glb") else None
        if kind in BYTE_OPS and size:
            at, run = a % size, b % 64 + 1
            if kind == "flip":
                buf = buf[:at] + bytes([buf[at] ^ 1 << (b % 8)]) + buf[at + 1 :]
            elif kind == "fill":
                run = b % 16 + 1
                fill = {0: b"\0" * run, 1: b"\xff" * run}.get(c % 3) or random.Random(c).randbytes(run)
                buf = buf[:at] + fill[: size - at] + buf[at + run :]
            elif kind == "truncate":
                buf = buf[:at]
            elif kind == "duplicate":
                buf = buf[: at + run] + buf[at:]
            else:
                buf = buf[:at] + buf[at + run :]
        elif kind == "number" and name.endswith(".glb"):
            if glb is not None:
                buf = pack_glb(_splice_number(glb[0], a, b), glb[1])
        elif kind == "number":
            header_end = buf.find(b"end_header") if buf.startswith(b"ply") else -1
            cut = header_end if header_end >= 0 and b"format ascii" not in buf[:header_end] else size
            buf = _splice_number(buf[:cut], a, b) + buf[cut:]
        elif kind == "field" and _u32_fields(name, buf):
            fields = _u32_fields(name, buf)
            at = fields[a % len(fields)]
            buf = buf[:at] + struct.pack("<I", SPECIAL_U32[b % len(SPECIAL_U32)]) + buf[at + 4 :]
        elif kind == "json_value" and glb is not None:
            try:
                gltf = json.loads(glb[0])
            except (ValueError, UnicodeDecodeError):
                continue
            slots = _json_slots(gltf)
            if slots:
                slot = slots[a % len(slots)]
                parent = gltf
                for key in slot[:-1]:
                    parent = parent[key]
                parent[slot[-1]] = SPECIAL_JSON[b % len(SPECIAL_JSON)]
                # json.dumps writes NaN and Infinity as bare tokens: invalid JSON that Python's parser accepts.
                buf = pack_glb(json.dumps(gltf).encode(), glb[1])
    return buf


def random_ops(rng: random.Random, name: str, count: int) -> list[tuple]:
    """`count` mutation operations for seed `name` drawn from `rng` (for fixed-seed end-to-end mutants)."""
    kinds = ops_for(name)
    return [(rng.choice(kinds), rng.randrange(2**20), rng.randrange(2**10), rng.randrange(2**10)) for _ in range(count)]
