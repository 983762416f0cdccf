"""OpenUSD (.usdc) export of a BakedAsset: geometry, materials and sssbake data, with typed primvars.

Layout of the file (one crate file, plus its thickness textures as PNG files next to it):

- stage metadata ``upAxis`` (the scene's), ``metersPerUnit`` (see `meters_per_unit`),
  ``defaultPrim`` = ``/<Root>``, an Xform of kind ``component`` named after the file stem, and
  ``customLayerData.creator`` = ``"sssbake <version>"``;
- the node hierarchy as Xforms under the root, each with one ``xformOp:transform`` when its matrix
  is not the identity (the node matrix transposed: USD multiplies row vectors), at most
  `MAX_USD_DEPTH` node levels deep: a node deeper than that is written beside its ancestor at that
  level (a child of the same Xform), its matrix the product of the matrices from that ancestor
  down to it, so every node keeps its world transform (up to the rounding of the products' order);
- each primitive of a node's mesh as a ``UsdGeom.Mesh`` child of the node's Xform (named after the
  mesh, ``<mesh>_<j>`` when it has several primitives; a mesh used by several nodes is written
  under each): points, faceVertexCounts (all 3), faceVertexIndices, normals (vertex
  interpolation), extent, subdivisionScheme ``none``, ``primvars:st``, ``primvars:st1``, ... from
  TEXCOORD_0, 1, ... (v flipped back to USD's bottom-up convention), displayColor/displayOpacity
  from the vertex colours, and ``sss:scaleMm`` (double, mm per file unit) when the asset has it;
- each `VertexAttribute` as a vertex-interpolated primvar (`VertexAttribute.usd_name`) of the
  type `primvar_layout` chooses: typed vectors (``float2[]``, ``float3[]``, ``normal3f[]`` for a
  key ending in ``normal``) rather than ``elementSize``, which Blender's importer zeroes; 8-bit
  integer codes as ``uchar[]``; two to four 8-bit codes, or two 16-bit ones, packed little-end
  first into one ``int`` (USD has no 16-bit integers), the same bytes as glTF's accessor. Its
  customData: ``unit``, ``description``, ``encoding`` (glTF's), ``components``, ``gltfName`` and,
  when packed, ``packedBits``; `primvar_values` decodes it to what a glTF reader gets;
- materials under ``/<Root>/Materials``: a Material with a UsdPreviewSurface (``PreviewSurface``),
  bound with the MaterialBindingAPI. A translucent material's surface carries the fallback's
  diffuseColor, roughness, ior and opacity 1; diffuse transmission and volume attenuation have no
  UsdPreviewSurface input, so they stay ``sss:fallback:*`` attributes and the Material's
  customData ``sssbake:previewSurface`` says so. Its thickness texture is a ``UsdUVTexture``
  (``ThicknessTexture``: ``file`` = ``@./<stem>.thickness<k>.png@``, raw colour space, ``scale``
  = thicknessFactor so ``outputs:g`` is the thickness in file units) reading ``st`` from a
  ``UsdPrimvarReader_float2`` of the atlas UV set, wired to the Material output
  ``outputs:sss:thickness``. The ``sss:`` attributes of `_scattering_attributes` include the
  OpenPBR subsurface parameters (``sss:openpbr:*``); usd-core has no MaterialX (no ``UsdMtlx``,
  no ``ND_open_pbr_surface_surfaceshader`` in its Sdr registry, so UsdValidation refuses such a
  shader), so no OpenPBR shader is authored. Where the bake writes the asset's OpenPBR MaterialX
  document (``<stem>.mtlx``, `exporters.mtlx`) each Material prim names it: ``sss:materialx`` =
  ``@./<stem>.mtlx@`` (asset) and ``sss:materialx:material`` (string), its surfacematerial there, the
  prim's own name (`material_prim_names`); a reference would not resolve in usd-core (no ``.mtlx``
  file format);
- on the root prim ``sss:schemaVersion`` and ``sss:extras`` (`BakedAsset.extras` as a JSON
  string); on each Mesh prim of a mesh with `BakedAsset.mesh_extras` its own ``sss:extras``; on
  each translucent Material prim with `BakedAsset.material_extras` its own ``sss:extras``. Numpy
  arrays in them become array attributes of the prim named by their keys (``sss:prt:directions``,
  ``sss:screen:offsets``): float tables typed by shape (``float3[]``, ``matrix4d[]``), integer ones
  ``int[]`` (compressed on disk), each with its shape and dtype in customData (`_table`);
  the JSON holds ``{"attribute": name, "shape": [...], "crc32": "<8 hex>"}`` in their place, and
  names primvars (``primvars:sss:prt:ref``) where the glTF JSON names vertex attributes
  (``_SSS_PRT_REF``).

`technique_tables` and `technique_data` read it back, refusing stale tables (`StaleDataError`).
Everything is float32 except matrices and ``sss:scaleMm`` (double).
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import re
import unicodedata
from pathlib import Path

import numpy as np
from pxr import Gf, Kind, Sdf, Usd, UsdGeom, UsdShade, Vt

from sssbake.exporters.atomic import atomic_path
from sssbake.exporters.finite import check_finite, finite_number
from sssbake.exporters.gltf import ENCODINGS, dequantize, generator, quantize, table_crc32
from sssbake.pipeline.core.errors import StaleDataError
from sssbake.pipeline.core.engine_materials import openpbr_subsurface
from sssbake.pipeline.mesh.baked import (
    SCHEMA_VERSION,
    BakedAsset,
    ScatteringMaterial,
    VertexAttribute,
    check_material_references,
)
from sssbake.pipeline.mesh.scene import Primitive, Scene, SourceMaterial, Texture, TextureRef

#: Prefix of every sssbake attribute and primvar namespace.
SSS = "sss:"
MATERIALS_SCOPE = "Materials"
SHADER_NAME = "PreviewSurface"
THICKNESS_TEXTURE = "ThicknessTexture"
THICKNESS_READER = "ThicknessUV"
#: The Material output the thickness texture (file units) is wired to.
THICKNESS_OUTPUT = SSS + "thickness"
FACE_BLOCKS = ("faceVertexCounts", "faceVertexIndices")
#: The Material prim attribute naming the asset's OpenPBR MaterialX document (`materialx_file`).
MATERIALX = SSS + "materialx"
#: What a Material's customData says UsdPreviewSurface cannot carry.
PREVIEW_SURFACE_NOTE = ("UsdPreviewSurface has no diffuse transmission and no volume attenuation "
                        "(glTF KHR_materials_diffuse_transmission, KHR_materials_volume): they are the "
                        "sss:fallback:* attributes; outputs:sss:thickness is the baked thickness (file units)")
_T = Sdf.ValueTypeNames
#: Float vector types by component count; Blender's importer keeps float[], float2[], float3[].
_FLOAT_TYPES = {1: _T.FloatArray, 2: _T.Float2Array, 3: _T.Float3Array, 4: _T.Float4Array}
_WRAPS = {33071: "clamp", 33648: "mirror", 10497: "repeat"}
#: Deepest node hierarchy written (levels of node Xforms under the root prim). A prim path holds one
#: name per level, and usd-core's crate writer spends time growing with the square of a path's depth
#: on each prim: a 2,000-node chain took 4.4 s to save and an 8,000-node one about 10 minutes, a
#: 100,000-node chain cut at 64 levels 0.8 s (benchmarks/README.md, "Deep node hierarchies in USD").
#: Rigs and CAD assemblies nest a few dozen levels; deeper ones keep their world transforms.
MAX_USD_DEPTH = 64


def meters_per_unit(asset: BakedAsset) -> float:
    """The ``metersPerUnit`` the stage declares.

    The scene's own claim when it has one (what the source file said, as read); otherwise the
    asset's ``scale_mm`` of the lowest mesh index / 1000 (node scale included, so exact only for
    assets whose meshes share one scale); otherwise 1 (glTF's metres).
    """
    if asset.scene.meters_per_unit is not None:
        return finite_number(asset.scene.meters_per_unit, "scene meters_per_unit")
    if asset.scale_mm:
        first = min(asset.scale_mm)
        return finite_number(asset.scale_mm[first], f"scale_mm of mesh {first}") / 1000.0
    return 1.0


def mm_per_unit(asset: BakedAsset) -> float:
    """Millimetres per file unit of the stage (`meters_per_unit` × 1000): the unit the .usdc's
    scattering attributes, the .mtlx and the materials JSON give lengths in."""
    return meters_per_unit(asset) * 1000.0


def thickness_texture_files(asset: BakedAsset, stem: str) -> dict[int, str]:
    """Texture index -> file name (``<stem>.thickness<k>.png``, k in order of first use) of every
    thickness texture a translucent material uses: what `write_usdc` writes next to the .usdc.

    The .usdc references them by name, and a USD asset path holds neither control characters nor
    bytes that are not UTF-8 (a POSIX file name may): in a `stem` with any, those characters and
    every ``%`` are written ``%XX``, byte by byte (``a%0Ab`` for ``a`` newline ``b``).
    """
    stem = _asset_stem(stem)
    out: dict[int, str] = {}
    for m in sorted(asset.scattering):
        ref = asset.scattering[m].fallback.thickness_texture
        if ref is not None and ref.texture not in out:
            image = asset.scene.images[asset.scene.textures[ref.texture].image]
            suffix = ".jpg" if image.mime_type == "image/jpeg" else ".png"
            out[ref.texture] = f"{stem}.thickness{len(out)}{suffix}"
    return out


def materialx_file(stem: str) -> str:
    """The name of the OpenPBR MaterialX document next to a .usdc of file stem `stem`:
    ``<stem>.mtlx``, `stem` escaped as in `thickness_texture_files` (the .usdc names it in an asset path)."""
    return _asset_stem(stem) + ".mtlx"


def _asset_stem(stem: str) -> str:
    """`stem` as a USD asset path can hold it: if it has control characters or bytes that are not
    UTF-8, those and every ``%`` written ``%XX`` byte by byte (`thickness_texture_files`)."""
    if any(_refused_in_asset_path(c) for c in stem):
        stem = "".join("".join(f"%{b:02X}" for b in os.fsencode(c)) if c == "%" or _refused_in_asset_path(c) else c
                       for c in stem)
    return stem


def _refused_in_asset_path(c: str) -> bool:
    # Cc: the C0 and C1 controls and DEL (Sdf.AssetPath refuses them); Cs: a byte that is not UTF-8,
    # as os.fsdecode's surrogate escape holds it (not UTF-8, so not a USD string)
    return unicodedata.category(c) in ("Cc", "Cs")


def to_stage(asset: BakedAsset, root_name: str = "Root",
             texture_files: dict[int, str] | None = None, materialx: str | None = None) -> tuple[Usd.Stage, dict]:
    """Build `asset` as an in-memory stage.

    Parameters
    ----------
    asset : BakedAsset
    root_name : str
        Name of the default prim; made a valid USD identifier.
    texture_files : dict of int to str, optional
        Texture index -> file name next to the .usdc (`thickness_texture_files`); a thickness
        texture not listed gets no UsdUVTexture (nothing is written to disk here).
    materialx : str, optional
        File name of the asset's OpenPBR MaterialX document next to the .usdc (`materialx_file`,
        written by `exporters.mtlx.write_mtlx`): each Material prim then names it in
        ``sss:materialx`` and its material in it in ``sss:materialx:material``.

    Returns
    -------
    stage : Usd.Stage
        Anonymous in-memory stage.
    summary : dict
        ``vertices``, ``faces`` (written Mesh prims, instances counted each time), ``blocks``
        {block name: bytes} (``points``, ``normals``, ``primvars:st``, ``primvars:sss:<key>``,
        ..., ``faceVertexCounts``, ``faceVertexIndices``: value bytes before the crate format's
        compression, summed over Mesh prims), ``bytes_per_vertex`` {vertex block name: bytes /
        vertices of the Mesh prims that carry it; ``total``: all vertex blocks / all vertices;
        ``sssbake``: ``primvars:sss:*`` / all vertices}.

    Raises
    ------
    ValueError
        Non-finite data (or beyond float32), a primvar whose element count is not the points',
        integer data out of its encoding's range, face indices out of range, attributes or
        scattering for meshes, primitives or materials the scene lacks.
    """
    scene = asset.scene
    _check_references(asset)
    stage = Usd.Stage.CreateInMemory()
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.z if scene.up_axis.upper() == "Z" else UsdGeom.Tokens.y)
    UsdGeom.SetStageMetersPerUnit(stage, meters_per_unit(asset))
    stage.SetMetadata("customLayerData", {"creator": generator()})

    root_path = Sdf.Path.absoluteRootPath.AppendChild(_identifier(root_name, "Root"))
    root = UsdGeom.Xform.Define(stage, root_path).GetPrim()
    stage.SetDefaultPrim(root)
    Usd.ModelAPI(root).SetKind(Kind.Tokens.component)
    _string_attribute(root, SSS + "schemaVersion", SCHEMA_VERSION)
    every = {a.gltf_name: a.usd_name for attrs in asset.vertex_attributes.values() for a in attrs}
    _string_attribute(root, SSS + "extras", _extras_json(asset.extras, root, "extras", every))

    materials = _materials(stage, root_path.AppendChild(MATERIALS_SCOPE), asset, texture_files or {}, materialx)

    acc = _Accounting()
    for m, mesh_paths in _node_specs(stage, root_path, scene):
        mesh = scene.meshes[m]
        names = {a.gltf_name: a.usd_name for j in range(len(mesh.primitives))
                 for a in asset.vertex_attributes.get((m, j), ())}
        for j, (prim, mesh_path) in enumerate(zip(mesh.primitives, mesh_paths)):
            where = f"mesh {mesh.name!r} primitive {j}"
            usd_mesh = _mesh(stage, mesh_path, prim, asset.vertex_attributes.get((m, j), ()), where, acc)
            if m in asset.scale_mm:
                scale = finite_number(asset.scale_mm[m], f"scale_mm of mesh {mesh.name!r}")
                attribute = usd_mesh.GetPrim().CreateAttribute(SSS + "scaleMm", Sdf.ValueTypeNames.Double, custom=True)
                attribute.Set(scale)
            if m in asset.mesh_extras:
                extras_json = _extras_json(asset.mesh_extras[m], usd_mesh.GetPrim(), f"mesh {mesh.name!r} extras",
                                           names)
                _string_attribute(usd_mesh.GetPrim(), SSS + "extras", extras_json)
            if prim.material is not None:
                src = scene.materials[prim.material]
                if src.double_sided and prim.material not in asset.scattering:
                    usd_mesh.CreateDoubleSidedAttr(True)
                UsdShade.MaterialBindingAPI.Apply(usd_mesh.GetPrim()).Bind(materials[prim.material])
    return stage, acc.summary()


def _node_specs(stage: Usd.Stage, root_path: Sdf.Path, scene: Scene) -> list[tuple[int, list[Sdf.Path]]]:
    """Author the node hierarchy under the root prim: an Xform per node (its transform op included,
    `MAX_USD_DEPTH` applied) and an empty Mesh prim per primitive of its mesh, for `_mesh` to fill.

    Authored as specs in one change block: a prim defined through the Usd API recomposes its
    parent's children, which made N siblings cost O(N²) (100,000 took 15 minutes).

    Returns
    -------
    list of (int, list of Sdf.Path)
        For each node with a mesh, depth first: the mesh index and the paths of its primitives.
    """
    layer = stage.GetRootLayer()
    taken = {root_path: {MATERIALS_SCOPE: 1}}
    placed = []
    with Sdf.ChangeBlock():
        # (node, parent spec, level, the matrices above it composed when it is written past MAX_USD_DEPTH)
        stack = [(r, layer.GetPrimAtPath(root_path), 1, None) for r in reversed(scene.roots)]
        while stack:
            i, parent, level, above = stack.pop()
            node = scene.nodes[i]
            name = _unique(_identifier(node.name, f"node{i}"), taken.setdefault(parent.path, {}))
            spec = Sdf.PrimSpec(parent, name, Sdf.SpecifierDef, "Xform")
            matrix = np.asarray(node.matrix, dtype=np.float64)
            check_finite(matrix, f"node {node.name!r} matrix")
            if above is not None:
                matrix = above @ matrix
                check_finite(matrix, f"node {node.name!r} matrix composed with its ancestors' past level "
                                     f"{MAX_USD_DEPTH}")
            if not np.array_equal(matrix, np.eye(4)):
                _transform_op(spec, matrix)
            if node.mesh is not None:
                mesh, mine, mesh_paths = scene.meshes[node.mesh], taken.setdefault(spec.path, {}), []
                for j in range(len(mesh.primitives)):
                    prim_name = mesh.name if len(mesh.primitives) == 1 else f"{mesh.name}_{j}"
                    mesh_name = _unique(_identifier(prim_name, f"mesh{node.mesh}_{j}"), mine)
                    mesh_paths.append(Sdf.PrimSpec(spec, mesh_name, Sdf.SpecifierDef, "Mesh").path)
                placed.append((node.mesh, mesh_paths))
            if level < MAX_USD_DEPTH:
                stack.extend((c, spec, level + 1, None) for c in reversed(node.children))
            else:  # the children join this node's parent, with this node's (composed) matrix before their own
                stack.extend((c, parent, level + 1, matrix) for c in reversed(node.children))
    return placed


def _transform_op(spec: Sdf.PrimSpec, matrix: np.ndarray) -> None:
    """What ``UsdGeom.Xformable.AddTransformOp().Set`` authors, as specs: ``xformOp:transform`` =
    `matrix` transposed (USD multiplies row vectors) and ``xformOpOrder``."""
    op = Sdf.AttributeSpec(spec, "xformOp:transform", _T.Matrix4d)
    op.default = Gf.Matrix4d(matrix.T.tolist())
    order = Sdf.AttributeSpec(spec, "xformOpOrder", _T.TokenArray, Sdf.VariabilityUniform)
    order.default = Vt.TokenArray(["xformOp:transform"])


def write_usdc(asset: BakedAsset, path: str | os.PathLike, materialx: str | None = None) -> dict:
    """Write `asset` to `path` (.usdc) and its thickness textures next to it, each atomically, the
    .usdc last: on any error the .usdc is left as it was and no temporary file remains.

    The default prim is named after the file stem (made a valid identifier); the textures are
    `thickness_texture_files`, referenced by relative asset paths. `materialx`: the file name of
    the OpenPBR MaterialX document the caller writes next to it (`materialx_file`, `to_stage`).

    Returns
    -------
    dict
        ``path``, ``bytes`` (file size), ``textures`` (paths of the texture files written) and
        `to_stage`'s summary.
    """
    path = Path(path)
    files = thickness_texture_files(asset, path.stem)
    stage, summary = to_stage(asset, path.stem, files, materialx)
    with contextlib.ExitStack() as stack:
        # entered first, renamed last: a new .usdc never appears without its textures
        usdc = stack.enter_context(atomic_path(path))
        for texture, name in files.items():
            tmp = stack.enter_context(atomic_path(path.with_name(name)))
            tmp.write_bytes(asset.scene.images[asset.scene.textures[texture].image].data)
        # as bytes: USD takes any POSIX name so, while a str must be UTF-8 (os.fsdecode's escapes are not)
        if not stage.GetRootLayer().Export(os.fsencode(usdc)):
            raise OSError(f"USD could not write {usdc}")
    textures = [str(path.with_name(name)) for name in files.values()]
    return {"path": str(path), "bytes": path.stat().st_size, "textures": textures, **summary}


class _Accounting:
    """Value bytes per data block and the vertex counts behind bytes-per-vertex figures."""

    def __init__(self) -> None:
        self.blocks: dict[str, int] = {}
        self.block_vertices: dict[str, int] = {}
        self.vertices = 0
        self.faces = 0

    def add(self, block: str, values: np.ndarray, vertices: int) -> None:
        self.blocks[block] = self.blocks.get(block, 0) + values.nbytes
        if block not in FACE_BLOCKS:
            self.block_vertices[block] = self.block_vertices.get(block, 0) + vertices

    def summary(self) -> dict:
        vertex = {b: n for b, n in self.blocks.items() if b not in FACE_BLOCKS}
        per_vertex = {b: vertex[b] / self.block_vertices[b] for b in vertex if self.block_vertices[b]}
        n = self.vertices
        per_vertex["total"] = sum(vertex.values()) / n if n else 0.0
        per_vertex["sssbake"] = sum(v for b, v in vertex.items() if b.startswith("primvars:" + SSS)) / n if n else 0.0
        return {"vertices": n, "faces": self.faces, "blocks": dict(self.blocks), "bytes_per_vertex": per_vertex}


def primvar_layout(attr: VertexAttribute, data: np.ndarray, what: str
                   ) -> tuple[Sdf.ValueTypeName, np.ndarray, int, dict]:
    """How one vertex attribute is stored as a USD primvar.

    Parameters
    ----------
    attr : VertexAttribute
    data : (n,) or (n, k) float32
        Its finite values.
    what : str
        For error messages.

    Returns
    -------
    type_name : Sdf.ValueTypeName
        ``uchar[]`` (one 8-bit code), ``int[]`` (one 16-bit integer, or 8-bit codes x 2..4 / 16-bit
        x 2 packed: component i in bits [b·i, b·(i+1)) of the value read as uint32), ``normal3f[]``
        (3 components, key ending in ``normal``), else ``float[]``, ``float2[]``, ``float3[]``,
        ``float4[]`` (values; normalized codes that do not pack decoded), ``float[]`` with
        ``elementSize`` k beyond 4 components, or ``int[]`` with ``elementSize`` k for integers
        that do not pack.
    values : (n,) or (n, k) array
        What the primvar holds, one row per vertex.
    element_size : int
        The primvar's elementSize: k for the ``float[]`` / ``int[]`` cases above, else 1.
    meta : dict
        The primvar's customData but ``unit`` and ``description``: ``encoding``, ``components``,
        ``gltfName``, ``packedBits`` when packed.
    """
    k = 1 if data.ndim == 1 else data.shape[1]
    columns = data.reshape(len(data), k).astype(np.float64)
    meta = {"encoding": attr.encoding, "components": k, "gltfName": attr.gltf_name}
    bits = _bits(attr.encoding)
    if bits is None:
        if k == 3 and attr.key.endswith("normal"):
            return _T.Normal3fArray, data, 1, meta
        return (_FLOAT_TYPES[k], data, 1, meta) if k in _FLOAT_TYPES else (_T.FloatArray, data, k, meta)
    codes = _codes(columns, attr.encoding, what)
    if k == 3 and attr.key.endswith("normal"):
        return _T.Normal3fArray, _decode(codes, attr.encoding).astype(np.float32), 1, meta
    if bits == 8 and k == 1:
        return _T.UCharArray, codes[:, 0].astype(np.uint8), 1, meta
    if bits * k <= 32 and k > 1:
        packed = np.zeros(len(codes), dtype=np.uint32)
        for i in range(k):
            packed |= codes[:, i].astype(np.uint32) << np.uint32(bits * i)
        return _T.IntArray, packed.view(np.int32), 1, {**meta, "packedBits": bits}
    if not ENCODINGS[attr.encoding][2]:  # plain integers
        return _T.IntArray, codes.astype(np.int32) if k > 1 else codes[:, 0].astype(np.int32), k, meta
    # normalized values that do not pack: decoded floats, what a glTF reader gets
    decoded = _decode(codes, attr.encoding).astype(np.float32)
    return (_FLOAT_TYPES[k], decoded, 1, meta) if k in _FLOAT_TYPES else (_T.FloatArray, decoded, k, meta)


def _bits(encoding: str) -> int | None:
    """Bits per component of an integer glTF `encoding` (`ENCODINGS`); None for float data."""
    dtype = np.dtype(ENCODINGS[encoding][1]) if encoding in ENCODINGS else None
    return None if dtype is None or dtype.kind == "f" else 8 * dtype.itemsize


def _codes(columns: np.ndarray, encoding: str, what: str) -> np.ndarray:
    """(n, k) unsigned integer codes of `columns` for `encoding` (glTF's `quantize`; signed codes
    two's complement)."""
    try:
        stored = quantize(columns, encoding)
    except ValueError as e:
        raise ValueError(f"{what}: {e}") from None
    return stored.astype(np.int64) % (1 << (8 * stored.dtype.itemsize))


def _decode(codes: np.ndarray, encoding: str) -> np.ndarray:
    """float64 values of unsigned `codes` as glTF decodes `encoding` (`dequantize`)."""
    _, dtype, normalized = ENCODINGS[encoding]
    return dequantize(codes.astype(np.int64).astype(dtype), normalized)


def primvar_values(primvar: UsdGeom.Primvar) -> np.ndarray:
    """(n, k) float64 values of an sssbake primvar as a glTF reader decodes the attribute (normalized
    codes as ``code / MAX``, integers as themselves), unpacking what `primvar_layout` packed.

    Raises
    ------
    StaleDataError
        The primvar's customData no longer describes its values.
    """
    data = primvar.GetAttr().GetCustomData()
    raw = primvar.Get()
    values = np.zeros(0) if raw is None else np.asarray(raw)
    encoding, k = data.get("encoding"), int(data.get("components", 1))
    coded = _bits(encoding) is not None
    if "packedBits" in data and coded:
        bits = int(data["packedBits"])
        unsigned = values.reshape(-1).astype(np.int32).view(np.uint32).astype(np.int64)
        codes = np.stack([(unsigned >> (bits * i)) & ((1 << bits) - 1) for i in range(k)], axis=1)
        return _decode(codes, encoding)
    width = values.shape[1] if values.ndim == 2 else primvar.GetElementSize()
    if width != k or values.size % k:
        raise _stale(primvar.GetAttr().GetPrim(), f"{primvar.GetAttr().GetPath()} has {width} components per "
                                                  f"vertex, its customData says {k}")
    values = values.reshape(-1, k)
    if coded and values.dtype.kind in "iu":
        return _decode(values.astype(np.int64), encoding)
    return values.astype(np.float64)


def _mesh(stage: Usd.Stage, path: Sdf.Path, prim: Primitive, attrs: tuple[VertexAttribute, ...], where: str,
          acc: _Accounting) -> UsdGeom.Mesh:
    positions = _float32(prim.positions, f"{where}: positions")
    n = len(positions)
    if positions.shape != (n, 3):
        raise ValueError(f"{where}: positions have shape {positions.shape}, expected (n, 3)")
    faces = np.asarray(prim.faces)
    if faces.ndim != 2 or faces.shape[1] != 3:
        raise ValueError(f"{where}: faces have shape {faces.shape}, expected (m, 3)")
    if faces.size and (faces.min() < 0 or faces.max() >= n):
        raise ValueError(f"{where}: face indices outside [0, {n})")
    indices = faces.reshape(-1).astype(np.int32)
    counts = np.full(len(faces), 3, dtype=np.int32)

    # Everything is converted and checked before the first attribute is authored.
    primvars: list[tuple[str, Sdf.ValueTypeName, np.ndarray, int | None, dict]] = []
    if prim.normals is not None:
        normals = np.asarray(prim.normals, dtype=np.float64)
        check_finite(normals, f"{where}: normals")
        length = np.linalg.norm(normals, axis=-1, keepdims=True)
        if np.any(length == 0.0):
            raise ValueError(f"{where}: normals have zero-length vectors")
        normals = _float32(normals / length, f"{where}: normals")
    for t, uv in enumerate(prim.uvs):
        uv = _float32(uv, f"{where}: TEXCOORD_{t}")
        if uv.ndim != 2 or uv.shape[1] != 2:
            raise ValueError(f"{where}: TEXCOORD_{t} has shape {uv.shape}, expected (n, 2)")
        flipped = np.column_stack([uv[:, 0], 1.0 - uv[:, 1]]).astype(np.float32)
        primvars.append((uv_primvar(t), Sdf.ValueTypeNames.TexCoord2fArray, flipped, None, {}))
    if prim.colors is not None:
        colors = _float32(prim.colors, f"{where}: colors")
        if colors.ndim != 2 or colors.shape[1] not in (3, 4):
            raise ValueError(f"{where}: colors have shape {colors.shape}, expected (n, 3) or (n, 4)")
        primvars.append(("displayColor", Sdf.ValueTypeNames.Color3fArray, colors[:, :3], None, {}))
        if colors.ndim == 2 and colors.shape[1] == 4:
            primvars.append(("displayOpacity", Sdf.ValueTypeNames.FloatArray, colors[:, 3], None, {}))
    for attr in attrs:
        name = attr.usd_name.removeprefix("primvars:")
        what = f"{where}: attribute {attr.usd_name}"
        if any(name == p[0] for p in primvars):
            raise ValueError(f"{where}: attribute {attr.usd_name} given twice")
        data = _float32(attr.data, what)
        if data.ndim not in (1, 2):
            raise ValueError(f"{what} has shape {data.shape}, expected (n,) or (n, k)")
        if len(data) != n:
            raise ValueError(f"{what} has {len(data)} elements, expected {n} points")
        type_name, values, element_size, meta = primvar_layout(attr, data, what)
        primvars.append((name, type_name, values, element_size if element_size > 1 else None,
                         {"unit": attr.unit, "description": attr.description, **meta}))

    vt_points = Vt.Vec3fArray.FromNumpy(positions)
    vt_normals = None if prim.normals is None else _vt_checked(
        Sdf.ValueTypeNames.Normal3fArray, normals, n, 1, f"{where}: normals")
    checked = [
        (name, type_name, values, _vt_checked(type_name, values, n, size or 1, f"{where}: primvars:{name}"), size, meta)
        for name, type_name, values, size, meta in primvars
    ]

    mesh = UsdGeom.Mesh.Define(stage, path)
    mesh.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
    mesh.CreatePointsAttr(vt_points)
    mesh.CreateFaceVertexCountsAttr(Vt.IntArray.FromNumpy(counts))
    mesh.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(indices))
    lo, hi = (positions.min(axis=0), positions.max(axis=0)) if n else (np.zeros(3, np.float32),) * 2
    mesh.CreateExtentAttr(Vt.Vec3fArray.FromNumpy(np.stack([lo, hi]).astype(np.float32)))
    acc.vertices += n
    acc.faces += len(faces)
    acc.add("points", positions, n)
    acc.add("faceVertexCounts", counts, n)
    acc.add("faceVertexIndices", indices, n)
    if vt_normals is not None:
        mesh.CreateNormalsAttr(vt_normals)
        mesh.SetNormalsInterpolation(UsdGeom.Tokens.vertex)
        acc.add("normals", normals, n)
    api = UsdGeom.PrimvarsAPI(mesh)
    for name, type_name, values, vt_values, size, meta in checked:
        primvar = api.CreatePrimvar(name, type_name, UsdGeom.Tokens.vertex, -1 if size is None else size)
        primvar.Set(vt_values)
        if meta:
            attribute = primvar.GetAttr()
            attribute.SetCustomData(meta)
            if meta["description"]:
                attribute.SetDocumentation(meta["description"])
        acc.add(f"primvars:{name}", values, n)
    return mesh


def uv_primvar(uv_set: int) -> str:
    """The primvar name of TEXCOORD set `uv_set`: ``st``, ``st1``, ..."""
    return "st" if uv_set == 0 else f"st{uv_set}"


def _vt_checked(type_name: Sdf.ValueTypeName, values: np.ndarray, n: int, element_size: int, what: str):
    """`values` as the Vt array of `type_name`, refused unless it holds n × element_size elements."""
    vt = type_name.type.pythonClass.FromNumpy(np.ascontiguousarray(values).reshape(-1) if element_size > 1
                                              else np.ascontiguousarray(values))
    if len(vt) != n * element_size:
        raise ValueError(f"{what} has {len(vt)} elements, expected {n} points × elementSize {element_size} "
                         f"= {n * element_size}")
    return vt


def material_prim_names(materials: tuple[SourceMaterial, ...]) -> list[str]:
    """The prim name of each material under ``/<Root>/Materials``, in order: its name made a valid
    identifier, ``_<k>`` appended to a repeat (the MaterialX document uses the same names)."""
    taken: dict[str, int] = {}
    return [_unique(_identifier(src.name, f"material{m}"), taken) for m, src in enumerate(materials)]


def _materials(stage: Usd.Stage, scope_path: Sdf.Path, asset: BakedAsset,
               texture_files: dict[int, str], materialx: str | None) -> list[UsdShade.Material]:
    scene = asset.scene
    if not scene.materials:
        return []
    UsdGeom.Scope.Define(stage, scope_path)
    paths = []
    names = material_prim_names(scene.materials)
    with Sdf.ChangeBlock():  # the prims as specs first, then defined: see `_node_specs`
        parent = stage.GetRootLayer().GetPrimAtPath(scope_path)
        for name in names:
            spec = Sdf.PrimSpec(parent, name, Sdf.SpecifierDef, "Material")
            Sdf.PrimSpec(spec, SHADER_NAME, Sdf.SpecifierDef, "Shader")
            paths.append(spec.path)
    out = []
    for m, (src, path) in enumerate(zip(scene.materials, paths)):
        material = UsdShade.Material.Define(stage, path)
        shader = UsdShade.Shader.Define(stage, path.AppendChild(SHADER_NAME))
        shader.CreateIdAttr("UsdPreviewSurface")
        scattering = asset.scattering.get(m)
        for name, type_name, value in _surface_inputs(src, scattering):
            shader.CreateInput(name, type_name).Set(value)
        material.CreateSurfaceOutput().ConnectToSource(shader.ConnectableAPI(), "surface")
        if materialx is not None:
            # usd-core reads no .mtlx (no UsdMtlx file format, no OpenPBR node in Sdr): a reference to it
            # would not resolve, so the document and the material in it are named, for a MaterialX-enabled
            # USD build to bind (docs/engines.md, "OpenPBR / MaterialX")
            material.GetPrim().CreateAttribute(MATERIALX, _T.Asset, custom=True).Set(
                Sdf.AssetPath("./" + materialx))
            _string_attribute(material.GetPrim(), MATERIALX + ":material", names[m])
        if scattering is not None:
            what = f"material {src.name!r}"
            material.GetPrim().SetCustomDataByKey("sssbake:previewSurface", PREVIEW_SURFACE_NOTE)
            for name, type_name, value in _scattering_attributes(scattering, mm_per_unit(asset), what):
                material.GetPrim().CreateAttribute(name, type_name, custom=True).Set(value)
            ref = scattering.fallback.thickness_texture
            if ref is not None and ref.texture in texture_files:
                _thickness_network(stage, material, asset.scene.textures[ref.texture], ref,
                                   scattering.fallback.thickness_factor, texture_files[ref.texture], what)
            if m in asset.material_extras:
                _string_attribute(material.GetPrim(), SSS + "extras",
                                  _extras_json(asset.material_extras[m], material.GetPrim(), f"{what} extras", {}))
        out.append(material)
    return out


def _thickness_network(stage: Usd.Stage, material: UsdShade.Material, texture: Texture, ref: TextureRef,
                       thickness_factor: float, file_name: str, what: str) -> None:
    """UsdPrimvarReader_float2 (the atlas UV set) -> UsdUVTexture (the thickness PNG, scaled to file
    units) -> the Material's ``outputs:sss:thickness``."""
    if ref.transform is not None:
        raise ValueError(f"{what}: a thickness texture with KHR_texture_transform cannot be written to USD")
    factor = finite_number(thickness_factor, f"{what} thickness_factor")
    path = material.GetPath()
    reader = UsdShade.Shader.Define(stage, path.AppendChild(THICKNESS_READER))
    reader.CreateIdAttr("UsdPrimvarReader_float2")
    reader.CreateInput("varname", _T.String).Set(uv_primvar(ref.uv_set))
    uv = reader.CreateOutput("result", _T.Float2)
    tex = UsdShade.Shader.Define(stage, path.AppendChild(THICKNESS_TEXTURE))
    tex.CreateIdAttr("UsdUVTexture")
    tex.CreateInput("file", _T.Asset).Set(Sdf.AssetPath("./" + file_name))
    tex.CreateInput("st", _T.Float2).ConnectToSource(uv)
    tex.CreateInput("sourceColorSpace", _T.Token).Set("raw")
    tex.CreateInput("wrapS", _T.Token).Set(_WRAPS.get(texture.wrap_s, "repeat"))
    tex.CreateInput("wrapT", _T.Token).Set(_WRAPS.get(texture.wrap_t, "repeat"))
    # scale makes outputs:g the thickness in file units (the PNG holds thickness / factor)
    tex.CreateInput("scale", _T.Float4).Set(Gf.Vec4f(factor, factor, factor, 1.0))
    thickness = tex.CreateOutput("g", _T.Float)
    material.CreateOutput(THICKNESS_OUTPUT, _T.Float).ConnectToSource(thickness)


def _surface_inputs(src: SourceMaterial, scattering: ScatteringMaterial | None) -> list[tuple]:
    """(input name, type, value) of the UsdPreviewSurface for one material: a translucent one's
    fallback colour and ior, opaque (its light transport is in the ``sss:`` data)."""
    what = f"material {src.name!r}"
    base = scattering.fallback.base_color if scattering is not None else src.base_color_factor[:3]
    opacity = 1.0 if scattering is not None else src.base_color_factor[3]
    inputs = [
        ("diffuseColor", _T.Color3f, Gf.Vec3f(*_vec3(base, f"{what} base color"))),
        ("roughness", _T.Float, finite_number(src.roughness_factor, f"{what} roughness")),
        ("metallic", _T.Float, finite_number(src.metallic_factor, f"{what} metallic")),
        ("opacity", _T.Float, finite_number(opacity, f"{what} opacity")),
        ("emissiveColor", _T.Color3f, Gf.Vec3f(*_vec3(src.emissive_factor, f"{what} emissive"))),
    ]
    ior = scattering.fallback.ior if scattering is not None else src.ior
    if ior is not None:
        inputs.append(("ior", _T.Float, finite_number(ior, f"{what} ior")))
    return inputs


def _scattering_attributes(scattering: ScatteringMaterial, mm_per_unit: float, what: str) -> list[tuple]:
    """The ``sss:`` attributes of a translucent material prim: (name, type, value).

    ``sss:schemaVersion``, ``sss:materialName``, ``sss:sourceName`` (strings), ``sss:units``
    (``"1/mm"``), ``sss:sigmaSPrime`` and ``sss:sigmaA`` (float3, 1/mm), ``sss:eta`` (float); the
    standard-viewer fallback: ``sss:fallback:baseColor``, ``:attenuationColor``,
    ``:diffuseTransmissionColor`` (color3f), ``:thicknessFactor``, ``:attenuationDistance``
    (float, file units; omitted when infinite, i.e. no attenuation), ``:diffuseTransmissionFactor``,
    ``:transmissionFactor``, ``:ior`` (float), ``:slabTransmittance`` (color3f, the slab transmittance
    the diffuse transmission lobe carries in part, `bake.fallback.diffuse_transmission_share`); and what an OpenPBR surface
    (``ND_open_pbr_surface_surfaceshader``) would take, `engine_materials.openpbr_subsurface`:
    ``sss:openpbr:subsurfaceWeight`` (1), ``:subsurfaceColor`` (color3f, the medium's R_d),
    ``:subsurfaceRadius`` (float, file units: the largest reduced mean free path 1/σ'_t over RGB /
    `mm_per_unit`), ``:subsurfaceRadiusScale`` (color3f, each channel's mean free path / the radius)
    and ``:subsurfaceScatterAnisotropy`` (float, 0).
    """
    mat, fb = scattering.material, scattering.fallback
    openpbr = openpbr_subsurface(mat, mm_per_unit)
    out = [
        (SSS + "schemaVersion", _T.String, SCHEMA_VERSION),
        (SSS + "materialName", _T.String, mat.name),
        (SSS + "sourceName", _T.String, scattering.source_name),
        (SSS + "units", _T.String, "1/mm"),
        (SSS + "sigmaSPrime", _T.Float3, Gf.Vec3f(*_vec3(mat.sigma_s_prime, f"{what} sigma_s_prime"))),
        (SSS + "sigmaA", _T.Float3, Gf.Vec3f(*_vec3(mat.sigma_a, f"{what} sigma_a"))),
        (SSS + "eta", _T.Float, finite_number(mat.eta, f"{what} eta")),
        (SSS + "profile", _T.Token, mat.profile),
        (SSS + "escapeGain", _T.Float3, Gf.Vec3f(*_vec3(mat.escape_gain, f"{what} escape_gain"))),
        (SSS + "backGain", _T.Float3, Gf.Vec3f(*_vec3(mat.back_gain, f"{what} back_gain"))),
        (SSS + "fallback:baseColor", _T.Color3f, Gf.Vec3f(*_vec3(fb.base_color, f"{what} fallback base_color"))),
        (SSS + "fallback:thicknessFactor", _T.Float, finite_number(fb.thickness_factor, f"{what} thickness_factor")),
        (SSS + "fallback:attenuationColor", _T.Color3f,
         Gf.Vec3f(*_vec3(fb.attenuation_color, f"{what} attenuation_color"))),
        (SSS + "fallback:diffuseTransmissionFactor", _T.Float,
         finite_number(fb.diffuse_transmission_factor, f"{what} diffuse_transmission_factor")),
        (SSS + "fallback:diffuseTransmissionColor", _T.Color3f,
         Gf.Vec3f(*_vec3(fb.diffuse_transmission_color, f"{what} diffuse_transmission_color"))),
        (SSS + "fallback:transmissionFactor", _T.Float,
         finite_number(fb.transmission_factor, f"{what} transmission_factor")),
        (SSS + "fallback:ior", _T.Float, finite_number(fb.ior, f"{what} fallback ior")),
        (SSS + "fallback:slabTransmittance", _T.Color3f,
         Gf.Vec3f(*_vec3(fb.slab_transmittance, f"{what} slab_transmittance"))),
        (SSS + "openpbr:subsurfaceWeight", _T.Float, openpbr["subsurface_weight"]),
        (SSS + "openpbr:subsurfaceColor", _T.Color3f,
         Gf.Vec3f(*_vec3(openpbr["subsurface_color"], f"{what} subsurface color"))),
        (SSS + "openpbr:subsurfaceRadius", _T.Float,
         finite_number(openpbr["subsurface_radius"], f"{what} subsurface radius")),
        (SSS + "openpbr:subsurfaceRadiusScale", _T.Color3f,
         Gf.Vec3f(*_vec3(openpbr["subsurface_radius_scale"], f"{what} radius scale"))),
        (SSS + "openpbr:subsurfaceScatterAnisotropy", _T.Float, openpbr["subsurface_scatter_anisotropy"]),
    ]
    if fb.attenuation_distance != math.inf:
        out.append((SSS + "fallback:attenuationDistance", _T.Float,
                    finite_number(fb.attenuation_distance, f"{what} attenuation_distance")))
    return out


def _extras_json(extras: dict, prim: Usd.Prim, where: str, primvars: dict[str, str]) -> str:
    """`extras` as JSON. Numpy arrays become `_table` attributes of `prim` named ``sss:`` + their
    keys joined by ``:`` (``sss:prt:directions``), referenced as ``{"attribute", "shape",
    "crc32"}``; strings naming a glTF vertex attribute (keys of `primvars`) become its primvar name."""
    names: set[str] = set()

    def convert(value, where: str, keys: tuple):
        if isinstance(value, dict):
            return {str(k): convert(v, f"{where}.{k}", keys + (str(k),)) for k, v in value.items()}
        if isinstance(value, (list, tuple)):
            return [convert(v, f"{where}[{i}]", keys + (str(i),)) for i, v in enumerate(value)]
        if isinstance(value, np.ndarray) and value.ndim > 0:
            name = SSS + ":".join(_identifier(k, "_") for k in keys)
            if name in names:
                raise ValueError(f"{where}: table name {name} is taken")
            names.add(name)
            return _table(prim, name, value, where)
        if isinstance(value, str) and value in primvars:
            return primvars[value]
        if isinstance(value, (np.generic, np.ndarray)):
            value = value.item()
        if isinstance(value, float) and not math.isfinite(value):
            raise ValueError(f"{where} is not finite: {value}")
        return value

    return json.dumps(convert(extras, where, ()), sort_keys=True, allow_nan=False)


def _table(prim: Usd.Prim, name: str, array: np.ndarray, where: str) -> dict:
    """Write one table as an attribute typed by its shape; return its JSON reference.

    Floats (stored float32): (n, k≤4) ``float<k>[]``, (n, 3, 3) ``matrix3d[]``, (n, 4, 4)
    ``matrix4d[]``, else ``float[]``; integers within int32, 8-bit ones included: ``int[]`` whatever
    the shape, because the crate format compresses ``int[]`` and stores ``uchar[]`` and
    ``int2[]``..``int4[]`` raw (a bake's ``kernels.texelVertices``: 0.13 MB as ``int[]``, 2.4 MB as
    ``int3[]``; thin_slab's int8 ``kernelCodes`` as ``uchar[]`` made its .usdc 16 MB larger). customData:
    ``shape``, ``dtype`` (what a reader restores), ``source``. The reference's ``crc32`` is zlib's
    CRC-32 of the restored array's little-endian bytes.
    """
    if array.size == 0:
        raise ValueError(f"{where}: a table must not be empty, got shape {array.shape}")
    shape = array.shape
    k = shape[-1] if array.ndim == 2 else 1
    if array.dtype.kind == "f":
        restored = _float32(array, where)
        if array.ndim == 3 and shape[1:] in ((3, 3), (4, 4)):
            type_name = _T.Matrix3dArray if shape[1] == 3 else _T.Matrix4dArray
            values = restored.astype(np.float64)
        else:
            type_name = _FLOAT_TYPES[k] if array.ndim == 2 and k in _FLOAT_TYPES else _T.FloatArray
            values = restored if type_name != _T.FloatArray else restored.reshape(-1)
    elif array.dtype.kind in "iu":
        if array.min() < np.iinfo(np.int32).min or array.max() > np.iinfo(np.int32).max:
            raise ValueError(f"{where}: a table's integers must fit int32, got [{array.min()}, {array.max()}]")
        restored = array
        type_name, values = _T.IntArray, array.astype(np.int32).reshape(-1)
    else:
        raise ValueError(f"{where}: a table must hold floats or integers, got dtype {array.dtype}")
    attribute = prim.CreateAttribute(name, type_name, custom=True)
    attribute.Set(type_name.type.pythonClass.FromNumpy(np.ascontiguousarray(values)))
    attribute.SetCustomData({"shape": Vt.IntArray(list(shape)), "dtype": restored.dtype.name, "source": where})
    return {"attribute": name, "shape": list(shape), "crc32": table_crc32(restored)}


def check_schema(stage: Usd.Stage) -> None:
    """Refuse a stage whose default prim says it was written by another major sssbake schema.

    Raises
    ------
    StaleDataError
        ``"<file>: written by sssbake schema 1.x; rebake it with this version"``.
    """
    default = stage.GetDefaultPrim()
    version = default.GetAttribute(SSS + "schemaVersion").Get() if default else None
    if version and str(version).split(".")[0] != SCHEMA_VERSION.split(".")[0]:
        major = str(version).split(".")[0]
        raise StaleDataError(_layer_path(default), f"written by sssbake schema {major}.x; rebake it with this version")


def technique_tables(prim: Usd.Prim, technique: str) -> dict | None:
    """A Mesh or Material prim's ``sss:extras[technique]`` with every table reference read into its
    array (shape and dtype as baked); primvar references stay primvar names. None when the prim
    has no such data.

    Raises
    ------
    StaleDataError
        ``sss:extras`` is not a JSON object; a table reference is malformed, its table missing, or its
        element count or CRC-32 no longer matches it; or the file was written by another major schema
        (`check_schema`).
    """
    attr = prim.GetAttribute(SSS + "extras")
    if not (prim.IsA(UsdGeom.Mesh) or prim.IsA(UsdShade.Material)) or not attr:
        return None
    try:
        extras = json.loads(attr.Get())
    except (TypeError, ValueError, RecursionError) as e:  # RecursionError: nested past what json parses
        raise _stale(prim, f"{attr.GetPath()} is not JSON ({type(e).__name__})") from None
    if not isinstance(extras, dict):
        raise _stale(prim, f"{attr.GetPath()} is not a JSON object")
    tables = extras.get(technique)
    if tables is None:
        return None
    check_schema(prim.GetStage())

    def resolve(value, what: str):
        if isinstance(value, dict) and "attribute" in value and "crc32" in value:
            return _read_table(prim, value, what)
        if isinstance(value, dict):
            return {k: resolve(v, f"{what}.{k}") for k, v in value.items()}
        return value

    try:
        return resolve(tables, technique)
    except RecursionError:  # json parses deeper than this walk goes
        raise _stale(prim, f"{attr.GetPath()} nests {technique} too deep") from None


def technique_data(prim: Usd.Prim, technique: str) -> tuple[dict, dict[str, np.ndarray]] | None:
    """`technique_tables` in the glTF layout's vocabulary, with the per-vertex data it names.

    Returns
    -------
    tables : dict
        As `technique_tables`, primvar names replaced by the glTF attribute names they stand for
        (their customData ``gltfName``), what the techniques' ``*_from_layout`` functions expect.
    per_vertex : dict
        glTF attribute name -> (n, k) float64 values (`primvar_values`) over the prim's n points.
    None when the prim has no such data.

    Raises
    ------
    StaleDataError
        As `technique_tables`, or a named primvar is missing or has not one value per point.
    """
    tables = technique_tables(prim, technique)
    if tables is None:
        return None
    points = UsdGeom.Mesh(prim).GetPointsAttr().Get() if prim.IsA(UsdGeom.Mesh) else None
    n = 0 if points is None else len(points)
    per_vertex: dict[str, np.ndarray] = {}
    api = UsdGeom.PrimvarsAPI(prim)

    def rename(value):
        if isinstance(value, dict):
            return {k: rename(v) for k, v in value.items()}
        if isinstance(value, list):
            return [rename(v) for v in value]
        if isinstance(value, str) and value.startswith("primvars:" + SSS):
            primvar = api.GetPrimvar(value.removeprefix("primvars:"))
            if not primvar or not primvar.HasAuthoredValue():
                raise _stale(prim, f"{prim.GetPath()} lacks {value}, which its sss:extras {technique} names")
            values = primvar_values(primvar)
            if len(values) != n:
                raise _stale(prim, f"{prim.GetPath()}.{value} has {len(values)} values for {n} points")
            gltf_name = str(primvar.GetAttr().GetCustomData().get("gltfName", value))
            per_vertex[gltf_name] = values
            return gltf_name
        return value

    return rename(tables), per_vertex


def _read_table(prim: Usd.Prim, ref: dict, what: str) -> np.ndarray:
    """The array a `_table` reference names, checked against its shape and CRC-32."""
    name, shape = ref["attribute"], ref.get("shape")
    if not isinstance(name, str) or not Sdf.Path.IsValidNamespacedIdentifier(name) or not isinstance(shape, list) \
            or not all(isinstance(s, int) and not isinstance(s, bool) and s >= 0 for s in shape):
        raise _stale(prim, f"{prim.GetPath()} table {what} has a malformed reference {str(ref)[:80]}")
    attribute = prim.GetAttribute(name)
    raw = attribute.Get() if attribute else None
    where = f"{prim.GetPath()} table {what} ({name})"
    values = None if raw is None else np.asarray(raw)
    if values is None or values.dtype.kind not in "fiu":
        raise _stale(prim, f"{where} is missing" if values is None else f"{where} does not hold numbers")
    declared = str(attribute.GetCustomData().get("dtype", values.dtype.name))
    try:
        dtype = np.dtype(declared)
    except TypeError:
        dtype = None
    if dtype is None or dtype.kind not in "fiu":
        raise _stale(prim, f"{where} has customData dtype {declared!r}, not a number type")
    if values.size != math.prod(shape):
        raise _stale(prim, f"{where} has {values.size} values, its reference says shape {list(shape)}")
    restored = values.astype(dtype).reshape(shape)
    crc = table_crc32(restored)
    if crc != ref["crc32"]:
        raise _stale(prim, f"{where} fails its CRC-32 ({crc}, reference {ref['crc32']})")
    return restored


def _layer_path(prim: Usd.Prim) -> str:
    layer = prim.GetStage().GetRootLayer()
    return layer.realPath or layer.identifier


def _stale(prim: Usd.Prim, problem: str) -> StaleDataError:
    """`StaleDataError` for `problem` in `prim`'s file, naming who most likely broke the data: the
    layer's ``creator`` (or documentation) when it is not sssbake."""
    layer = prim.GetStage().GetRootLayer()
    creator = str(layer.customLayerData.get("creator") or layer.documentation or "")
    tool = creator if creator and not creator.startswith("sssbake") else "a tool that rewrote the file's sss: data"
    return StaleDataError(_layer_path(prim), f"{problem}; likely broken by {tool}: bake the asset again")


def _check_references(asset: BakedAsset) -> None:
    scene = asset.scene
    for i, j in asset.vertex_attributes:
        if not (0 <= i < len(scene.meshes) and 0 <= j < len(scene.meshes[i].primitives)):
            raise ValueError(f"vertex_attributes refer to mesh {i} primitive {j}, which the scene lacks")
    check_material_references(asset)
    for mesh in scene.meshes:
        for j, prim in enumerate(mesh.primitives):
            if prim.material is not None and not 0 <= prim.material < len(scene.materials):
                raise ValueError(f"mesh {mesh.name!r} primitive {j} uses material {prim.material}, "
                                 f"not in the scene ({len(scene.materials)} materials)")


def _string_attribute(prim: Usd.Prim, name: str, value: str) -> None:
    prim.CreateAttribute(name, Sdf.ValueTypeNames.String, custom=True).Set(value)


def _identifier(name: str, fallback: str) -> str:
    """`name` as a prim name: characters outside [A-Za-z0-9_] become ``_``, a leading digit gets a ``_``."""
    if not name:
        return fallback
    name = re.sub(r"[^A-Za-z0-9_]", "_", name)
    return "_" + name if name[0].isdigit() else name


def _unique(name: str, taken: dict[str, int]) -> str:
    """`name`, or `name_<k>` with the lowest free k; records the choice in `taken` (names taken ->
    the first k to try for that name next, so that N siblings of one name cost O(N), not O(N²))."""
    candidate, k = name, taken.get(name, 1)
    while candidate in taken:
        candidate, k = f"{name}_{k}", k + 1
    taken[name] = k
    taken.setdefault(candidate, 1)
    return candidate


def _float32(values, what: str) -> np.ndarray:
    """`values` as float32, refused when anything is NaN or Inf (before or after the cast)."""
    with np.errstate(over="ignore"):
        out = np.asarray(values, dtype=np.float64).astype(np.float32)
    if not np.all(np.isfinite(out)):
        raise ValueError(f"{what} has non-finite values (NaN or Inf) or values beyond float32 range")
    return out


def _vec3(values, what: str) -> tuple[float, float, float]:
    arr = np.asarray(values, dtype=np.float64).reshape(-1)
    if arr.size != 3:
        raise ValueError(f"{what} needs 3 values, got {arr.size}")
    check_finite(arr, what)
    return (float(arr[0]), float(arr[1]), float(arr[2]))


