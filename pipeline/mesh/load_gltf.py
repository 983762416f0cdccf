"""glTF 2.0 (.gltf with external or data-URI buffers, and .glb).

The GLB container, the JSON, buffers and accessors are decoded here, not by pygltflib, so that every
inconsistency (short chunk, buffer shorter than a view needs, index out of range) becomes an
`AssetError` that says which one, and so that reading stays linear: pygltflib's dataclasses_json
decoding takes seconds per thousand nodes. `read_gltf_file` is the one reader of the container and
the JSON for every command (bake, inspect, verify, view); its objects (`GltfObject`) read their
properties as attributes, as pygltflib's do.

Extensions: KHR_draco_mesh_compression is decoded with DracoPy (an uncompressed fallback, when the
extension is only used, is read as it is); EXT_mesh_gpu_instancing becomes one child node per
instance; KHR_texture_transform is kept on the `TextureRef`; EXT_meshopt_compression is read
through its uncompressed fallback. A file that requires any extension not in `SUPPORTED_REQUIRED`
is refused, naming it (and, for compression, the command that removes it).

Downloaded files are hostile input: every external buffer and image goes through the asset's
`Confinement` before a byte is read, a buffer is read up to its declared ``byteLength`` only, and the
glTF 2.0 rules a broken or malicious file breaks (asset version, JSON shapes, accessor types per
attribute semantic, strides, alignment, sparse and index ranges, GLB chunk layout, a node graph of
disjoint trees) are refused in one line.
"""

from __future__ import annotations

import base64
import binascii
import json
import os
import re
import struct
from dataclasses import dataclass, replace
from pathlib import Path
from urllib.parse import unquote, unquote_to_bytes, urlsplit

import numpy as np

from sssbake.pipeline.core.errors import AssetError
from sssbake.pipeline.mesh.confine import Confinement
from sssbake.pipeline.mesh.digest import bytes_digest, file_digest
from sssbake.pipeline.mesh.scene import (
    TEXTURE_TRANSFORM,
    Image,
    Mesh,
    Node,
    Primitive,
    Scene,
    SourceMaterial,
    Texture,
    TextureRef,
    TextureTransform,
)

COMPONENT_DTYPES = {5120: "<i1", 5121: "<u1", 5122: "<i2", 5123: "<u2", 5125: "<u4", 5126: "<f4"}
COMPONENT_NAMES = {5120: "BYTE", 5121: "UNSIGNED_BYTE", 5122: "SHORT", 5123: "UNSIGNED_SHORT", 5125: "UNSIGNED_INT",
                   5126: "FLOAT"}
TYPE_SIZES = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT2": 4, "MAT3": 9, "MAT4": 16}
MODE_NAMES = {0: "POINTS", 1: "LINES", 2: "LINE_LOOP", 3: "LINE_STRIP", 4: "TRIANGLES", 5: "TRIANGLE_STRIP", 6: "TRIANGLE_FAN"}
GLB_JSON_CHUNK = 0x4E4F534A
GLB_BIN_CHUNK = 0x004E4942
DRACO = "KHR_draco_mesh_compression"
INSTANCING = "EXT_mesh_gpu_instancing"
#: Required extensions this reader implements: Draco (decoded with DracoPy), texture transforms (kept),
#: GPU instancing (one node per instance), quantized attributes (any component type is read) and the
#: material extensions it reads. A file requiring any other is refused: it cannot be read right without.
SUPPORTED_REQUIRED = frozenset({DRACO, TEXTURE_TRANSFORM, INSTANCING, "KHR_mesh_quantization", "KHR_materials_ior",
                                "KHR_materials_volume", "KHR_materials_diffuse_transmission",
                                "KHR_materials_volume_scatter"})
#: How to turn a file that requires an unsupported compression into one sssbake reads.
DECOMPRESS = {
    "EXT_meshopt_compression": "gltfpack -i in.glb -o out.glb -noq",
    "KHR_meshopt_compression": "gltfpack -i in.glb -o out.glb -noq",
    DRACO: "gltf-transform copy in.glb out.glb",
}
CORE_IMAGE_TYPES = ("image/png", "image/jpeg")
#: Largest buffer read (declared byteLength): engines address buffers with 32-bit offsets, and a
#: bit-flipped byteLength must not make the reader allocate or read gigabytes.
MAX_BUFFER_BYTES = 2 << 30
#: Largest encoded image read: a 16k x 16k PNG is far below it; a 1 GB "texture" is an attack or an accident.
MAX_IMAGE_BYTES = 512 << 20
QUANTIZATION = "KHR_mesh_quantization"
#: glTF 2.0 "Meshes": per attribute semantic (indexed ones without ``_n``), the accessor types and the
#: (componentType, normalized) pairs the spec allows. EXT_mesh_gpu_instancing's attributes as its spec says.
_FLOAT = frozenset({(5126, False)})
_UNORM = frozenset({(5121, True), (5123, True)})
_SNORM = frozenset({(5120, True), (5122, True)})
_INTEGERS = frozenset((c, n) for c in (5120, 5121, 5122, 5123) for n in (False, True))
SEMANTICS = {
    "POSITION": (("VEC3",), _FLOAT), "NORMAL": (("VEC3",), _FLOAT), "TANGENT": (("VEC4",), _FLOAT),
    "TEXCOORD": (("VEC2",), _FLOAT | _UNORM), "COLOR": (("VEC3", "VEC4"), _FLOAT | _UNORM),
    "JOINTS": (("VEC4",), frozenset({(5121, False), (5123, False)})), "WEIGHTS": (("VEC4",), _FLOAT | _UNORM),
    "TRANSLATION": (("VEC3",), _FLOAT), "ROTATION": (("VEC4",), _FLOAT | _SNORM), "SCALE": (("VEC3",), _FLOAT),
}
#: What KHR_mesh_quantization adds to `SEMANTICS` (its "Extending Mesh Attributes" table; instancing's
#: TRANSLATION and SCALE are allowed as widely as POSITION, a superset of what EXT_mesh_gpu_instancing lists).
QUANTIZED = {
    "POSITION": _INTEGERS, "NORMAL": _SNORM, "TANGENT": _SNORM, "TRANSLATION": _INTEGERS, "SCALE": _INTEGERS,
    "TEXCOORD": frozenset({(5120, False), (5120, True), (5121, False), (5122, False), (5122, True), (5123, False)}),
}
#: glTF 2.0 "Morph Targets": the position, normal and tangent displacements' types, and what
#: KHR_mesh_quantization's "Extending Morph Target Attributes" adds.
TARGET_SEMANTICS = {name: (("VEC3",), _FLOAT) for name in ("POSITION", "NORMAL", "TANGENT")}
TARGET_QUANTIZED = {"POSITION": _SNORM | {(5120, False), (5122, False)}, "NORMAL": _SNORM, "TANGENT": _SNORM}
INDEX_COMPONENTS = (5121, 5123, 5125)
VERSION = re.compile(r"(\d+)\.(\d+)")
IMAGE_SIGNATURES = ((b"\x89PNG", "image/png"), (b"\xff\xd8", "image/jpeg"), (b"RIFF", "image/webp"), (b"\xabKTX", "image/ktx2"))
#: Deepest JSON nesting read (the root object is level 1). glTF itself nests about 8 deep; extras and
#: extension objects may nest more, and Python code that walks JSON (the json module's own parser and
#: encoder among it) recurses once per level, under a limit of 1000 frames.
MAX_JSON_DEPTH = 256
_SCALARS = frozenset({str, int, float, bool})
#: The JSON shape glTF 2.0 gives each property the readers walk, by kind of object: an object of a kind
#: (``"sparse"``), an array of objects of a kind (``["node"]``), an array of strings (``[str]``) or an
#: array of anything (``[]``). ``extensions`` is an object in every object; kinds not listed here have
#: no other property to check (``"object"``).
SHAPES = {
    "glTF": {"asset": "object", "extensionsUsed": [str], "extensionsRequired": [str], "accessors": ["accessor"],
             "animations": ["object"], "buffers": ["object"], "bufferViews": ["object"], "cameras": ["object"],
             "images": ["object"], "materials": ["material"], "meshes": ["mesh"], "nodes": ["node"],
             "samplers": ["object"], "scenes": ["scene"], "skins": ["object"], "textures": ["object"]},
    "accessor": {"sparse": "sparse", "min": [], "max": []},
    "sparse": {"indices": "object", "values": "object"},
    "material": {"pbrMetallicRoughness": "pbr", "normalTexture": "object", "occlusionTexture": "object",
                 "emissiveTexture": "object", "emissiveFactor": []},
    "pbr": {"baseColorTexture": "object", "metallicRoughnessTexture": "object", "baseColorFactor": []},
    "mesh": {"primitives": ["primitive"], "weights": []},
    "primitive": {"attributes": "object", "targets": ["object"]},
    "node": {"children": [], "matrix": [], "translation": [], "rotation": [], "scale": [], "weights": []},
    "scene": {"nodes": []},
}
#: How messages name an element of an array property (``mesh 0 primitive 1``).
_ELEMENT_NAMES = {"accessors": "accessor", "animations": "animation", "buffers": "buffer", "bufferViews": "buffer view",
                  "cameras": "camera", "images": "image", "materials": "material", "meshes": "mesh", "nodes": "node",
                  "samplers": "sampler", "scenes": "scene", "skins": "skin", "textures": "texture",
                  "primitives": "primitive", "targets": "morph target"}


class GltfObject(dict):
    """A glTF JSON object whose properties also read (None when absent) and write as attributes
    (``node.mesh``): the access pygltflib's object model gives, without its per-object decoding."""

    __slots__ = ()

    def __getattr__(self, name: str):
        if name.startswith("__"):  # protocols (copy, pickle) probe dunder names: those are not properties
            raise AttributeError(name)
        return self.get(name)

    def __setattr__(self, name: str, value) -> None:
        self[name] = value


class _Sparse(GltfObject):
    """An accessor's ``sparse`` object: its ``values`` property reads as an attribute too, where a
    dict's ``values`` method would be found first."""

    __slots__ = ()

    @property
    def values(self):
        return self.get("values")


@dataclass(frozen=True)
class GltfFile:
    """A glTF file's JSON and GLB binary chunk, as `read_gltf_file` checked them.

    Attributes
    ----------
    gltf : GltfObject
        The root object; each array of objects `SHAPES` names is present (``[]`` when the file has none).
    blob : memoryview or None
        The GLB BIN chunk (None: a .gltf, or a GLB without one).
    warnings : tuple of str
        GLB chunks of unknown type, skipped as the spec requires.
    """

    gltf: GltfObject
    blob: memoryview | None
    warnings: tuple[str, ...]


@dataclass(frozen=True)
class _Document:
    """A parsed glTF file and its decoded buffers."""

    path: str
    gltf: GltfObject
    buffers: tuple[bytes | memoryview, ...]
    confinement: Confinement
    quantized: bool  # KHR_mesh_quantization is used: integer attribute types are allowed
    read: list[tuple[str, str]]  # the external files read so far and their digests (`Scene.dependencies`)


def load_gltf(path: str, confinement: Confinement | None = None) -> Scene:
    """Read a .gltf or .glb file.

    Parameters
    ----------
    path : str
        External buffers and images are resolved relative to its folder.
    confinement : Confinement or None
        Where external files may lie (default: the asset's folder only).

    Returns
    -------
    Scene
        Every mesh (TRIANGLES primitives; strips and fans converted to lists, points and lines
        skipped), the node hierarchy of the default scene, materials, textures and images (bytes
        as stored). ``meters_per_unit`` is 1 (the glTF spec), up axis ``"Y"``; ``warnings``
        names GLB chunks of unknown type (ignored, as the spec requires).

    Raises
    ------
    AssetError
        Bad GLB header or chunk layout, invalid JSON, an asset version other than 2.x, missing or
        short buffers, a buffer or image URI outside the allowed folders or over its size bound,
        indices out of range or equal to the primitive-restart value, accessors whose type,
        componentType, stride or offset glTF 2.0 does not allow, no triangles, a required extension
        sssbake does not support, Draco data that does not decode, a texture whose only image needs
        an extension.
    """
    confinement = confinement or Confinement.for_asset(path)
    file = read_gltf_file(path)
    gltf = file.gltf
    # Before the buffers: a file requiring meshopt has placeholder buffers with no data.
    for extension in gltf.extensionsRequired or ():
        if extension not in SUPPORTED_REQUIRED:
            raise AssetError(path, _unsupported(extension))
        if extension not in (gltf.extensionsUsed or ()):
            raise AssetError(path, f"{extension} is in extensionsRequired but not in extensionsUsed; glTF 2.0 lists "
                                   "every required extension as used too")
    quantized = QUANTIZATION in (gltf.extensionsUsed or []) + (gltf.extensionsRequired or [])
    files: list[tuple[str, str]] = []
    doc = _Document(path, gltf, load_buffers(path, gltf, file.blob, confinement, files), confinement, quantized, files)
    meshes, skipped = [], []
    skinned = {node.mesh for node in gltf.nodes if node.mesh is not None and node.skin is not None}
    for i, mesh in enumerate(gltf.meshes):
        prims = []
        for j, prim in enumerate(mesh.primitives):
            read = _primitive(doc, prim, f"mesh {i} primitive {j}")
            if read is None:
                skipped.append(MODE_NAMES.get(prim.mode, str(prim.mode)))
            else:
                prims.append(read)
        morphed = any(prim.targets for prim in mesh.primitives)
        meshes.append(Mesh(mesh.name or f"mesh_{i}", tuple(prims), deforming=i in skinned or morphed))
    if not any(len(p.faces) for m in meshes for p in m.primitives):
        if skipped:
            raise AssetError(path, f"no triangles: only {', '.join(sorted(set(skipped)))} primitives ({len(skipped)} skipped)")
        raise AssetError(path, "no triangles: the file has no mesh geometry")
    nodes = _nodes(doc)
    textures, images = _textures_and_images(doc)
    return Scene(
        source=path,
        meshes=tuple(meshes),
        nodes=nodes,
        roots=_roots(doc, nodes),
        materials=tuple(_material(doc, m, i) for i, m in enumerate(gltf.materials)),
        textures=textures,
        images=images,
        up_axis="Y",
        meters_per_unit=1.0,
        warnings=file.warnings,
        dependencies=tuple(dict.fromkeys(files)),
    )


def _unsupported(extension: str, detail: str = "") -> str:
    """The one-line refusal of a required `extension`, with the command that removes it when there is one."""
    fix = DECOMPRESS.get(extension)
    return f"{extension} is required and not supported{detail}" + (f"; decompress it first ({fix})" if fix else "")


def read_gltf_file(path: str | os.PathLike) -> GltfFile:
    """A .gltf or .glb file's JSON and GLB binary chunk, checked; the one reader of glTF files for
    every command (`load_gltf`; inspect, verify and view through `gltf_tables.load_sssbake_gltf`).

    Every GLB length field (the header's, each chunk's) is checked against the bytes the file really
    holds before it is trusted (`_split_glb`), and the JSON as `_parse_json` says.

    Raises
    ------
    AssetError
        The file cannot be read, or any of those checks fails.
    """
    path = os.fspath(path)
    try:
        data = Path(path).read_bytes()
    except OSError as e:
        raise AssetError(path, f"cannot read file: {e.strerror or e}") from None
    warnings: list[str] = []
    if Path(path).suffix.lower() == ".glb" or data[:4] == b"glTF":
        text, blob = _split_glb(path, data, warnings)
    else:
        text, blob = _decode_text(path, data), None
    return GltfFile(_parse_json(path, text), blob, tuple(warnings))


def _split_glb(path: str, data: bytes, warnings: list[str]) -> tuple[str, memoryview | None]:
    """JSON text and BIN chunk of a GLB container (glTF 2.0 "GLB File Format Specification").

    The JSON chunk comes first, the BIN chunk (if any) second; every chunk is 4-byte aligned and
    inside the file, whose length the header states exactly. Chunks of unknown type after those
    are skipped, as the spec requires, with a line in `warnings`.
    """
    if len(data) < 12:
        raise AssetError(path, f"truncated file: {len(data)} bytes, shorter than the 12-byte GLB header")
    magic, version, length = struct.unpack_from("<4sII", data)
    if magic != b"glTF":
        raise AssetError(path, f"not a GLB file: bad magic {magic!r} (expected b'glTF')")
    if version != 2:
        raise AssetError(path, f"unsupported GLB version {version} (only 2 is supported)")
    if length > len(data):
        raise AssetError(path, f"truncated file: GLB header declares {length} bytes, the file has {len(data)}")
    if length < len(data):
        raise AssetError(path, f"corrupt GLB: header declares {length} bytes, the file has {len(data)} "
                               f"({len(data) - length} bytes after the last chunk)")
    view = memoryview(data)
    text, blob = None, None
    offset, n = 12, 0
    while offset < length:
        if offset + 8 > length:
            raise AssetError(path, f"corrupt GLB: {length - offset} stray bytes after chunk {n - 1}, too few for a chunk header")
        size, kind = struct.unpack_from("<II", data, offset)
        if offset + 8 + size > length:
            raise AssetError(path, f"truncated file: GLB chunk {n} declares {size} bytes, only {length - offset - 8} remain")
        if size % 4:
            raise AssetError(path, f"corrupt GLB: chunk {n} is {size} bytes long, not a multiple of 4 as chunks must be")
        chunk = view[offset + 8 : offset + 8 + size]
        if n == 0 and kind != GLB_JSON_CHUNK:
            raise AssetError(path, f"corrupt GLB: the first chunk is not JSON (type 0x{kind:08X})")
        if n == 0:
            text = _decode_text(path, bytes(chunk))
        elif kind == GLB_BIN_CHUNK and n == 1:
            blob = chunk
        elif kind in (GLB_JSON_CHUNK, GLB_BIN_CHUNK):
            raise AssetError(path, f"corrupt GLB: chunk {n} is a {'JSON' if kind == GLB_JSON_CHUNK else 'BIN'} chunk; "
                                   "only one JSON chunk, then at most one BIN chunk, may lead the file")
        else:
            warnings.append(f"GLB chunk {n} has unknown type 0x{kind:08X} ({size} bytes); ignored, as glTF 2.0 requires")
        offset += 8 + size
        n += 1
    if text is None:
        raise AssetError(path, "corrupt GLB: no chunks after the header (the JSON chunk is missing)")
    return text, blob


def _decode_text(path: str, data: bytes) -> str:
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError as e:
        raise AssetError(path, f"invalid JSON: not UTF-8 text (byte {e.start})") from None


def _parse_json(path: str, text: str) -> GltfObject:
    """The root object of glTF JSON `text`, checked: nesting (`MAX_JSON_DEPTH`), nulls, the asset
    version and the shape of every property the readers walk (`SHAPES`)."""
    try:
        raw = json.loads(text, object_pairs_hook=GltfObject)
    except RecursionError:  # the parser recurses per level: past ~1000 levels it stops here
        raise AssetError(path, f"JSON nested deeper than {MAX_JSON_DEPTH} levels") from None
    except json.JSONDecodeError as e:
        raise AssetError(path, f"invalid JSON: {e.msg} at line {e.lineno} column {e.colno}") from None
    except ValueError as e:  # an integer of more digits than Python converts
        raise AssetError(path, f"invalid JSON: {e}") from None
    if not isinstance(raw, dict):
        raise AssetError(path, f"invalid glTF: the top-level JSON value is a {type(raw).__name__}, not an object")
    _check_tree(path, raw)
    _check_version(path, raw.get("asset"))
    _check_shape(path, raw, "glTF", "")
    return raw


def _check_tree(path: str, raw: dict) -> None:
    """Refuse JSON nested deeper than `MAX_JSON_DEPTH`, or holding a null outside ``extras`` (glTF 2.0
    allows it nowhere else, and every lookup would trip on it).

    A stack, not recursion: the walk must not overflow on the nesting it is there to refuse. Where a
    null lies (``meshes[0].primitives[1]``) is spelled out only when one is found."""
    stack = [(raw, 1, (), False)]  # (value, its level, keys to it, inside extras)
    while stack:
        value, depth, keys, extras = stack.pop()
        if depth > MAX_JSON_DEPTH:
            raise AssetError(path, f"JSON nested deeper than {MAX_JSON_DEPTH} levels")
        if isinstance(value, list) and set(map(type, value)) <= _SCALARS:
            continue  # numbers or strings: the common array, checked at C speed
        for key, item in value.items() if isinstance(value, dict) else enumerate(value):
            if item is None and not extras:
                where = "".join(f".{k}" if isinstance(k, str) else f"[{k}]" for k in (*keys, key)).lstrip(".")
                raise AssetError(path, f"invalid glTF: {where} is null (glTF 2.0 allows null nowhere outside extras)")
            if isinstance(item, (dict, list)):
                stack.append((item, depth + 1, (*keys, key), extras or key == "extras"))


def _check_shape(path: str, obj: GltfObject, kind: str, where: str) -> None:
    """Refuse a property of `obj` (an object of `kind`, named `where` in messages: ``"mesh 0"``)
    whose JSON type is not the one `SHAPES` gives it, and set each absent array of objects to ``[]``.
    Recurses through `SHAPES` only: as deep as that table, whatever the file's nesting."""
    at = f"{where}: " if where else ""
    extensions = obj.get("extensions")
    if extensions is not None and not isinstance(extensions, dict):
        raise AssetError(path, f"{at}extensions is {_brief(extensions)}, not an object")
    for name, shape in SHAPES.get(kind, {}).items():
        value = obj.get(name)
        if value is None:
            if isinstance(shape, list) and shape and shape[0] is not str:
                obj[name] = []
            continue
        if isinstance(shape, str):
            if not isinstance(value, dict):
                raise AssetError(path, f"{at}{name} is {_brief(value)}, not an object")
            if shape == "sparse":
                obj[name] = value = _Sparse(value)
            _check_shape(path, value, shape, f"{where} {name}".lstrip())
            continue
        if not isinstance(value, list):
            raise AssetError(path, f"{at}{name} is {_brief(value)}, not an array")
        element = _ELEMENT_NAMES.get(name, name)
        for i, item in enumerate(value):
            if shape == [str] and not isinstance(item, str):
                raise AssetError(path, f"{at}{name}[{i}] is {_brief(item)}, not a string")
            if shape and shape[0] is not str:
                if not isinstance(item, dict):
                    raise AssetError(path, f"{at}{element} {i} is {_brief(item)}, not an object")
                _check_shape(path, item, shape[0], f"{where} {element} {i}".lstrip())


def _brief(value) -> str:
    """`value` for a message: its repr, or its JSON type when that is long."""
    text = repr(value)
    if len(text) <= 40:
        return text
    return {dict: "an object", list: "an array", str: "a string"}.get(type(value), "a number")


def _check_version(path: str, asset) -> None:
    """Refuse a file that is not glTF 2.x or needs a newer minor version (glTF 2.0 "Asset")."""
    version = asset.get("version") if isinstance(asset, dict) else None
    if version is None:
        raise AssetError(path, "no asset.version: not a glTF 2.0 file (the asset object and its version are required)")
    if not isinstance(version, str):
        raise AssetError(path, f"asset.version is {version!r}, not a version string such as '2.0'")
    match = VERSION.fullmatch(version)
    if match is None or int(match[1]) != 2:
        raise AssetError(path, f"asset.version is {version!r}; only glTF 2.x is read "
                               "(gltf-pipeline -i in.gltf -o out.gltf upgrades a glTF 1.0 file)")
    minimum = asset.get("minVersion")
    if minimum is not None:
        match = VERSION.fullmatch(minimum) if isinstance(minimum, str) else None
        if match is None or (int(match[1]), int(match[2])) > (2, 0):
            raise AssetError(path, f"asset.minVersion is {minimum!r}; sssbake reads glTF 2.0")


def _whole(path: str, value, what: str, least: int = 0, default: int | None = None) -> int:
    """`value` as a whole number >= `least` (`default` when absent), or an `AssetError` naming `what`."""
    if value is None and default is not None:
        return default
    if not isinstance(value, int) or isinstance(value, bool) or value < least:
        raise AssetError(path, f"{what} is {value!r}; glTF 2.0 requires a whole number >= {least}")
    return value


def _item(doc: _Document, items: list, index, what: str):
    """``items[index]`` or an `AssetError` naming `what` when the index is invalid."""
    if not isinstance(index, int) or isinstance(index, bool) or not 0 <= index < len(items):
        raise AssetError(doc.path, f"{what} index {index!r} out of range ({len(items)} {what}s)")
    return items[index]


def _uri_bytes(path: str, uri, what: str, confinement: Confinement, limit: int,
               read: list[tuple[str, str]]) -> tuple[bytes, str | None]:
    """Bytes behind a data: URI or a file the URI names, and the data URI's media type.

    A relative reference is percent-decoded and taken from the asset's folder, a ``file:`` URI is its
    path; either must pass `confinement` before it is opened, and at most `limit` bytes of it are read.
    A file's real path and digest are appended to `read`.
    Other schemes (http:, ...) are refused: a batch never fetches.
    """
    if not isinstance(uri, str):
        raise AssetError(path, f"{what} has uri {uri!r}, not a string")
    if uri.startswith("data:"):
        header, sep, payload = uri[5:].partition(",")
        if not sep:
            raise AssetError(path, f"{what}: malformed data URI")
        try:
            if header.endswith(";base64"):
                return base64.b64decode(payload, validate=True), header[: -len(";base64")] or None
            return unquote_to_bytes(payload), header or None
        except (binascii.Error, ValueError):
            raise AssetError(path, f"{what}: invalid base64 in data URI") from None
    reference = f"{what} URI '{uri}'"
    parts = urlsplit(uri)
    if parts.scheme == "file" and parts.netloc in ("", "localhost"):
        file = Path(unquote(parts.path))
    elif len(parts.scheme) > 1:  # one letter: a Windows drive, i.e. a path
        raise AssetError(path, f"{reference} is not a file beside the asset; sssbake reads only relative paths, "
                               "file: and data: URIs")
    else:
        file = Path(path).parent / unquote(uri)
    if "\0" in str(file):
        raise AssetError(path, f"{reference} contains a NUL character")
    real = confinement.check(file, reference)
    if not real.is_file():
        raise AssetError(path, f"{what}: missing file '{uri}'")
    with open(real, "rb") as f:
        data = f.read(limit)
        whole = not f.read(1)
    # A file read whole is hashed from memory; one longer than its limit is hashed from disk, in blocks.
    read.append((str(real), bytes_digest(data) if whole else file_digest(real)))
    return data, None


def load_buffers(path: str, gltf: GltfObject, blob: memoryview | None,
                 confinement: Confinement, read: list[tuple[str, str]]) -> tuple[bytes | memoryview, ...]:
    """Each buffer's first ``byteLength`` bytes (a GLB BIN chunk may be padded past it; an external
    file is read no further, and its real path and digest appended to `read`)."""
    out = []
    for i, buf in enumerate(gltf.buffers):
        size = _whole(path, buf.byteLength, f"buffer {i} byteLength", least=1)
        if size > MAX_BUFFER_BYTES:
            raise AssetError(path, f"buffer {i} declares byteLength {size}, over the {MAX_BUFFER_BYTES >> 30} GiB "
                                   "sssbake reads per buffer")
        if buf.uri is None:
            if blob is None or i != 0:
                raise AssetError(path, f"buffer {i} has no uri and the file has no GLB binary chunk")
            data = blob
        else:
            data, _ = _uri_bytes(path, buf.uri, f"buffer {i}", confinement, size, read)
        if len(data) < size:
            raise AssetError(path, f"truncated buffer {i}: {len(data)} bytes, byteLength says {size}")
        out.append(data if len(data) == size else memoryview(data)[:size])
    return tuple(out)


def _view(doc: _Document, index) -> tuple[memoryview, int | None, int]:
    """Bytes of a buffer view, its byteStride (checked: a multiple of 4 in [4, 252]) and its byteOffset."""
    view = _item(doc, doc.gltf.bufferViews, index, "buffer view")
    data = _item(doc, doc.buffers, view.buffer, "buffer")
    start = _whole(doc.path, view.byteOffset, f"buffer view {index} byteOffset", default=0)
    end = start + _whole(doc.path, view.byteLength, f"buffer view {index} byteLength", least=1)
    if end > len(data):
        raise AssetError(
            doc.path, f"buffer {view.buffer} is shorter than buffer view {index} needs ({len(data)} < {end} bytes)"
        )
    stride = view.byteStride
    if stride is not None and (not isinstance(stride, int) or isinstance(stride, bool) or stride % 4
                               or not 4 <= stride <= 252):
        raise AssetError(doc.path, f"buffer view {index} has byteStride {stride!r}; glTF 2.0 requires a multiple "
                                   "of 4 from 4 to 252")
    return memoryview(data)[start:end], stride, start


def _strided(doc: _Document, view_index, offset, dtype: str, count: int, kind: str, what: str) -> np.ndarray:
    """(count, width) array of `dtype` read from a buffer view, honouring its byteStride; width is the
    number of components of accessor type `kind` (``"VEC3"``: 3).

    `offset` (the accessor's byteOffset) and the view's own offset must be multiples of the component
    size, and a stride must hold a whole element (glTF 2.0 "Data Alignment")."""
    data, stride, view_offset = _view(doc, view_index)
    offset = _whole(doc.path, offset, f"{what} byteOffset", default=0)
    itemsize, width = np.dtype(dtype).itemsize, TYPE_SIZES[kind]
    if offset % itemsize or (view_offset + offset) % itemsize:
        raise AssetError(doc.path, f"{what} starts at byte {view_offset + offset} of its buffer ({offset} into buffer "
                                   f"view {view_index}), not a multiple of its {itemsize}-byte component")
    element = itemsize * width
    if stride is not None and stride < element:
        raise AssetError(doc.path, f"{what}: byteStride {stride} of buffer view {view_index} is smaller than the "
                                   f"{element}-byte {kind} {np.dtype(dtype).name.replace('32', '')} element")
    stride = stride or element
    needed = offset + (count - 1) * stride + element if count else 0
    if needed > len(data):
        raise AssetError(doc.path, f"{what} needs {needed} bytes of buffer view {view_index}, which has {len(data)}")
    return np.ndarray((count, width), dtype, buffer=data, offset=offset, strides=(stride, itemsize)).copy()


def _accessor(doc: _Document, index, what: str) -> tuple[np.ndarray, GltfObject]:
    """(count, components) array of an accessor in its stored component type, sparse values applied."""
    acc = _item(doc, doc.gltf.accessors, index, "accessor")
    name = f"{what} (accessor {index})"
    dtype = COMPONENT_DTYPES.get(acc.componentType)
    width = TYPE_SIZES.get(acc.type)
    if dtype is None or width is None:
        raise AssetError(doc.path, f"{name} has unknown componentType {acc.componentType} or type {acc.type!r}")
    count = _whole(doc.path, acc.count, f"{name} count", least=1)
    if acc.normalized and acc.componentType in (5125, 5126):
        raise AssetError(doc.path, f"{name} is a normalized {COMPONENT_NAMES[acc.componentType]}; glTF 2.0 "
                                   "normalizes only 8- and 16-bit integers")
    if acc.bufferView is None:
        # All zeros (plus sparse values): a bit-flipped count must not allocate gigabytes.
        if count * width * np.dtype(dtype).itemsize > MAX_BUFFER_BYTES:
            raise AssetError(doc.path, f"{name} has count {count} and no buffer view: over the "
                                       f"{MAX_BUFFER_BYTES >> 30} GiB sssbake reads per buffer")
        values = np.zeros((count, width), dtype)
    else:
        values = _strided(doc, acc.bufferView, acc.byteOffset, dtype, count, acc.type, name)
    if acc.sparse is not None:
        sparse = acc.sparse
        index_dtype = COMPONENT_DTYPES.get(sparse.indices.componentType)
        if sparse.indices.componentType not in INDEX_COMPONENTS:
            raise AssetError(doc.path, f"{name}: sparse indices have componentType {sparse.indices.componentType}")
        n = _whole(doc.path, sparse.count, f"{name} sparse count", least=1)
        if n > count:
            raise AssetError(doc.path, f"{name}: sparse count {n} exceeds the accessor's count {count}")
        _unstrided(doc, sparse.indices.bufferView, f"{name}: sparse indices")
        _unstrided(doc, sparse.values.bufferView, f"{name}: sparse values")
        where = _strided(doc, sparse.indices.bufferView, sparse.indices.byteOffset, index_dtype, n, "SCALAR", name)
        where = where.ravel().astype(np.int64)
        if (np.diff(where) <= 0).any():
            k = int(np.argmax(np.diff(where) <= 0)) + 1
            raise AssetError(doc.path, f"{name}: sparse indices are not strictly increasing ({int(where[k])} "
                                       f"follows {int(where[k - 1])})")
        if where[-1] >= count:
            raise AssetError(doc.path, f"{name}: sparse index {int(where[-1])} out of range for {count} elements")
        values[where] = _strided(doc, sparse.values.bufferView, sparse.values.byteOffset, dtype, n, acc.type, name)
    return values, acc


def _floats(values: np.ndarray, normalized: bool) -> np.ndarray:
    """float64 copy; normalized integers mapped to [0, 1] (unsigned) or [-1, 1] (signed) as the spec says."""
    if values.dtype.kind == "f" or not normalized:
        return values.astype(np.float64)
    out = values.astype(np.float64) / np.iinfo(values.dtype).max
    return np.maximum(out, -1.0) if values.dtype.kind == "i" else out


def _check_semantic(doc: _Document, acc: GltfObject, index, name: str, where: str,
                    table: dict = SEMANTICS, quantized: dict = QUANTIZED) -> None:
    """Refuse an accessor whose type, componentType or normalized flag glTF 2.0 does not allow for
    attribute `name` (`table`, widened by `quantized` when the file uses KHR_mesh_quantization; a morph
    target's are `TARGET_SEMANTICS` and `TARGET_QUANTIZED`).
    Application-specific attributes (``_FOO``) are not checked."""
    semantic = name.rsplit("_", 1)[0] if name[-1:].isdigit() else name
    if semantic not in table:
        return
    types, components = table[semantic]
    if doc.quantized:
        components = components | quantized.get(semantic, frozenset())
    if acc.type not in types:
        raise AssetError(doc.path, f"{where}: {name} accessor {index} has type {acc.type}, expected {' or '.join(types)}")
    if (acc.componentType, bool(acc.normalized)) not in components:
        allowed = ", ".join(_component_name(*c) for c in sorted(components, key=lambda c: (c[0] != 5126, c)))
        hint = "" if doc.quantized or semantic not in quantized else f" ({QUANTIZATION} allows more)"
        raise AssetError(doc.path, f"{where}: {name} accessor {index} is "
                                   f"{_component_name(acc.componentType, bool(acc.normalized))}; glTF 2.0 allows "
                                   f"{allowed}{hint}")


def _component_name(component, normalized: bool) -> str:
    """``"normalized UNSIGNED_BYTE"`` and the like, for messages."""
    return ("normalized " if normalized else "") + COMPONENT_NAMES.get(component, repr(component))


def _attribute(doc: _Document, index, name: str, count: int | None, where: str,
               decoded: np.ndarray | None = None) -> np.ndarray:
    """float64 (count, k) vertex attribute, checked against its semantic (`_check_semantic`) and
    (unless `count` is None) for length.

    `decoded`: the attribute's values as a KHR_draco_mesh_compression stream decodes them (the accessor
    then gives only the type, the count and ``normalized``)."""
    if decoded is None:
        values, acc = _accessor(doc, index, f"{where} {name}")
    else:
        acc = _item(doc, doc.gltf.accessors, index, "accessor")
        values = decoded
        if values.dtype.kind != "f" and acc.componentType in COMPONENT_DTYPES:
            values = values.astype(COMPONENT_DTYPES[acc.componentType])  # normalized: the accessor's type's range
        if values.shape[1] != TYPE_SIZES.get(acc.type) or len(values) != acc.count:
            raise AssetError(doc.path, f"{where}: {DRACO} decodes {name} as {len(values)} x {values.shape[1]} values, "
                                       f"accessor {index} says {acc.count} x {acc.type}")
    _check_semantic(doc, acc, index, name, where)
    if count is not None and len(values) != count:
        raise AssetError(doc.path, f"{where}: {name} has {len(values)} elements but POSITION has {count}")
    return _floats(values, bool(acc.normalized))


def _primitive(doc: _Document, prim: GltfObject, where: str) -> Primitive | None:
    """A primitive's triangles and vertex attributes; None for points and lines."""
    mode = _whole(doc.path, prim.mode, f"{where} mode", default=4)
    if mode not in (4, 5, 6):
        return None
    attrs = dict(prim.attributes or {})
    if "POSITION" not in attrs:
        raise AssetError(doc.path, f"{where} has no POSITION attribute")
    # Attributes sssbake does not read (JOINTS_n, WEIGHTS_n, ...) must still be what the spec allows.
    for name, index in attrs.items():
        _check_semantic(doc, _item(doc, doc.gltf.accessors, index, "accessor"), index, name, where)
    _check_targets(doc, prim, _item(doc, doc.gltf.accessors, attrs["POSITION"], "accessor").count, where)
    draco = _draco(doc, prim, attrs, where)

    def read(name: str, count: int | None) -> np.ndarray:
        return _attribute(doc, attrs[name], name, count, where, draco.get(name))

    positions = read("POSITION", None)
    n = len(positions)
    normals = read("NORMAL", n) if "NORMAL" in attrs else None
    tangents = read("TANGENT", n) if "TANGENT" in attrs else None
    uvs = []
    while f"TEXCOORD_{len(uvs)}" in attrs:
        uvs.append(read(f"TEXCOORD_{len(uvs)}", n))
    colors = None
    if "COLOR_0" in attrs:
        colors = read("COLOR_0", n)
        if colors.shape[1] == 3:
            colors = np.column_stack([colors, np.ones(n)])
    if "indices" in draco:
        index = draco["indices"]
    elif prim.indices is None:
        index = np.arange(n, dtype=np.int64)
    else:
        index = _indices(doc, prim.indices, where)
    if len(index) and index.max() >= n:
        raise AssetError(doc.path, f"{where}: index {int(index.max())} out of range for {n} vertices")
    if prim.material is not None:
        _item(doc, doc.gltf.materials, prim.material, "material")
    return Primitive(
        positions=positions,
        faces=_faces(doc, index, mode, where),
        normals=normals,
        uvs=tuple(uvs),
        colors=colors,
        material=prim.material,
        tangents=tangents,
    )


def _indices(doc: _Document, index, where: str) -> np.ndarray:
    """int64 index list of a primitive's indices accessor: SCALAR, an unsigned integer type, not
    normalized, in a buffer view without byteStride, and free of the primitive-restart value (the type's
    maximum), as glTF 2.0 requires."""
    view = _item(doc, doc.gltf.accessors, index, "accessor").bufferView
    if view is not None:
        _unstrided(doc, view, f"{where}: indices accessor {index}")
    values, acc = _accessor(doc, index, f"{where} indices")
    if acc.type != "SCALAR":
        raise AssetError(doc.path, f"{where}: indices accessor {index} has type {acc.type}, expected SCALAR")
    if acc.componentType not in INDEX_COMPONENTS or acc.normalized:
        raise AssetError(doc.path, f"{where}: indices accessor {index} is "
                                   f"{_component_name(acc.componentType, bool(acc.normalized))}; glTF 2.0 allows "
                                   "UNSIGNED_BYTE, UNSIGNED_SHORT or UNSIGNED_INT")
    restart = np.iinfo(values.dtype).max
    if len(values) and values.max() == restart:
        raise AssetError(doc.path, f"{where}: indices accessor {index} holds {restart}, the primitive-restart value "
                                   f"of {COMPONENT_NAMES[acc.componentType]}, which glTF 2.0 forbids")
    return values.ravel().astype(np.int64)


def _unstrided(doc: _Document, view_index, what: str) -> None:
    """Refuse a byteStride on a buffer view of index data (glTF 2.0: only vertex attributes have one)."""
    stride = _item(doc, doc.gltf.bufferViews, view_index, "buffer view").byteStride
    if stride is not None:
        raise AssetError(doc.path, f"{what} uses buffer view {view_index}, which has byteStride {stride!r}; glTF 2.0 "
                                   "allows byteStride only on vertex attribute data")


def _check_targets(doc: _Document, prim: GltfObject, count, where: str) -> None:
    """Refuse a morph target whose attribute is not an object of accessors of the kind glTF 2.0 allows
    (`TARGET_SEMANTICS`) or whose count differs from the primitive's POSITION `count`. sssbake does not
    read the displacements; a file breaking these rules is still not glTF."""
    for t, target in enumerate(prim.targets or ()):
        for name, index in target.items():
            acc = _item(doc, doc.gltf.accessors, index, "accessor")
            _check_semantic(doc, acc, index, name, f"{where} target {t}", TARGET_SEMANTICS, TARGET_QUANTIZED)
            if acc.count != count:
                raise AssetError(doc.path, f"{where} target {t}: {name} accessor {index} has count {acc.count!r} "
                                           f"but POSITION has {count!r}")


def _draco(doc: _Document, prim: GltfObject, attrs: dict, where: str) -> dict[str, np.ndarray]:
    """A KHR_draco_mesh_compression primitive's attributes (by glTF name) and ``indices``, decoded.

    Empty when the primitive is not compressed, or when the extension is only used and the accessors
    hold the uncompressed fallback (read as they are: exact, where Draco quantizes)."""
    ext = (prim.extensions or {}).get(DRACO)
    if not isinstance(ext, dict):
        return {}
    position = _item(doc, doc.gltf.accessors, attrs["POSITION"], "accessor")
    if DRACO not in (doc.gltf.extensionsRequired or ()) and (position.bufferView is not None or position.sparse):
        return {}
    try:
        import DracoPy
    except ImportError:
        raise AssetError(doc.path, _unsupported(DRACO, " (the Python package DracoPy is not installed)")) from None
    data = bytes(_view(doc, ext.get("bufferView"))[0])
    try:
        mesh = DracoPy.decode(data)
    except Exception as e:  # DracoPy raises its own types (and ValueError) on a corrupt stream
        raise AssetError(doc.path, f"{where}: {DRACO} data cannot be decoded ({type(e).__name__}: {e})") from None
    if not isinstance(mesh, DracoPy.DracoMesh):
        raise AssetError(doc.path, f"{where}: {DRACO} data is a point cloud, not a triangle mesh")
    out = {"indices": np.asarray(mesh.faces, np.int64).reshape(-1)}
    for name, unique_id in (ext.get("attributes") or {}).items():
        attribute = mesh.get_attribute_by_unique_id(unique_id)
        if attribute is None or name not in attrs:
            raise AssetError(doc.path, f"{where}: {DRACO} maps {name} to Draco attribute {unique_id!r}, which "
                                       f"{'the stream lacks' if attribute is None else 'the primitive does not list'}")
        values = np.asarray(attribute["data"])
        out[name] = values.reshape(len(values), -1)
    return out


def _faces(doc: _Document, index: np.ndarray, mode: int, where: str) -> np.ndarray:
    """(m, 3) int64 triangles from a TRIANGLES, TRIANGLE_STRIP or TRIANGLE_FAN index list."""
    if mode == 4:
        if len(index) % 3:
            raise AssetError(doc.path, f"{where}: {len(index)} indices is not a multiple of 3")
        return index.reshape(-1, 3)
    i = np.arange(max(len(index) - 2, 0))
    if mode == 5:
        # Every other strip triangle swaps two corners so all keep the strip's winding.
        return np.column_stack([index[i], index[i + 1 + i % 2], index[i + 2 - i % 2]])
    return np.column_stack([index[i + 1], index[i + 2], np.full(len(i), index[0] if len(index) else 0)])


def _node_matrices(doc: _Document) -> np.ndarray:
    """(n, 4, 4) local transform of every node, from ``matrix`` (column-major) or translation,
    rotation, scale; computed for all nodes at once (a file may hold 100,000)."""
    nodes = doc.gltf.nodes
    n = len(nodes)
    fields = {"translation": (3, (0.0, 0.0, 0.0)), "rotation": (4, (0.0, 0.0, 0.0, 1.0)), "scale": (3, (1.0, 1.0, 1.0)),
              "matrix": (16, tuple(np.eye(4).ravel()))}
    values = {}
    for name, (width, default) in fields.items():
        values[name] = np.tile(np.array(default), (n, 1))
        given = [i for i, node in enumerate(nodes) if node.get(name) is not None]
        try:
            values[name][given] = np.array([nodes[i][name] for i in given], np.float64).reshape(len(given), width)
        except (ValueError, TypeError, OverflowError):  # another length, or not numbers: name the first such node
            for i in given:
                try:
                    shape = np.array(nodes[i][name], np.float64).shape
                except (ValueError, TypeError, OverflowError):
                    shape = None
                if shape != (width,):
                    raise AssetError(doc.path, f"node {i} has a malformed transform ({name} is "
                                               f"{_brief(nodes[i][name])}, not {width} numbers)") from None
        finite = np.isfinite(values[name]).all(axis=1)
        if not finite.all():  # before normalising: a NaN quaternion would read as none at all
            raise AssetError(doc.path, f"node {int(np.argmin(finite))} has a non-finite transform")
    matrices = np.zeros((n, 4, 4))
    matrices[:, :3, :3] = _quaternion_matrices(values["rotation"]) * values["scale"][:, None, :]
    matrices[:, :3, 3] = values["translation"]
    matrices[:, 3, 3] = 1.0
    given = [i for i, node in enumerate(nodes) if node.get("matrix") is not None]
    matrices[given] = values["matrix"][given].reshape(-1, 4, 4).transpose(0, 2, 1)
    finite = np.isfinite(matrices).all(axis=(1, 2))
    if not finite.all():  # finite parts, overflowing product
        raise AssetError(doc.path, f"node {int(np.argmin(finite))} has a non-finite transform")
    return matrices


def _quaternion_matrices(q: np.ndarray) -> np.ndarray:
    """(n, 3, 3) rotations of quaternions (n, 4) (x, y, z, w), each normalised first (a zero one: none)."""
    norm = np.linalg.norm(q, axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        q = np.where((norm > 0)[:, None], q / norm[:, None], [0.0, 0.0, 0.0, 1.0])
    x, y, z, w = q.T
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], axis=-1),
        np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], axis=-1),
        np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], axis=-1),
    ], axis=1)


def _nodes(doc: _Document) -> tuple[Node, ...]:
    """All nodes, checked to form disjoint strict trees (glTF 2.0 "Nodes and Hierarchy"; `_check_trees`)."""
    gltf = doc.gltf
    nodes = []
    instances: list[Node] = []  # EXT_mesh_gpu_instancing: one child node per instance, after the file's nodes
    parents = [-1] * len(gltf.nodes)
    matrices = _node_matrices(doc)
    for i, node in enumerate(gltf.nodes):
        mesh = node.get("mesh")
        if mesh is not None:
            _item(doc, gltf.meshes, mesh, "mesh")
        children = tuple(node.get("children") or ())
        for c in children:
            _item(doc, gltf.nodes, c, "node")
            if parents[c] != -1:
                raise AssetError(doc.path, f"node {c} is the child of more than one node (nodes {parents[c]} and {i})"
                                 if parents[c] != i else f"node {i} lists node {c} as a child twice")
            parents[c] = i
        name = node.get("name") or f"node_{i}"
        instancing = (node.get("extensions") or {}).get(INSTANCING)
        if isinstance(instancing, dict) and mesh is not None:
            # The node draws its mesh once per instance transform (applied before the node's own), never alone.
            first = len(gltf.nodes) + len(instances)
            placed = _instance_matrices(doc, instancing, i)
            instances += [Node(f"{name}_instance_{k}", m, mesh) for k, m in enumerate(placed)]
            children += tuple(range(first, len(gltf.nodes) + len(instances)))
            mesh = None
        nodes.append(Node(name, matrices[i], mesh, children))
    _check_trees(doc, nodes, parents)
    return tuple(nodes + instances)


def _check_trees(doc: _Document, nodes: list[Node], parents: list[int]) -> None:
    """Refuse a cycle of child links, whether or not a scene reaches it: glTF 2.0 nodes form disjoint
    strict trees, and a cycle would have every walk of the graph loop for ever.

    With one parent per node (checked before), every node lies below a parentless one, except on or
    below a cycle; a walk up from any node no root reaches comes back to a node on it. Linear time,
    no recursion (a chain of 100,000 nodes is a legal tree)."""
    reached = [False] * len(nodes)
    stack = [i for i, p in enumerate(parents) if p == -1]
    while stack:
        i = stack.pop()
        reached[i] = True
        stack.extend(c for c in nodes[i].children if c < len(nodes))  # instances (past the file's nodes) are leaves
    if all(reached):
        return
    i, seen = reached.index(False), set()
    while i not in seen:
        seen.add(i)
        i = parents[i]
    cycle, j = [i], parents[i]
    while j != i:
        cycle.append(j)
        j = parents[j]
    raise AssetError(doc.path, f"the node graph has a cycle through node {min(cycle)} ({len(cycle)} node"
                               f"{'s' if len(cycle) > 1 else ''}); glTF 2.0 nodes form disjoint trees")


def _instance_matrices(doc: _Document, ext: dict, i: int) -> list[np.ndarray]:
    """(4, 4) transform of each EXT_mesh_gpu_instancing instance of node `i` (TRANSLATION, ROTATION, SCALE)."""
    attrs = ext.get("attributes") or {}
    where = f"node {i} {INSTANCING}"
    read = {name: _attribute(doc, attrs[name], name, None, where)
            for name in ("TRANSLATION", "ROTATION", "SCALE") if name in attrs}
    counts = {len(v) for v in read.values()}
    if len(counts) != 1:
        raise AssetError(doc.path, f"{where}: " + ("no instance attributes" if not counts else
                                                  f"attributes of different counts {sorted(counts)}"))
    k = counts.pop()
    matrices = np.tile(np.eye(4), (k, 1, 1))
    rotation = read.get("ROTATION", np.tile([0.0, 0.0, 0.0, 1.0], (k, 1)))
    matrices[:, :3, :3] = _quaternion_matrices(rotation) * (read["SCALE"][:, None, :] if "SCALE" in read else 1.0)
    if "TRANSLATION" in read:
        matrices[:, :3, 3] = read["TRANSLATION"]
    finite = np.isfinite(matrices).all(axis=(1, 2)) & np.isfinite(rotation).all(axis=1)
    if not finite.all():
        raise AssetError(doc.path, f"{where}: instance {int(np.argmin(finite))} has a non-finite transform")
    return list(matrices)


def _roots(doc: _Document, nodes: tuple[Node, ...]) -> tuple[int, ...]:
    """Root nodes of the default scene (scene 0 when unset; every parentless node without scenes)."""
    gltf = doc.gltf
    children = {c for n in nodes for c in n.children}
    if not gltf.scenes:
        return tuple(i for i in range(len(nodes)) if i not in children)
    scene = _item(doc, gltf.scenes, 0 if gltf.scene is None else gltf.scene, "scene")
    roots = tuple(scene.nodes or ())
    for r in roots:
        _item(doc, gltf.nodes, r, "node")
        # glTF 2.0: a scene lists root nodes; a child listed too would be drawn twice, once out of its tree.
        if r in children:
            raise AssetError(doc.path, f"scene root node {r} is also the child of another node")
    return roots


def _texture_ref(doc: _Document, info, slot: str) -> TextureRef | None:
    if info is None or info.index is None:
        return None
    _item(doc, doc.gltf.textures, info.index, f"{slot} texture")
    return TextureRef(info.index, info.texCoord or 0, _texture_transform(doc, info, slot))


def _texture_transform(doc: _Document, info, slot: str) -> TextureTransform | None:
    """A texture slot's KHR_texture_transform (kept as authored, for the exporter to write back)."""
    ext = (info.extensions or {}).get(TEXTURE_TRANSFORM)
    if ext is None:
        return None
    try:
        offset = tuple(float(x) for x in ext.get("offset", (0.0, 0.0)))
        scale = tuple(float(x) for x in ext.get("scale", (1.0, 1.0)))
        rotation = float(ext.get("rotation", 0.0))
        tex_coord = ext.get("texCoord")
        if len(offset) != 2 or len(scale) != 2 or not np.isfinite(offset + scale + (rotation,)).all() or not (
                tex_coord is None or (isinstance(tex_coord, int) and tex_coord >= 0)):
            raise ValueError
    except (AttributeError, TypeError, ValueError):
        raise AssetError(doc.path, f"{slot} texture: malformed {TEXTURE_TRANSFORM} {ext!r}") from None
    return TextureTransform(offset, rotation, scale, tex_coord)


def _material(doc: _Document, m: GltfObject, i: int) -> SourceMaterial:
    """glTF material terms; defaults are the glTF spec's (metallic 1, roughness 1)."""
    pbr = m.pbrMetallicRoughness or GltfObject()
    ext = m.extensions or {}
    base = tuple(float(x) for x in (pbr.baseColorFactor or (1.0, 1.0, 1.0, 1.0)))
    emissive = tuple(float(x) for x in (m.emissiveFactor or (0.0, 0.0, 0.0)))
    if len(base) != 4 or len(emissive) != 3:
        raise AssetError(doc.path, f"material {i}: baseColorFactor needs 4 numbers and emissiveFactor 3")
    ior = ext.get("KHR_materials_ior")
    return SourceMaterial(
        name=m.name or f"material_{i}",
        base_color_factor=base,
        base_color_texture=_texture_ref(doc, pbr.baseColorTexture, "baseColor"),
        metallic_factor=1.0 if pbr.metallicFactor is None else float(pbr.metallicFactor),
        roughness_factor=1.0 if pbr.roughnessFactor is None else float(pbr.roughnessFactor),
        metallic_roughness_texture=_texture_ref(doc, pbr.metallicRoughnessTexture, "metallicRoughness"),
        normal_texture=_texture_ref(doc, m.normalTexture, "normal"),
        occlusion_texture=_texture_ref(doc, m.occlusionTexture, "occlusion"),
        emissive_factor=emissive,
        emissive_texture=_texture_ref(doc, m.emissiveTexture, "emissive"),
        double_sided=bool(m.doubleSided),
        ior=None if ior is None else float(ior.get("ior", 1.5)),
        volume=_material_extension(doc, ext, "KHR_materials_volume", i),
        diffuse_transmission=_material_extension(doc, ext, "KHR_materials_diffuse_transmission", i),
        volume_scatter=_material_extension(doc, ext, "KHR_materials_volume_scatter", i),
    )


def _material_extension(doc: _Document, ext: dict, name: str, i: int) -> dict | None:
    """Material `i`'s extension object `name` (None when absent) as plain dicts and lists (`_plain`)."""
    if name not in ext:
        return None
    if not isinstance(ext[name], dict):
        raise AssetError(doc.path, f"material {i}: {name} is {_brief(ext[name])}, not an object")
    return _plain(ext[name])


def _plain(value):
    """JSON as plain dicts and lists: the scene goes into the stage cache, which stores no
    `GltfObject` (a volume's ``thicknessTexture`` is one)."""
    if isinstance(value, dict):
        return {k: _plain(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_plain(v) for v in value]
    return value


def _textures_and_images(doc: _Document) -> tuple[tuple[Texture, ...], tuple[Image, ...]]:
    """Textures and images; an image only an extension names (EXT_texture_webp, KHR_texture_basisu beside a
    PNG/JPEG source) is left out: no glTF can hold it without that extension."""
    textures = [_texture(doc, t, i) for i, t in enumerate(doc.gltf.textures)]
    images = [_image(doc, im, i) for i, im in enumerate(doc.gltf.images)]
    used = {t.image for t in textures}
    keep = [i for i, im in enumerate(images) if i in used or im.mime_type in CORE_IMAGE_TYPES]
    remap = {old: new for new, old in enumerate(keep)}
    return tuple(replace(t, image=remap[t.image]) for t in textures), tuple(images[i] for i in keep)


def _texture(doc: _Document, t: GltfObject, i: int) -> Texture:
    """Image and sampler state of a texture: its core (PNG/JPEG) source; a texture with only an extension's
    image (EXT_texture_webp, KHR_texture_basisu) is refused."""
    source = t.source
    if source is None:
        # Only an extension's image (WebP, KTX2): sssbake cannot write it back (the file would need the extension).
        ext = next((k for k, e in (t.extensions or {}).items() if isinstance(e, dict) and "source" in e), None)
        if ext is not None:
            raise AssetError(doc.path, f"texture {i}: its only image is an {ext} one (no PNG/JPEG fallback), "
                                       "and sssbake does not support that extension")
        raise AssetError(doc.path, f"texture {i} has no image")
    _item(doc, doc.gltf.images, source, "image")
    if t.sampler is None:
        return Texture(source)
    s = _item(doc, doc.gltf.samplers, t.sampler, "sampler")
    return Texture(source, s.magFilter, s.minFilter, s.wrapS or 10497, s.wrapT or 10497)


def _image(doc: _Document, im: GltfObject, i: int) -> Image:
    """Encoded bytes of an image (GLB buffer view, data: URI or external file) and its media type."""
    uri_mime = None
    if im.bufferView is not None:
        data = bytes(_view(doc, im.bufferView)[0])
    elif im.uri:
        data, uri_mime = _uri_bytes(doc.path, im.uri, f"image {i}", doc.confinement, MAX_IMAGE_BYTES + 1, doc.read)
    else:
        raise AssetError(doc.path, f"image {i} has neither a uri nor a bufferView")
    if len(data) > MAX_IMAGE_BYTES:
        raise AssetError(doc.path, f"image {i} is over the {MAX_IMAGE_BYTES >> 20} MiB sssbake reads per image")
    # The bytes' signature beats a declared type: exporters mislabel JPEGs as PNG, and the copy must not.
    mime = next((m for sig, m in IMAGE_SIGNATURES if data.startswith(sig)), None) or im.mimeType or uri_mime
    if mime is None:
        raise AssetError(doc.path, f"image {i}: unknown image format")
    name = im.name or (Path(unquote(im.uri)).stem if im.uri and not im.uri.startswith("data:") else f"image_{i}")
    return Image(name, mime, data)
