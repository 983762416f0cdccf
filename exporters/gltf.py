"""glTF 2.0 binary (.glb) export of a BakedAsset: geometry, materials, textures and sssbake data.

Layout of the file (documented for readers in ``exporters/schema/sssbake.schema.json``):

- one buffer (the GLB binary chunk); every buffer view starts on a 4-byte boundary;
- per primitive: POSITION, NORMAL, TANGENT, TEXCOORD_n, COLOR_0 (float32), indices (uint16/uint32), and
  each sssbake vertex attribute as an application-specific attribute ``_KEY`` stored in its
  own buffer view with a 4-byte-aligned ``byteStride``;
- translucent materials get ``KHR_materials_volume``, ``KHR_materials_diffuse_transmission`` and
  ``KHR_materials_ior`` (all optional: listed in ``extensionsUsed`` only), are single-sided (see
  `TRANSLUCENT_EXTENSIONS`) and carry the vendor extension `EXTENSION` with their scattering
  material and `BakedAsset.material_extras`' technique data (such as screen);
- the root's `EXTENSION` object holds the asset-level data, each scattering mesh's its scale,
  technique data, ``vertexCounts`` and ``attributeTypes``; `EXTENSION` is in ``extensionsUsed``,
  never in ``extensionsRequired`` (a viewer that ignores it still shows the fallback);
- numpy arrays in that data become accessors ("tables") named ``sssbake/<owner>/<key path>``
  and referenced by a table reference ``{"accessor", "name", "count", "type", "componentType",
  "crc32"}`` (`exporters/schema/SSSBAKE_subsurface.md`; `gltf_tables` resolves and checks them);
- a texture slot's ``KHR_texture_transform`` (read from the source) is written back as it was,
  listed in ``extensionsUsed``; images are copied byte for byte;
- on request (``volume_scatter``, the bake's ``--khr-materials-volume-scatter``), translucent materials
  also get Khronos's draft `VOLUME_SCATTER`, and their ``KHR_materials_volume`` attenuation is then the
  extinction σ'_t that draft defines instead of the fallback's σ_tr (`_volume_scatter`); listed in
  ``extensionsUsed`` only.
"""

from __future__ import annotations

import importlib.metadata
import json
import math
import os
import struct
import zlib

import numpy as np
import pygltflib as g

from sssbake.exporters.atomic import atomic_path
from sssbake.exporters.finite import check_finite, finite_number
from sssbake.pipeline.mesh.baked import (
    SCHEMA_VERSION,
    BakedAsset,
    ScatteringMaterial,
    VertexAttribute,
    check_material_references,
)
from sssbake.pipeline.mesh.scene import TEXTURE_TRANSFORM, SourceMaterial, TextureRef

FLOAT, BYTE, UNSIGNED_BYTE, SHORT, UNSIGNED_SHORT, UNSIGNED_INT = 5126, 5120, 5121, 5122, 5123, 5125
ARRAY_BUFFER, ELEMENT_ARRAY_BUFFER = 34962, 34963

#: encoding name -> (glTF componentType, numpy storage dtype, normalized)
ENCODINGS: dict[str, tuple[int, type, bool]] = {
    "float32": (FLOAT, np.float32, False),
    "snorm8": (BYTE, np.int8, True),
    "snorm16": (SHORT, np.int16, True),
    "unorm8": (UNSIGNED_BYTE, np.uint8, True),
    "unorm16": (UNSIGNED_SHORT, np.uint16, True),
    # Plain integers (indices, packed codes). glTF forbids UNSIGNED_INT vertex attributes, so 16
    # bits is the widest.
    "uint8": (UNSIGNED_BYTE, np.uint8, False),
    "uint16": (UNSIGNED_SHORT, np.uint16, False),
}
COMPONENT_DTYPES = {
    FLOAT: np.float32, BYTE: np.int8, UNSIGNED_BYTE: np.uint8, SHORT: np.int16,
    UNSIGNED_SHORT: np.uint16, UNSIGNED_INT: np.uint32,
}
COMPONENT_NAMES = {
    FLOAT: "FLOAT", BYTE: "BYTE", UNSIGNED_BYTE: "UNSIGNED_BYTE", SHORT: "SHORT",
    UNSIGNED_SHORT: "UNSIGNED_SHORT", UNSIGNED_INT: "UNSIGNED_INT",
}
#: The vendor extension that holds sssbake's data (root, meshes, materials).
EXTENSION = "SSSBAKE_subsurface"
#: Khronos's draft dense-scattering extension (glTF PR 2453), written only on request.
VOLUME_SCATTER = "KHR_materials_volume_scatter"

TYPE_SIZES = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT2": 4, "MAT3": 9, "MAT4": 16}
_VEC_TYPES = {1: "SCALAR", 2: "VEC2", 3: "VEC3", 4: "VEC4"}
_MAT_TYPES = {2: "MAT2", 3: "MAT3", 4: "MAT4"}

#: Extensions a translucent material carries (values: `pipeline.bake.fallback`).
#: KHR_materials_volume needs a transmission extension to mean anything: KHR_materials_transmission
#: (three.js and Blender read it), and KHR_materials_diffuse_transmission for viewers that have it
#: (glTF-Validator 2.0.0-dev.3.10 does not know it: an UNSUPPORTED_EXTENSION info). A volume on a
#: double-sided material is a validator warning (KHR_MATERIALS_VOLUME_DOUBLE_SIDED) and no volume
#: at all, so translucent materials are written single-sided.
TRANSLUCENT_EXTENSIONS = (
    "KHR_materials_transmission",
    "KHR_materials_volume",
    "KHR_materials_diffuse_transmission",
    "KHR_materials_ior",
)


def generator() -> str:
    """The ``asset.generator`` string, ``"sssbake <version>"``."""
    return f"sssbake {importlib.metadata.version('sssbake')}"


def quantize(data: np.ndarray, encoding: str) -> np.ndarray:
    """Values as stored for `encoding` (glTF's normalized-integer rounding).

    Parameters
    ----------
    data : (n,) or (n, k) float
    encoding : str
        A key of `ENCODINGS`.

    Returns
    -------
    (n,) or (n, k) array of the encoding's storage dtype.
    """
    _, dtype, normalized = ENCODINGS[encoding]
    if np.dtype(dtype).kind == "f":
        return np.asarray(data, dtype=np.float32)
    info = np.iinfo(dtype)
    if not normalized:
        if data.size and (data.min() < info.min or data.max() > info.max or np.any(data != np.round(data))):
            raise ValueError(f"{encoding} needs integers in [{info.min}, {info.max}], got [{data.min():g}, {data.max():g}]")
        return np.asarray(data).astype(dtype)
    low = -1.0 if info.min < 0 else 0.0
    if data.size and (data.min() < low or data.max() > 1.0):
        raise ValueError(f"{encoding} needs values in [{low:g}, 1], got [{data.min():g}, {data.max():g}]")
    return np.round(np.asarray(data, dtype=np.float64) * info.max).astype(dtype)


def dequantize(stored: np.ndarray, normalized: bool) -> np.ndarray:
    """Float64 values of stored accessor data (inverse of `quantize` up to rounding).

    Parameters
    ----------
    stored : (n,) or (n, k) array of a glTF component dtype
    normalized : bool
        The accessor's ``normalized`` flag.

    Returns
    -------
    (n,) or (n, k) float64
    """
    if not normalized or stored.dtype.kind == "f":
        return stored.astype(np.float64)
    info = np.iinfo(stored.dtype)
    # glTF decodes signed normalized values with max(c / MAX, -1): both -MAX and MIN mean -1.
    return np.maximum(stored.astype(np.float64) / info.max, -1.0)


def quantization_step(encoding: str) -> float:
    """Largest absolute round-trip error of a normalized `encoding` for in-range data.

    0.0 for ``"float32"``, whose rounding error is relative (2^-24).
    """
    _, dtype, normalized = ENCODINGS[encoding]
    return 0.5 / np.iinfo(dtype).max if normalized else 0.0


def accessor_elements(gltf: g.GLTF2, index: int, blob: bytes | None = None) -> np.ndarray:
    """The elements of accessor `index` as glTF stores them, densely: sparse substitutions applied,
    zeros where it has no buffer view, no stride padding.

    Parameters
    ----------
    gltf : GLTF2
        A file loaded with pygltflib (GLB: its binary chunk is used unless `blob` is given).
    index : int

    Returns
    -------
    (count, k) array of the accessor's component dtype, k its components per element (MATk:
    k² values in glTF's column-major order).
    """
    acc = gltf.accessors[index]
    data = gltf.binary_blob() if blob is None else blob
    dtype = np.dtype(COMPONENT_DTYPES[acc.componentType])
    k = TYPE_SIZES[acc.type]
    if acc.bufferView is None:
        values = np.zeros((acc.count, k), dtype=dtype)
    else:
        view = gltf.bufferViews[acc.bufferView]
        values = _strided(data, (view.byteOffset or 0) + (acc.byteOffset or 0), acc.count,
                          view.byteStride or dtype.itemsize * k, dtype, k)
    sparse = acc.sparse
    if sparse is not None and sparse.count:
        # Tools such as glTF-Transform's `sparse` rewrite mostly-zero accessors this way.
        ind, val = sparse.indices, sparse.values
        ind_view, val_view = gltf.bufferViews[ind.bufferView], gltf.bufferViews[val.bufferView]
        ind_dtype = np.dtype(COMPONENT_DTYPES[ind.componentType])
        rows = _strided(data, (ind_view.byteOffset or 0) + (ind.byteOffset or 0), sparse.count, ind_dtype.itemsize,
                        ind_dtype, 1)[:, 0].astype(np.int64)
        if rows.size and (rows.min() < 0 or rows.max() >= acc.count):
            raise ValueError(f"accessors[{index}]: sparse indices outside [0, {acc.count})")
        values[rows] = _strided(data, (val_view.byteOffset or 0) + (val.byteOffset or 0), sparse.count,
                                dtype.itemsize * k, dtype, k)
    return values


def _strided(data: bytes, start: int, count: int, stride: int, dtype: np.dtype, k: int) -> np.ndarray:
    """(count, k) elements of `k` little-endian `dtype` values at `start`, `stride` bytes apart."""
    elem = dtype.itemsize * k
    raw = np.frombuffer(data, dtype=np.uint8, count=max(stride * (count - 1) + elem, 0), offset=start)
    rows = np.lib.stride_tricks.as_strided(raw, shape=(count, elem), strides=(stride, 1))
    return np.ascontiguousarray(rows).view(dtype.newbyteorder("<")).astype(dtype)


def read_accessor(gltf: g.GLTF2, index: int, blob: bytes | None = None) -> np.ndarray:
    """The stored values of accessor `index`, as written (no dequantisation).

    Parameters
    ----------
    gltf : GLTF2
        A file loaded with pygltflib (GLB: its binary chunk is used unless `blob` is given).
    index : int

    Returns
    -------
    (count,) for SCALAR, (count, k) for VECk, (count, k, k) for MATk (row-major numpy layout,
    transposed from glTF's column-major storage); the accessor's component dtype.
    """
    acc = gltf.accessors[index]
    return element_array(accessor_elements(gltf, index, blob), acc.type)


def element_array(elements: np.ndarray, acc_type: str) -> np.ndarray:
    """`accessor_elements`' (count, k) rows in numpy's shape for `acc_type`: (count,) for SCALAR,
    (count, k) for VECk, (count, k, k) row-major for MATk."""
    count = len(elements)
    if acc_type == "SCALAR":
        return elements.reshape(count)
    if acc_type.startswith("MAT"):
        n = int(acc_type[3])
        return elements.reshape(count, n, n).transpose(0, 2, 1).copy()
    return elements


def table_crc32(elements: np.ndarray) -> str:
    """A table reference's ``crc32``: zlib CRC-32 of `elements` packed densely little-endian, as 8
    lowercase hex digits. glTF: (count, k) in glTF's element order, as `accessor_elements` gives
    them; USD: the restored table."""
    packed = np.ascontiguousarray(elements, dtype=elements.dtype.newbyteorder("<"))
    return f"{zlib.crc32(packed.tobytes()):08x}"


def to_glb(asset: BakedAsset, volume_scatter: dict[int, dict] | None = None) -> tuple[bytes, dict]:
    """Encode `asset` as GLB bytes: `glb_pieces` joined."""
    pieces, summary = glb_pieces(asset, volume_scatter)
    return b"".join(pieces), summary


def glb_pieces(asset: BakedAsset, volume_scatter: dict[int, dict] | None = None) -> tuple[list, dict]:
    """Encode `asset` as GLB, in pieces: the buffer views are the asset's own arrays where they
    are stored as they are (a bake's tables run to hundreds of MB: joined copies of them were
    the bake's memory peak).

    Parameters
    ----------
    volume_scatter : dict or None
        Scattering material index -> its `engine_materials.khr_materials_volume_scatter` record
        (`materials_json.khr_volume_scatter` gives the asset's, as its ``.materials.json`` holds
        them): those materials get `VOLUME_SCATTER` (`_volume_scatter`). None or empty: none does.

    Returns
    -------
    pieces : list of bytes-like
        The file is their concatenation.
    summary : dict
        ``bytes`` (file size), ``json_bytes``, ``bin_bytes``, ``vertices`` (all primitives),
        ``blocks`` {block name: bytes} (glTF attribute names such as ``POSITION``,
        ``TEXCOORD_1``, ``_THICKNESS``, summed over primitives, stride padding included;
        ``indices``; ``images``; ``tables``), ``kinds`` {``vertex``, ``index``, ``image``,
        ``table``, ``padding``: bytes; they sum to ``bin_bytes``}, and ``bytes_per_vertex``
        {attribute name: bytes / vertices of the primitives that carry it; ``total``: all vertex
        data / all vertices; ``sssbake``: ``_`` attributes / all vertices}.

    Raises
    ------
    ValueError
        Non-finite data (the message names the array), attribute data of the wrong length or
        out of its encoding's range, indices out of range, conflicting names.
    """
    gltf = g.GLTF2(asset=g.Asset(generator=generator(), version="2.0"))
    packer = _Packer(gltf)
    scene = asset.scene

    for image in scene.images:
        view = packer.view(image.data, "image", "images")
        gltf.images.append(g.Image(name=image.name or None, mimeType=image.mime_type, bufferView=view))
    samplers: dict[tuple, int] = {}
    for tex in scene.textures:
        key = (tex.mag_filter, tex.min_filter, tex.wrap_s, tex.wrap_t)
        if key not in samplers:
            samplers[key] = len(gltf.samplers)
            gltf.samplers.append(g.Sampler(magFilter=key[0], minFilter=key[1], wrapS=key[2], wrapT=key[3]))
        gltf.textures.append(g.Texture(sampler=samplers[key], source=tex.image))

    check_material_references(asset)
    volume_scatter = volume_scatter or {}
    bare = sorted(set(volume_scatter) - set(asset.scattering))
    if bare:
        raise ValueError(f"{VOLUME_SCATTER} for materials {bare} that have no scattering material")
    used: set[str] = set()
    for m, src in enumerate(scene.materials):
        material, extensions = _material(src, asset.scattering.get(m))
        if m in volume_scatter:
            extensions = extensions + _volume_scatter(material, volume_scatter[m], f"material {src.name!r}")
        if m in asset.material_extras:
            if EXTENSION not in (material.extensions or {}):
                raise ValueError(f"material {src.name!r} has technique data but no scattering material")
            _technique_extras(material.extensions[EXTENSION], asset.material_extras[m], packer,
                              f"material {src.name!r} extras", f"material{m}")
        gltf.materials.append(material)
        used.update(extensions)

    _check_attribute_keys(asset)
    vertex_counts: dict[str, int] = {}
    total_vertices = 0
    for i, mesh in enumerate(scene.meshes):
        prims = []
        for j, prim in enumerate(mesh.primitives):
            where = f"mesh {mesh.name!r} primitive {j}"
            attributes = _primitive_attributes(packer, prim, asset.vertex_attributes.get((i, j), ()), where)
            n = len(prim.positions)
            total_vertices += n
            for name in attributes:
                vertex_counts[name] = vertex_counts.get(name, 0) + n
            prims.append(g.Primitive(
                attributes=g.Attributes(**attributes),
                indices=_indices(packer, prim.faces, n, where),
                material=prim.material,
                mode=g.TRIANGLES,
            ))
        extensions = {}
        if i in asset.scale_mm or i in asset.mesh_extras:
            extensions[EXTENSION] = _mesh_extension(asset, i, prims, packer)
        gltf.meshes.append(g.Mesh(name=mesh.name or None, primitives=prims, extensions=extensions))

    for node in scene.nodes:
        matrix = np.asarray(node.matrix, dtype=np.float64)
        check_finite(matrix, f"node {node.name!r} matrix")
        gltf.nodes.append(g.Node(
            name=node.name or None,
            mesh=node.mesh,
            children=list(node.children),
            # glTF stores matrices column-major.
            matrix=None if np.array_equal(matrix, np.eye(4)) else matrix.flatten(order="F").tolist(),
        ))
    gltf.scenes.append(g.Scene(nodes=list(scene.roots)))
    gltf.scene = 0

    gltf.extensions = {EXTENSION: _asset_extras(asset, packer)}
    gltf.extensionsUsed = sorted(used | {EXTENSION})

    blob = packer.blob()
    bin_bytes = sum(len(piece) for piece in blob)
    if bin_bytes:
        gltf.buffers.append(g.Buffer(byteLength=bin_bytes))
    pieces, json_bytes = _pack_glb(gltf, blob, bin_bytes)

    blocks = dict(packer.blocks)
    kinds = dict(packer.kinds)
    kinds["padding"] = bin_bytes - sum(kinds.values())
    vertex_bytes = {name: blocks[name] for name in vertex_counts}
    per_vertex = {name: vertex_bytes[name] / vertex_counts[name] for name in vertex_counts}
    per_vertex["total"] = sum(vertex_bytes.values()) / total_vertices if total_vertices else 0.0
    per_vertex["sssbake"] = (
        sum(b for name, b in vertex_bytes.items() if name.startswith("_")) / total_vertices if total_vertices else 0.0
    )
    summary = {
        "bytes": sum(len(piece) for piece in pieces),
        "json_bytes": json_bytes,
        "bin_bytes": bin_bytes,
        "vertices": total_vertices,
        "blocks": blocks,
        "kinds": kinds,
        "bytes_per_vertex": per_vertex,
    }
    return pieces, summary


def write_glb(asset: BakedAsset, path: str | os.PathLike, volume_scatter: dict[int, dict] | None = None) -> dict:
    """Write `asset` to `path` (.glb) atomically: on any error nothing is left behind.

    `volume_scatter`: as `glb_pieces` takes it.

    Returns
    -------
    dict
        `to_glb`'s summary plus ``path``.
    """
    pieces, summary = glb_pieces(asset, volume_scatter)
    with atomic_path(path) as tmp, open(tmp, "wb") as f:
        for piece in pieces:
            f.write(piece)
    return {"path": str(path), **summary}


class _Packer:
    """Builds the one binary buffer: 4-byte-aligned buffer views, accessors, byte accounting."""

    def __init__(self, gltf: g.GLTF2):
        self.gltf = gltf
        self.chunks: list = []  # bytes-like, 1-D
        self.length = 0
        self.blocks: dict[str, int] = {}
        self.kinds = {"vertex": 0, "index": 0, "image": 0, "table": 0}

    def view(self, raw, kind: str, block: str, target: int | None = None, stride: int | None = None) -> int:
        pad = -self.length % 4
        if pad:
            self.chunks.append(b"\0" * pad)
            self.length += pad
        self.gltf.bufferViews.append(g.BufferView(
            buffer=0, byteOffset=self.length, byteLength=len(raw), byteStride=stride, target=target,
        ))
        self.chunks.append(raw)
        self.length += len(raw)
        self.blocks[block] = self.blocks.get(block, 0) + len(raw)
        self.kinds[kind] += len(raw)
        return len(self.gltf.bufferViews) - 1

    def accessor(self, values: np.ndarray, component: int, normalized: bool, kind: str, block: str,
                 target: int | None = None, minmax: bool = False, name: str | None = None) -> int:
        """Append `values` ((n,), (n, k) or (n, k, k), already in the component dtype) as an
        accessor named `name`."""
        n = len(values)
        if values.ndim == 3:
            acc_type = _MAT_TYPES[values.shape[1]]
            # numpy rows -> glTF columns
            flat = values.transpose(0, 2, 1).reshape(n, -1)
        else:
            flat = values.reshape(n, -1)
            acc_type = _VEC_TYPES[flat.shape[1]]
        flat = np.ascontiguousarray(flat, dtype=flat.dtype.newbyteorder("<"))
        raw = flat.view(np.uint8).reshape(n, -1)
        stride = None
        if kind == "vertex":
            # Vertex attribute elements must start on 4-byte boundaries.
            stride = -(-raw.shape[1] // 4) * 4
            if stride != raw.shape[1]:
                padded = np.zeros((n, stride), dtype=np.uint8)
                padded[:, : raw.shape[1]] = raw
                raw = padded
        view = self.view(raw.reshape(-1).data, kind, block, target=target, stride=stride)
        accessor = g.Accessor(
            bufferView=view, byteOffset=None, componentType=component, normalized=normalized or None,
            count=n, type=acc_type, name=name,
        )
        if minmax:
            accessor.min = flat.min(axis=0).astype(np.float64).tolist()
            accessor.max = flat.max(axis=0).astype(np.float64).tolist()
        self.gltf.accessors.append(accessor)
        return len(self.gltf.accessors) - 1

    def blob(self) -> list:
        """The buffer's pieces, padded to a multiple of 4 bytes."""
        return self.chunks + [b"\0" * (-self.length % 4)]


def _pack_glb(gltf: g.GLTF2, blob: list, bin_bytes: int) -> tuple[list, int]:
    # pygltflib's own GLB writer drops empty values everywhere, extras included ("unit": "",
    # "warnings": []); this keeps extras and extensions exactly as given.
    doc = _prune(g.gltf_asdict(gltf))
    text = json.dumps(doc, allow_nan=False, separators=(",", ":")).encode("utf-8")
    text += b" " * (-len(text) % 4)
    chunks = [struct.pack("<I4s", len(text), b"JSON"), text]
    if bin_bytes:
        chunks += [struct.pack("<I4s", bin_bytes, b"BIN\0"), *blob]
    total = 12 + sum(len(c) for c in chunks)
    return [struct.pack("<4sII", b"glTF", 2, total), *chunks], len(text)


def _prune(value):
    """Drop None and empty values of pygltflib's dict form, leaving extras/extensions untouched."""
    if isinstance(value, dict):
        out = {}
        for key, item in value.items():
            if key not in ("extras", "extensions"):
                item = _prune(item)
            if item is None or (isinstance(item, (dict, list, str)) and not item):
                continue
            out[key] = item
        return out
    if isinstance(value, list):
        return [_prune(item) for item in value]
    return value


def _check_attribute_keys(asset: BakedAsset) -> None:
    meshes = asset.scene.meshes
    for i, j in asset.vertex_attributes:
        if not (0 <= i < len(meshes) and 0 <= j < len(meshes[i].primitives)):
            raise ValueError(f"vertex_attributes refer to mesh {i} primitive {j}, which the scene lacks")


def _primitive_attributes(packer: _Packer, prim, attrs: tuple[VertexAttribute, ...], where: str) -> dict[str, int]:
    n = len(prim.positions)
    out: dict[str, int] = {}

    positions = np.asarray(prim.positions, dtype=np.float64)
    check_finite(positions, f"{where}: POSITION")
    out["POSITION"] = packer.accessor(positions.astype(np.float32), FLOAT, False, "vertex", "POSITION",
                                      ARRAY_BUFFER, minmax=True)
    if prim.normals is not None:
        normals = np.asarray(prim.normals, dtype=np.float64)
        check_finite(normals, f"{where}: NORMAL")
        length = np.linalg.norm(normals, axis=1, keepdims=True)
        if np.any(length == 0.0):
            raise ValueError(f"{where}: NORMAL has zero-length vectors")
        out["NORMAL"] = packer.accessor((normals / length).astype(np.float32), FLOAT, False, "vertex", "NORMAL",
                                        ARRAY_BUFFER)
    if prim.tangents is not None:
        tangents = np.asarray(prim.tangents, dtype=np.float64)
        if tangents.shape != (n, 4):
            raise ValueError(f"{where}: TANGENT has shape {tangents.shape}, expected ({n}, 4)")
        check_finite(tangents, f"{where}: TANGENT")
        length = np.linalg.norm(tangents[:, :3], axis=1, keepdims=True)
        if np.any(length == 0.0):
            raise ValueError(f"{where}: TANGENT has zero-length vectors")
        # The validator wants unit xyz and w exactly ±1; float64 data read from files is near both.
        stored = np.column_stack([tangents[:, :3] / length, np.where(tangents[:, 3] < 0.0, -1.0, 1.0)])
        out["TANGENT"] = packer.accessor(stored.astype(np.float32), FLOAT, False, "vertex", "TANGENT", ARRAY_BUFFER)
    for t, uv in enumerate(prim.uvs):
        name = f"TEXCOORD_{t}"
        uv = np.asarray(uv, dtype=np.float64)
        check_finite(uv, f"{where}: {name}")
        out[name] = packer.accessor(uv.astype(np.float32), FLOAT, False, "vertex", name, ARRAY_BUFFER)
    if prim.colors is not None:
        colors = np.asarray(prim.colors, dtype=np.float64)
        check_finite(colors, f"{where}: COLOR_0")
        out["COLOR_0"] = packer.accessor(colors.astype(np.float32), FLOAT, False, "vertex", "COLOR_0", ARRAY_BUFFER)

    for attr in attrs:
        name = attr.gltf_name
        if name in out:
            raise ValueError(f"{where}: attribute {name} given twice")
        data = np.asarray(attr.data, dtype=np.float64)
        if data.ndim not in (1, 2) or len(data) != n or (data.ndim == 2 and not 1 <= data.shape[1] <= 4):
            raise ValueError(f"{where}: attribute {name} has shape {data.shape}, expected ({n},) or ({n}, 1..4)")
        check_finite(data, f"{where}: attribute {name}")
        if attr.encoding not in ENCODINGS:
            raise ValueError(f"{where}: attribute {name} has unknown encoding {attr.encoding!r}")
        component, _, normalized = ENCODINGS[attr.encoding]
        try:
            stored = quantize(data, attr.encoding)
        except ValueError as exc:
            raise ValueError(f"{where}: attribute {name}: {exc}") from None
        out[name] = packer.accessor(stored, component, normalized, "vertex", name, ARRAY_BUFFER)
    return out


def _indices(packer: _Packer, faces: np.ndarray, n: int, where: str) -> int:
    faces = np.asarray(faces)
    if faces.size and (faces.min() < 0 or faces.max() >= n):
        raise ValueError(f"{where}: face indices outside [0, {n})")
    # 65535 is the primitive-restart value of uint16, so uint16 only below 65536 vertices.
    if n < 65536:
        return packer.accessor(faces.reshape(-1).astype(np.uint16), UNSIGNED_SHORT, False, "index", "indices",
                               ELEMENT_ARRAY_BUFFER)
    return packer.accessor(faces.reshape(-1).astype(np.uint32), UNSIGNED_INT, False, "index", "indices",
                           ELEMENT_ARRAY_BUFFER)


def _texture_extensions(ref: TextureRef) -> dict:
    """A slot's KHR_texture_transform as read from the source, written back unchanged."""
    return {TEXTURE_TRANSFORM: ref.transform.to_json()} if ref.transform is not None else {}


def _texture_info(ref: TextureRef | None) -> g.TextureInfo | None:
    if ref is None:
        return None
    return g.TextureInfo(index=ref.texture, texCoord=ref.tex_coord, extensions=_texture_extensions(ref))


def _material(src: SourceMaterial, scattering: ScatteringMaterial | None) -> tuple[g.Material, list[str]]:
    """The glTF material (`_material_json`) and the extensions it uses; a scattering one also gets
    its `EXTENSION` object (scattering material in 1/mm, source name)."""
    material, extensions = _material_json(src, scattering)
    if scattering is not None:
        material.extensions[EXTENSION] = {
            "schemaVersion": SCHEMA_VERSION,
            "material": {**scattering.material.to_json(), "units": "1/mm"},
            "sourceName": scattering.source_name,
        }
        transmit = np.asarray(scattering.fallback.slab_transmittance, dtype=np.float64)
        if np.any(transmit > 0):
            # whole, where KHR_materials_diffuse_transmission carries it only in part (bake/fallback.py)
            check_finite(transmit, f"material {src.name!r} slab_transmittance")
            material.extensions[EXTENSION]["slabTransmittance"] = transmit.tolist()
        extensions = extensions + [EXTENSION]
    slots = (material.pbrMetallicRoughness.baseColorTexture, material.pbrMetallicRoughness.metallicRoughnessTexture,
             material.normalTexture, material.occlusionTexture, material.emissiveTexture)
    if any(slot is not None and TEXTURE_TRANSFORM in (slot.extensions or {}) for slot in slots):
        extensions = extensions + [TEXTURE_TRANSFORM]
    return material, extensions


def _material_json(src: SourceMaterial, scattering: ScatteringMaterial | None) -> tuple[g.Material, list[str]]:
    pbr = g.PbrMetallicRoughness(
        baseColorFactor=[float(c) for c in src.base_color_factor],
        metallicFactor=float(src.metallic_factor),
        roughnessFactor=float(src.roughness_factor),
        baseColorTexture=_texture_info(src.base_color_texture),
        metallicRoughnessTexture=_texture_info(src.metallic_roughness_texture),
    )
    material = g.Material(
        name=src.name or None,
        pbrMetallicRoughness=pbr,
        normalTexture=None if src.normal_texture is None else g.NormalMaterialTexture(
            index=src.normal_texture.texture, texCoord=src.normal_texture.tex_coord,
            extensions=_texture_extensions(src.normal_texture)),
        occlusionTexture=None if src.occlusion_texture is None else g.OcclusionTextureInfo(
            index=src.occlusion_texture.texture, texCoord=src.occlusion_texture.tex_coord,
            extensions=_texture_extensions(src.occlusion_texture)),
        emissiveFactor=[float(c) for c in src.emissive_factor],
        emissiveTexture=_texture_info(src.emissive_texture),
        doubleSided=bool(src.double_sided),
    )
    if scattering is None:
        if src.ior is None:
            return material, []
        material.extensions = {"KHR_materials_ior": {"ior": finite_number(src.ior, f"material {src.name!r} ior")}}
        return material, ["KHR_materials_ior"]

    fb = scattering.fallback
    what = f"material {src.name!r} fallback"
    for field in ("base_color", "attenuation_color", "diffuse_transmission_color"):
        check_finite(np.asarray(getattr(fb, field), dtype=np.float64), f"{what} {field}")
    if not (scattering.keep_base_color_texture and src.base_color_texture is not None):
        pbr.baseColorFactor = [float(c) for c in fb.base_color] + [1.0]
        pbr.baseColorTexture = None
    # Scattering happens only in dielectrics; glTF's default metallicFactor is 1.
    pbr.metallicFactor = 0.0
    material.doubleSided = False
    volume: dict = {"thicknessFactor": finite_number(fb.thickness_factor, f"{what} thickness_factor")}
    if fb.thickness_texture is not None:
        volume["thicknessTexture"] = {"index": fb.thickness_texture.texture, "texCoord": fb.thickness_texture.tex_coord}
    # attenuationDistance defaults to +inf (no attenuation), which JSON cannot hold.
    if not math.isinf(fb.attenuation_distance):
        volume["attenuationDistance"] = finite_number(fb.attenuation_distance, f"{what} attenuation_distance")
    volume["attenuationColor"] = [float(c) for c in fb.attenuation_color]
    material.extensions = {
        "KHR_materials_transmission": {
            "transmissionFactor": finite_number(fb.transmission_factor, f"{what} transmission_factor")},
        "KHR_materials_volume": volume,
        "KHR_materials_diffuse_transmission": {
            "diffuseTransmissionFactor": finite_number(fb.diffuse_transmission_factor,
                                                        f"{what} diffuse_transmission_factor"),
            "diffuseTransmissionColorFactor": [float(c) for c in fb.diffuse_transmission_color],
        },
        "KHR_materials_ior": {"ior": finite_number(fb.ior, f"{what} ior")},
    }
    return material, list(TRANSLUCENT_EXTENSIONS)


def _volume_scatter(material: g.Material, record: dict, what: str) -> list[str]:
    """Put `record` (`engine_materials.khr_materials_volume_scatter`) on the translucent `material`:
    `VOLUME_SCATTER`'s ``multiscatterColor`` (also as ``multiscatterColorFactor``) and
    ``scatterAnisotropy``, and its ``attenuationColor``
    and ``attenuationDistance`` in place of the fallback's in ``KHR_materials_volume`` (thickness
    kept). The draft reads that attenuation as the extinction σ_t = −ln(colour) / distance, which
    only sssbake's σ'_t makes its medium sssbake's; a viewer without the draft reads it as absorption
    (darker thin parts than the fallback's σ_tr). Returns the extension names it adds.
    """
    volume = material.extensions["KHR_materials_volume"]
    colour = np.asarray(record["attenuationColor"], dtype=np.float64)
    multiscatter = np.asarray(record["multiscatterColor"], dtype=np.float64)
    check_finite(colour, f"{what} {VOLUME_SCATTER} attenuationColor")
    check_finite(multiscatter, f"{what} {VOLUME_SCATTER} multiscatterColor")
    volume["attenuationDistance"] = finite_number(record["attenuationDistance"],
                                                  f"{what} {VOLUME_SCATTER} attenuationDistance")
    volume["attenuationColor"] = colour.tolist()
    # The draft's name for the colour is not settled: glTF-Transform (PR 2453) writes
    # multiscatterColor, Babylon.js 9.28's loader reads multiscatterColorFactor (glTF's factor/texture
    # naming) and takes black without it. Both carry the same values.
    material.extensions[VOLUME_SCATTER] = {
        "multiscatterColor": multiscatter.tolist(),
        "multiscatterColorFactor": multiscatter.tolist(),
        "scatterAnisotropy": finite_number(record["scatterAnisotropy"], f"{what} {VOLUME_SCATTER} scatterAnisotropy"),
    }
    return [VOLUME_SCATTER]


def _asset_extras(asset: BakedAsset, packer: _Packer) -> dict:
    reserved = {"schemaVersion", "scaleMm", "attributes"}
    clash = reserved & set(asset.extras)
    if clash:
        raise ValueError(f"BakedAsset.extras must not set {sorted(clash)}; the exporter writes them")
    extras = {"schemaVersion": SCHEMA_VERSION, **_json_value(asset.extras, packer, "extras", "sssbake/asset")}

    meshes = asset.scene.meshes
    names = [m.name for m in meshes]
    scale = {}
    for i, value in sorted(asset.scale_mm.items()):
        # Mesh names need not be unique; a repeated name is qualified by the mesh index.
        key = names[i] if names.count(names[i]) == 1 else f"{names[i]}#{i}"
        scale[key] = finite_number(value, f"scale_mm of mesh {names[i]!r}")
    extras["scaleMm"] = scale

    described: dict[str, dict] = {}
    for _, attrs in sorted(asset.vertex_attributes.items()):
        for attr in attrs:
            entry = {"name": attr.gltf_name, "key": attr.key, "unit": attr.unit, "encoding": attr.encoding,
                     "description": attr.description}
            if described.setdefault(attr.gltf_name, entry) != entry:
                raise ValueError(f"attribute {attr.gltf_name} is described differently on different primitives")
    extras["attributes"] = list(described.values())
    return extras


def _mesh_extension(asset: BakedAsset, i: int, prims: list[g.Primitive], packer: _Packer) -> dict:
    """Mesh `i`'s `EXTENSION` object: scale, ``vertexCounts`` (POSITION count per primitive),
    ``attributeTypes`` (accessor type of each ``_`` attribute) and its technique data."""
    mesh = asset.scene.meshes[i]
    ext: dict = {"schemaVersion": SCHEMA_VERSION}
    if i in asset.scale_mm:
        ext["scaleMm"] = finite_number(asset.scale_mm[i], f"scale_mm of mesh {mesh.name!r}")
    ext["vertexCounts"] = [len(p.positions) for p in mesh.primitives]
    types: dict[str, str] = {}
    for j, prim in enumerate(prims):
        for name, index in vars(prim.attributes).items():
            if not name.startswith("_") or index is None:
                continue
            acc_type = packer.gltf.accessors[index].type
            if types.setdefault(name, acc_type) != acc_type:
                raise ValueError(f"mesh {mesh.name!r}: attribute {name} is {types[name]} on one primitive and "
                                 f"{acc_type} on primitive {j}")
    ext["attributeTypes"] = dict(sorted(types.items()))
    _technique_extras(ext, asset.mesh_extras.get(i, {}), packer, f"mesh {mesh.name!r} extras", f"mesh{i}")
    return ext


def _technique_extras(sssbake: dict, data: dict, packer: _Packer, where: str, owner: str) -> None:
    """Add a mesh's or material's technique data to its `EXTENSION` object (arrays become tables
    named ``sssbake/<owner>/<key path>``)."""
    clash = sorted(set(data) & set(sssbake))
    if clash:
        raise ValueError(f"{where} use reserved keys {clash}")
    sssbake.update(_json_value(data, packer, where, f"sssbake/{owner}"))


def _json_value(value, packer: _Packer, where: str, name: str):
    """`value` as JSON; numpy arrays become table accessors named `name` plus their key path and
    are replaced by their table reference."""
    if isinstance(value, dict):
        return {str(k): _json_value(v, packer, f"{where}.{k}", f"{name}/{k}") for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_json_value(v, packer, f"{where}[{i}]", f"{name}/{i}") for i, v in enumerate(value)]
    if isinstance(value, np.ndarray) and value.ndim > 0:
        return _table(value, packer, where, name)
    if isinstance(value, (np.generic, np.ndarray)):
        value = value.item()
    if isinstance(value, float) and not math.isfinite(value):
        raise ValueError(f"{where} is not finite: {value}")
    return value


#: Integer table dtypes stored as they are; other integer dtypes become UNSIGNED_INT.
_TABLE_COMPONENTS = {np.dtype(np.uint8): UNSIGNED_BYTE, np.dtype(np.int8): BYTE,
                     np.dtype(np.uint16): UNSIGNED_SHORT, np.dtype(np.int16): SHORT}


def table_dtype(dtype: np.dtype) -> np.dtype:
    """The dtype a table of `dtype` is stored at in a .glb (`_table`): floats as float32, (u)int8
    and (u)int16 as they are, other integers as uint32; what the table costs a runtime, whatever
    the container (USD keeps integers as int[])."""
    dtype = np.dtype(dtype)
    if dtype.kind == "f":
        return np.dtype(np.float32)
    return dtype if dtype in _TABLE_COMPONENTS else np.dtype(np.uint32)


def _table(array: np.ndarray, packer: _Packer, where: str, name: str) -> dict:
    """Write a table as accessor `name` (float -> FLOAT, (u)int8/(u)int16 as they are, other
    non-negative integers -> UNSIGNED_INT) and return its table reference.

    Shapes (n,), (n, k) with k <= 4, and (n, k, k) with k in 2..4 (MATk) are accepted.
    """
    shape_ok = (
        array.ndim == 1
        or (array.ndim == 2 and 1 <= array.shape[1] <= 4)
        or (array.ndim == 3 and array.shape[1] == array.shape[2] and array.shape[1] in _MAT_TYPES)
    )
    if not shape_ok or len(array) == 0:
        raise ValueError(f"{where}: a table must have shape (n,), (n, 1..4) or (n, k, k) with k in 2..4 "
                         f"and n > 0, got {array.shape}")
    if array.dtype.kind == "f":
        check_finite(array, where)
    elif array.dtype.kind not in "iu" or (array.dtype not in _TABLE_COMPONENTS and not (
            array.min() >= 0 and array.max() <= np.iinfo(np.uint32).max)):
        raise ValueError(f"{where}: a table must hold floats or integers in [0, 2^32), got dtype {array.dtype}")
    dtype = table_dtype(array.dtype)
    stored = array.astype(dtype, copy=False)
    component = next(c for c, d in COMPONENT_DTYPES.items() if np.dtype(d) == dtype)
    index = packer.accessor(stored, component, False, "table", "tables", name=name)
    acc = packer.gltf.accessors[index]
    # The elements in glTF's order (MATk column-major), as a reader gets them back.
    elements = stored.transpose(0, 2, 1) if stored.ndim == 3 else stored
    return {"accessor": index, "name": name, "count": acc.count, "type": acc.type, "componentType": component,
            "crc32": table_crc32(elements.reshape(len(stored), -1))}
