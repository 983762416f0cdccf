"""OpenUSD (.usdc) export of a BakedAsset: geometry, UsdPreviewSurface materials and sssbake data.

Layout of the file (one self-contained crate file):

- stage metadata ``upAxis`` (the scene's), ``metersPerUnit`` (see `meters_per_unit`),
  ``defaultPrim`` = ``/<Root>``, an Xform of kind ``component`` named after the file stem, and
  ``customLayerData.creator`` = ``"sssbake <version>"``;
- the node hierarchy as Xforms under the root, each with one ``xformOp:transform`` when its matrix
  is not the identity (the node matrix transposed: USD multiplies row vectors);
- each primitive of a node's mesh as a ``UsdGeom.Mesh`` child of the node's Xform (named after the
  mesh, ``<mesh>_<j>`` when it has several primitives; a mesh used by several nodes is written
  under each): points, faceVertexCounts (all 3), faceVertexIndices, normals (vertex
  interpolation), extent, subdivisionScheme ``none``, ``primvars:st``, ``primvars:st1``, ... from
  TEXCOORD_0, 1, ... (v flipped back to USD's bottom-up convention), displayColor/displayOpacity
  from the vertex colours, and ``sss:scaleMm`` (double, mm per file unit) when the asset has it;
- each `VertexAttribute` as a float[] (int[] for ``uint8``, ``uint16``) primvar (`VertexAttribute.usd_name`) with vertex interpolation,
  ``elementSize`` k for (n, k) data, the unit and description in its ``customData`` (``unit``,
  ``description``) and the description as its documentation;
- materials under ``/<Root>/Materials``: a Material with one UsdPreviewSurface shader, bound with
  the MaterialBindingAPI. Translucent materials get the fallback's diffuseColor and ior and the
  ``sss:`` attributes listed in `_scattering_attributes`;
- on the root prim ``sss:schemaVersion`` and ``sss:extras`` (`BakedAsset.extras` as a JSON string);
  numpy arrays in the extras become ``sss:tables:t<i>`` array attributes referenced in the JSON
  as ``{"attribute": "sss:tables:t<i>", "shape": [...]}``;
- on each Mesh prim of a mesh with `BakedAsset.mesh_extras` (technique data such as prt), its own
  ``sss:extras`` JSON and ``sss:tables:t<i>`` attributes, the same way;
- on each translucent Material prim with `BakedAsset.material_extras` (technique data such as
  screen), its own ``sss:extras`` JSON, the tables as attributes named by their keys
  (``sss:screen:offsets``, ``sss:screen:weights``, ``sss:screen:rdTable``);

Textures are not written: a .usdc cannot embed images, and files next to it would break the
one-file output. Everything is float32 except matrices and ``sss:scaleMm`` (double).
"""

from __future__ import annotations

import json
import math
import os
import re
from pathlib import Path

import numpy as np
from pxr import Gf, Kind, Sdf, Usd, UsdGeom, UsdShade, Vt

from sssbake.exporters.atomic import atomic_path
from sssbake.exporters.finite import check_finite, finite_number
from sssbake.exporters.gltf import generator
from sssbake.pipeline.mesh.baked import (
    SCHEMA_VERSION,
    BakedAsset,
    ScatteringMaterial,
    VertexAttribute,
    check_material_references,
)
from sssbake.pipeline.mesh.scene import Primitive, SourceMaterial

#: Prefix of every sssbake attribute and primvar namespace.
SSS = "sss:"
MATERIALS_SCOPE = "Materials"
SHADER_NAME = "PreviewSurface"
FACE_BLOCKS = ("faceVertexCounts", "faceVertexIndices")


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


def to_stage(asset: BakedAsset, root_name: str = "Root") -> tuple[Usd.Stage, dict]:
    """Build `asset` as an in-memory stage.

    Parameters
    ----------
    asset : BakedAsset
    root_name : str
        Name of the default prim; made a valid USD identifier.

    Returns
    -------
    stage : Usd.Stage
        Anonymous in-memory stage; nothing is written to disk.
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
        Non-finite data (or beyond float32), a primvar whose element count is not points ×
        elementSize, face indices out of range, attributes or scattering for meshes,
        primitives or materials the scene lacks.
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
    _string_attribute(root, SSS + "extras", _extras_json(asset.extras, root, "extras"))

    materials = _materials(stage, root_path.AppendChild(MATERIALS_SCOPE), asset)

    acc = _Accounting()
    taken = {root_path: {MATERIALS_SCOPE}}
    stack = [(r, root_path) for r in reversed(scene.roots)]
    while stack:
        i, parent = stack.pop()
        node = scene.nodes[i]
        path = parent.AppendChild(_unique(_identifier(node.name, f"node{i}"), taken.setdefault(parent, set())))
        xform = UsdGeom.Xform.Define(stage, path)
        matrix = np.asarray(node.matrix, dtype=np.float64)
        check_finite(matrix, f"node {node.name!r} matrix")
        if not np.array_equal(matrix, np.eye(4)):
            xform.AddTransformOp().Set(Gf.Matrix4d(matrix.T.tolist()))
        if node.mesh is not None:
            mesh = scene.meshes[node.mesh]
            for j, prim in enumerate(mesh.primitives):
                name = mesh.name if len(mesh.primitives) == 1 else f"{mesh.name}_{j}"
                mesh_name = _unique(_identifier(name, f"mesh{node.mesh}_{j}"), taken.setdefault(path, set()))
                mesh_path = path.AppendChild(mesh_name)
                where = f"mesh {mesh.name!r} primitive {j}"
                usd_mesh = _mesh(stage, mesh_path, prim, asset.vertex_attributes.get((node.mesh, j), ()), where, acc)
                if node.mesh in asset.scale_mm:
                    scale = finite_number(asset.scale_mm[node.mesh], f"scale_mm of mesh {mesh.name!r}")
                    attribute = usd_mesh.GetPrim().CreateAttribute(SSS + "scaleMm", Sdf.ValueTypeNames.Double, custom=True)
                    attribute.Set(scale)
                if node.mesh in asset.mesh_extras:
                    extras_json = _extras_json(asset.mesh_extras[node.mesh], usd_mesh.GetPrim(),
                                               f"mesh {mesh.name!r} extras")
                    _string_attribute(usd_mesh.GetPrim(), SSS + "extras", extras_json)
                if prim.material is not None:
                    src = scene.materials[prim.material]
                    if src.double_sided and prim.material not in asset.scattering:
                        usd_mesh.CreateDoubleSidedAttr(True)
                    UsdShade.MaterialBindingAPI.Apply(usd_mesh.GetPrim()).Bind(materials[prim.material])
        stack.extend((c, path) for c in reversed(node.children))
    return stage, acc.summary()


def write_usdc(asset: BakedAsset, path: str | os.PathLike) -> dict:
    """Write `asset` to `path` (.usdc) atomically: on any error nothing is left behind.

    The default prim is named after the file stem (made a valid identifier).

    Returns
    -------
    dict
        ``path``, ``bytes`` (file size) and `to_stage`'s summary.
    """
    path = Path(path)
    stage, summary = to_stage(asset, path.stem)
    with atomic_path(path) as tmp:
        if not stage.GetRootLayer().Export(str(tmp)):
            raise OSError(f"USD could not write {tmp}")
    return {"path": str(path), "bytes": path.stat().st_size, **summary}


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
        primvars.append(("st" if t == 0 else f"st{t}", Sdf.ValueTypeNames.TexCoord2fArray, flipped, None, {}))
    if prim.colors is not None:
        colors = _float32(prim.colors, f"{where}: colors")
        if colors.ndim != 2 or colors.shape[1] not in (3, 4):
            raise ValueError(f"{where}: colors have shape {colors.shape}, expected (n, 3) or (n, 4)")
        primvars.append(("displayColor", Sdf.ValueTypeNames.Color3fArray, colors[:, :3], None, {}))
        if colors.ndim == 2 and colors.shape[1] == 4:
            primvars.append(("displayOpacity", Sdf.ValueTypeNames.FloatArray, colors[:, 3], None, {}))
    for attr in attrs:
        name = attr.usd_name.removeprefix("primvars:")
        if any(name == p[0] for p in primvars):
            raise ValueError(f"{where}: attribute {attr.usd_name} given twice")
        data = _float32(attr.data, f"{where}: attribute {attr.usd_name}")
        if data.ndim not in (1, 2):
            raise ValueError(f"{where}: attribute {attr.usd_name} has shape {data.shape}, expected (n,) or (n, k)")
        size = data.shape[1] if data.ndim == 2 else None
        meta = {"unit": attr.unit, "description": attr.description}
        type_name = Sdf.ValueTypeNames.FloatArray
        if attr.encoding in ("uint8", "uint16"):
            top = np.iinfo(attr.encoding).max
            if data.size and (data.min() < 0 or data.max() > top or np.any(data != np.round(data))):
                raise ValueError(f"{where}: attribute {attr.usd_name} needs integers in [0, {top}]")
            data, type_name = data.astype(np.int32), Sdf.ValueTypeNames.IntArray
        primvars.append((name, type_name, data.reshape(-1), size, meta))

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


def _vt_checked(type_name: Sdf.ValueTypeName, values: np.ndarray, n: int, element_size: int, what: str):
    """`values` as the Vt array of `type_name`, refused unless it holds n × element_size elements."""
    vt = type_name.type.pythonClass.FromNumpy(np.ascontiguousarray(values))
    if len(vt) != n * element_size:
        raise ValueError(f"{what} has {len(vt)} elements, expected {n} points × elementSize {element_size} "
                         f"= {n * element_size}")
    return vt


def _materials(stage: Usd.Stage, scope_path: Sdf.Path, asset: BakedAsset) -> list[UsdShade.Material]:
    scene = asset.scene
    if not scene.materials:
        return []
    UsdGeom.Scope.Define(stage, scope_path)
    taken: set[str] = set()
    out = []
    for m, src in enumerate(scene.materials):
        path = scope_path.AppendChild(_unique(_identifier(src.name, f"material{m}"), taken))
        material = UsdShade.Material.Define(stage, path)
        shader = UsdShade.Shader.Define(stage, path.AppendChild(SHADER_NAME))
        shader.CreateIdAttr("UsdPreviewSurface")
        scattering = asset.scattering.get(m)
        for name, type_name, value in _surface_inputs(src, scattering):
            shader.CreateInput(name, type_name).Set(value)
        material.CreateSurfaceOutput().ConnectToSource(shader.ConnectableAPI(), "surface")
        if scattering is not None:
            for name, type_name, value in _scattering_attributes(scattering, f"material {src.name!r}"):
                material.GetPrim().CreateAttribute(name, type_name, custom=True).Set(value)
            if m in asset.material_extras:
                _string_attribute(material.GetPrim(), SSS + "extras",
                                  _extras_json(asset.material_extras[m], material.GetPrim(),
                                               f"material {src.name!r} extras", named=True))
        out.append(material)
    return out


def _surface_inputs(src: SourceMaterial, scattering: ScatteringMaterial | None) -> list[tuple]:
    """(input name, type, value) of the UsdPreviewSurface for one material."""
    what = f"material {src.name!r}"
    base = scattering.fallback.base_color if scattering is not None else src.base_color_factor[:3]
    inputs = [
        ("diffuseColor", Sdf.ValueTypeNames.Color3f, Gf.Vec3f(*_vec3(base, f"{what} base color"))),
        ("roughness", Sdf.ValueTypeNames.Float, finite_number(src.roughness_factor, f"{what} roughness")),
        ("metallic", Sdf.ValueTypeNames.Float, finite_number(src.metallic_factor, f"{what} metallic")),
        ("opacity", Sdf.ValueTypeNames.Float, finite_number(src.base_color_factor[3], f"{what} opacity")),
        ("emissiveColor", Sdf.ValueTypeNames.Color3f, Gf.Vec3f(*_vec3(src.emissive_factor, f"{what} emissive"))),
    ]
    ior = scattering.fallback.ior if scattering is not None else src.ior
    if ior is not None:
        inputs.append(("ior", Sdf.ValueTypeNames.Float, finite_number(ior, f"{what} ior")))
    return inputs


def _scattering_attributes(scattering: ScatteringMaterial, what: str) -> list[tuple]:
    """The ``sss:`` attributes of a translucent material prim: (name, type, value).

    ``sss:schemaVersion``, ``sss:materialName``, ``sss:sourceName`` (strings), ``sss:units``
    (``"1/mm"``), ``sss:sigmaSPrime`` and ``sss:sigmaA`` (float3, 1/mm), ``sss:eta`` (float), and
    the standard-viewer fallback: ``sss:fallback:baseColor``, ``:attenuationColor``,
    ``:diffuseTransmissionColor`` (color3f), ``:thicknessFactor``, ``:attenuationDistance``
    (float, file units; omitted when infinite, i.e. no attenuation), ``:diffuseTransmissionFactor``,
    ``:ior`` (float).
    """
    mat, fb = scattering.material, scattering.fallback
    T = Sdf.ValueTypeNames
    out = [
        (SSS + "schemaVersion", T.String, SCHEMA_VERSION),
        (SSS + "materialName", T.String, mat.name),
        (SSS + "sourceName", T.String, scattering.source_name),
        (SSS + "units", T.String, "1/mm"),
        (SSS + "sigmaSPrime", T.Float3, Gf.Vec3f(*_vec3(mat.sigma_s_prime, f"{what} sigma_s_prime"))),
        (SSS + "sigmaA", T.Float3, Gf.Vec3f(*_vec3(mat.sigma_a, f"{what} sigma_a"))),
        (SSS + "eta", T.Float, finite_number(mat.eta, f"{what} eta")),
        (SSS + "fallback:baseColor", T.Color3f, Gf.Vec3f(*_vec3(fb.base_color, f"{what} fallback base_color"))),
        (SSS + "fallback:thicknessFactor", T.Float, finite_number(fb.thickness_factor, f"{what} thickness_factor")),
        (SSS + "fallback:attenuationColor", T.Color3f,
         Gf.Vec3f(*_vec3(fb.attenuation_color, f"{what} attenuation_color"))),
        (SSS + "fallback:diffuseTransmissionFactor", T.Float,
         finite_number(fb.diffuse_transmission_factor, f"{what} diffuse_transmission_factor")),
        (SSS + "fallback:diffuseTransmissionColor", T.Color3f,
         Gf.Vec3f(*_vec3(fb.diffuse_transmission_color, f"{what} diffuse_transmission_color"))),
        (SSS + "fallback:ior", T.Float, finite_number(fb.ior, f"{what} fallback ior")),
    ]
    if fb.attenuation_distance != math.inf:
        out.append((SSS + "fallback:attenuationDistance", T.Float,
                    finite_number(fb.attenuation_distance, f"{what} attenuation_distance")))
    return out


def _extras_json(extras: dict, root: Usd.Prim, where: str, named: bool = False) -> str:
    """`extras` as JSON; numpy arrays become ``sss:tables:t<i>`` attributes on `root` (`named`:
    ``sss:<key>:<key>...``, the array's keys in `extras`, e.g. ``sss:screen:offsets``)."""
    tables: list[Usd.Attribute] = []

    def convert(value, where: str, keys: tuple):
        if isinstance(value, dict):
            return {str(k): convert(v, f"{where}.{k}", keys + (str(k),)) for k, v in value.items()}
        if isinstance(value, (list, tuple)):
            return [convert(v, f"{where}[{i}]", keys + (str(i),)) for i, v in enumerate(value)]
        if isinstance(value, np.ndarray) and value.ndim > 0:
            name = SSS + ":".join(keys) if named else f"{SSS}tables:t{len(tables)}"
            tables.append(_table(root, name, value, where))
            return {"attribute": name, "shape": list(value.shape)}
        if isinstance(value, (np.generic, np.ndarray)):
            value = value.item()
        if isinstance(value, float) and not math.isfinite(value):
            raise ValueError(f"{where} is not finite: {value}")
        return value

    return json.dumps(convert(extras, where, ()), sort_keys=True, allow_nan=False)


def technique_tables(prim: Usd.Prim, technique: str) -> dict | None:
    """A Mesh or Material prim's ``sss:extras[technique]`` with every ``{"attribute": name, "shape":
    ...}`` read into its array; None when the prim has no such data."""
    attr = prim.GetAttribute("sss:extras")
    if not (prim.IsA(UsdGeom.Mesh) or prim.IsA(UsdShade.Material)) or not attr:
        return None
    tables = json.loads(attr.Get()).get(technique)
    if tables is None:
        return None
    return {k: np.asarray(prim.GetAttribute(v["attribute"]).Get()).reshape(v["shape"])
            if isinstance(v, dict) and "attribute" in v else v for k, v in tables.items()}


def _table(root: Usd.Prim, name: str, array: np.ndarray, where: str) -> Usd.Attribute:
    """A table as a flat float[] (float32), uchar[] (uint8), int[] (int8, int16) or uint[] attribute;
    customData holds its shape."""
    if array.size == 0:
        raise ValueError(f"{where}: a table must not be empty, got shape {array.shape}")
    if array.dtype.kind == "f":
        values, type_name = Vt.FloatArray.FromNumpy(_float32(array, where).reshape(-1)), Sdf.ValueTypeNames.FloatArray
    elif array.dtype == np.uint8:
        values, type_name = Vt.UCharArray.FromNumpy(array.reshape(-1)), Sdf.ValueTypeNames.UCharArray
    elif array.dtype in (np.int8, np.int16):
        values, type_name = Vt.IntArray.FromNumpy(array.astype(np.int32).reshape(-1)), Sdf.ValueTypeNames.IntArray
    elif array.dtype.kind in "iu" and array.min() >= 0 and array.max() <= np.iinfo(np.uint32).max:
        values, type_name = Vt.UIntArray.FromNumpy(array.astype(np.uint32).reshape(-1)), Sdf.ValueTypeNames.UIntArray
    else:
        raise ValueError(f"{where}: a table must hold floats or integers in [0, 2^32), got dtype {array.dtype}")
    attribute = root.CreateAttribute(name, type_name, custom=True)
    attribute.Set(values)
    attribute.SetCustomData({"shape": Vt.IntArray(list(array.shape)), "source": where})
    return attribute


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


def _unique(name: str, taken: set[str]) -> str:
    """`name`, or `name_<k>` with the lowest free k; records the choice in `taken`."""
    candidate, k = name, 1
    while candidate in taken:
        candidate, k = f"{name}_{k}", k + 1
    taken.add(candidate)
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


