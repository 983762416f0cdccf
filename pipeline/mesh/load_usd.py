"""Reads an OpenUSD stage (.usd, .usda, .usdc) into a `Scene`.

What is read, at the earliest authored time (the default value when nothing is animated):

- every ``UsdGeom.Mesh`` under the default prim (the whole stage when it has none), skipping
  meshes of purpose ``guide`` or ``proxy``; polygons are fan-triangulated, holes dropped,
  ``leftHanded`` winding reversed, polygons with fewer than 3 corners ignored;
- a `Node` per prim on the way to a mesh (Xforms, Scopes, the Mesh prims themselves) with its
  local matrix transposed to column vectors; the top nodes carry their full local-to-world matrix
  (ancestors above the default prim included), a prim that resets the transform stack its matrix
  relative to its parent node;
- normals (``primvars:normals`` before ``normals``), ``primvars:st`` and further texture
  coordinate sets (``st1``, ``st2``, ... and other texCoord2 primvars, sorted by name) with v
  flipped to glTF's convention, displayColor/displayOpacity as vertex colours. Any attribute
  with faceVarying or uniform interpolation splits vertices per face corner; corners with equal
  data are welded again;
- the bound material (``GeomSubset`` bindings of the ``materialBind`` family split the mesh into
  primitives): a UsdPreviewSurface's unconnected diffuseColor, opacity, roughness, metallic,
  emissiveColor and ior; textures are not read. sssbake's own ``sss:fallback:*`` attributes
  become the material's ``volume`` / ``diffuse_transmission``. A mesh without a material but
  with a constant displayColor gets a material of that colour;
- ``upAxis`` and, when authored, ``metersPerUnit``.

Before the stage opens, every layer it would read (sublayers, references, payloads, value clips)
is found by walking the layers and checked against the asset's `Confinement`.
"""

from __future__ import annotations

import math
import os
import re
from dataclasses import replace

import numpy as np
from pxr import Ar, Gf, Sdf, Tf, Usd, UsdGeom, UsdShade, UsdSkel

from sssbake.pipeline.core.errors import AssetError
from sssbake.pipeline.mesh.confine import Confinement
from sssbake.pipeline.mesh.digest import file_digest
from sssbake.pipeline.mesh.scene import Mesh, Node, Primitive, Scene, SourceMaterial

#: UsdPreviewSurface input defaults (UsdPreviewSurface specification).
_PREVIEW_DEFAULTS = {
    "diffuseColor": (0.18, 0.18, 0.18),
    "opacity": 1.0,
    "roughness": 0.5,
    "metallic": 0.0,
    "emissiveColor": (0.0, 0.0, 0.0),
}
_SKIPPED_PURPOSES = (UsdGeom.Tokens.guide, UsdGeom.Tokens.proxy)


def load_usd(path: str | os.PathLike, confinement: Confinement | None = None) -> Scene:
    """Read the meshes, node hierarchy and materials of a USD stage.

    Parameters
    ----------
    path : str or os.PathLike
        A .usd, .usda or .usdc file.
    confinement : Confinement or None
        Where the layers and assets it references may lie (default: the asset's folder only).

    Returns
    -------
    Scene
        One `Mesh` per Mesh prim (one `Primitive` per material subset), positions (n, 3) and
        faces (m, 3) as documented in `sssbake.pipeline.mesh.scene`.

    Raises
    ------
    AssetError
        Unreadable, empty or corrupt file; no meshes; non-finite points; faceVertexCounts not
        matching faceVertexIndices; face or primvar indices out of range; primvars whose length
        does not fit their interpolation; no triangles.
    """
    path = os.fspath(path)
    confinement = confinement or Confinement.for_asset(path)
    try:
        if os.path.getsize(path) == 0:
            raise AssetError(path, "empty file (0 bytes)")
    except OSError as e:
        raise AssetError(path, f"cannot read file: {e.strerror or e}") from None
    try:
        # A linked asset file is opened where it really lies: its layers anchor their
        # references there, beside the real file, as a linked asset library expects.
        real = os.path.realpath(path)
        root = Sdf.Layer.FindOrOpen(real)
    except Tf.ErrorException as e:
        raise AssetError(path, f"corrupt USD file: {usd_error_message(e, real)}") from None
    if root is None:
        raise AssetError(path, "corrupt USD file: no USD file format reads it")
    # The checked layers stay open (in Sdf's layer registry) while the stage composes, so the
    # stage finds each of them there instead of opening anything the walk did not check.
    layers = _LayerWalk(path, confinement).walk(root)
    try:
        stage = Usd.Stage.Open(root, Usd.Stage.LoadAll)
    except Tf.ErrorException as e:
        raise AssetError(path, f"corrupt USD file: {usd_error_message(e, path)}") from None
    unchecked = sorted(layer.identifier for layer in stage.GetUsedLayers()
                       if not layer.anonymous and layer.identifier not in layers)
    if unchecked:
        # A composition route the walk does not know; refuse rather than bake from it.
        raise AssetError(path, f"the stage composed layer {unchecked[0]}, which no sublayer, reference, payload "
                               "or value clip names; refused")
    read = dict.fromkeys(layer.realPath for layer in layers.values() if layer.realPath and layer.realPath != real)
    return replace(_Reader(path, stage).scene(), dependencies=tuple((p, file_digest(p)) for p in read))


class _LayerWalk:
    """Every layer a stage would read, each checked against the confinement before it is opened.

    Sublayers, references and payloads (in variants too) come from
    ``Sdf.Layer.GetCompositionAssetDependencies``; value clips (which ``Usd.Stage.Open`` reads
    to build their manifest) from the ``clips`` metadata of each prim spec. Variable
    expressions in asset paths are evaluated with the layer stack's ``expressionVariables``, the
    referencing stack's values winning, as composition does.
    """

    def __init__(self, asset: str, confinement: Confinement):
        self.asset = asset
        self.confinement = confinement
        self.folder = os.path.dirname(os.path.abspath(asset))
        self.resolver = Ar.GetResolver()

    def walk(self, root: Sdf.Layer) -> dict[str, Sdf.Layer]:
        """Identifier -> open layer, `root` and every layer reachable from it."""
        layers = {root.identifier: root}
        todo = [(root, dict(root.expressionVariables))]
        while todo:
            layer, variables = todo.pop()
            kinds, clips = _arcs(layer, self.asset)
            # internal references (</Prim>, no asset) are listed as ''
            assets = [(a, kinds.get(a, "reference")) for a in layer.GetCompositionAssetDependencies() if a]
            assets += [(a, "value clip") for a in clips]
            for authored, kind in assets:
                child = self.open(layer, authored, kind, variables)
                if child is not None and child.identifier not in layers:
                    layers[child.identifier] = child
                    stack = variables if kind == "sublayer" else {**child.expressionVariables, **variables}
                    todo.append((child, stack))
        return layers

    def name(self, layer: Sdf.Layer) -> str:
        """`layer` as the user finds it: relative to the asset's folder when inside it."""
        rel = os.path.relpath(layer.realPath, self.folder)
        return layer.realPath if rel.startswith("..") else rel

    def open(self, layer: Sdf.Layer, authored: str, kind: str, variables: dict) -> Sdf.Layer | None:
        """The layer `authored` (as written in `layer`) names, None for an expression that names none."""
        what = f"{kind} '{authored}' (from {self.name(layer)})"
        asset = authored
        if Sdf.VariableExpression.IsExpression(authored):
            result = Sdf.VariableExpression(authored).Evaluate(variables)
            if result.errors or not isinstance(result.value, str):
                problem = "; ".join(result.errors) or f"evaluates to {result.value!r}, not a string"
                raise AssetError(self.asset, f"{what}: {problem}")
            if not result.value:
                return None
            asset = result.value
        identifier = self.resolver.CreateIdentifier(asset, Ar.ResolvedPath(layer.resolvedPath))
        resolved = str(self.resolver.Resolve(identifier))
        file = Ar.SplitPackageRelativePathOuter(Sdf.Layer.SplitIdentifier(resolved or identifier)[0])[0]
        if os.path.isabs(file):
            self.confinement.check(file, what)
        if not resolved:
            raise AssetError(self.asset, f"{what} not found")
        try:
            child = Sdf.Layer.FindOrOpen(identifier)
        except Tf.ErrorException as e:
            raise AssetError(self.asset, f"corrupt {what}: {usd_error_message(e, file)}") from None
        if child is None:
            raise AssetError(self.asset, f"{what}: no USD file format reads it")
        return child


def _arcs(layer: Sdf.Layer, asset: str) -> tuple[dict[str, str], list[str]]:
    """What `layer` names, as authored.

    Returns
    -------
    kinds : dict of str to str
        Asset path -> ``"sublayer"``, ``"reference"`` or ``"payload"``, variants included.
    clips : list of str
        Value clip asset paths and manifests.

    Raises
    ------
    AssetError
        For template value clips, whose files are only known by listing a folder.
    """
    kinds = dict.fromkeys(layer.subLayerPaths, "sublayer")
    clips: list[str] = []

    def visit(path: Sdf.Path) -> None:
        spec = layer.GetObjectAtPath(path)
        if isinstance(spec, Sdf.VariantSpec):
            spec = spec.primSpec
        elif not isinstance(spec, Sdf.PrimSpec):
            return
        for kind, items in (("reference", spec.referenceList), ("payload", spec.payloadList)):
            kinds.update((item.assetPath, kind) for item in items.GetAddedOrExplicitItems() if item.assetPath)
        for name, clip_set in (dict(spec.GetInfo("clips")) if spec.HasInfo("clips") else {}).items():
            if "templateAssetPath" in clip_set:
                raise AssetError(asset, f"value clip set '{name}' on <{path}> in {layer.realPath} uses a template "
                                        "asset path, which is not supported; list the clip files in assetPaths")
            clips.extend(a.path for a in clip_set.get("assetPaths", ()))
            if clip_set.get("manifestAssetPath"):
                clips.append(clip_set["manifestAssetPath"].path)

    layer.Traverse(Sdf.Path.absoluteRootPath, visit)
    return kinds, clips


class _Reader:
    def __init__(self, path: str, stage: Usd.Stage):
        self.path = path
        self.stage = stage
        self.time = Usd.TimeCode.EarliestTime()
        self.xforms = UsdGeom.XformCache(self.time)
        self.predicate = Usd.TraverseInstanceProxies(Usd.PrimDefaultPredicate)
        self.nodes: list[Node | None] = []
        self.meshes: list[Mesh] = []
        self.materials: list[SourceMaterial] = []
        self.material_index: dict[tuple, int] = {}
        self.skipped = 0

    def scene(self) -> Scene:
        default = self.stage.GetDefaultPrim()
        top = [default] if default else list(self.stage.GetPseudoRoot().GetFilteredChildren(self.predicate))
        roots = tuple(i for i in (self.node(p, top=True) for p in top) if i is not None)
        where = f"under <{default.GetPath()}>" if default else "in the stage"
        if not self.meshes:
            skipped = f" ({self.skipped} guide/proxy meshes skipped)" if self.skipped else ""
            raise AssetError(self.path, f"no meshes: no UsdGeom.Mesh prims {where}{skipped}")
        if not any(len(p.faces) for m in self.meshes for p in m.primitives):
            vertices = sum(len(p.positions) for m in self.meshes for p in m.primitives)
            raise AssetError(self.path, f"no triangles ({vertices} vertices, 0 faces) {where}")
        meters = UsdGeom.GetStageMetersPerUnit(self.stage) if UsdGeom.StageHasAuthoredMetersPerUnit(self.stage) else None
        if meters is not None and not (math.isfinite(meters) and meters > 0):
            raise AssetError(self.path, f"metersPerUnit is {meters!r}; it must be a finite number > 0 "
                                        "(fix the layer's metadata, or pass --scale-mm)")
        return Scene(
            source=self.path,
            meshes=tuple(self.meshes),
            nodes=tuple(self.nodes),
            roots=roots,
            materials=tuple(self.materials),
            up_axis="Z" if UsdGeom.GetStageUpAxis(self.stage) == UsdGeom.Tokens.z else "Y",
            meters_per_unit=float(meters) if meters is not None else None,
        )

    def node(self, prim: Usd.Prim, top: bool) -> int | None:
        """Index of the node for `prim`, or None when no mesh lies at or below it."""
        if prim.IsA(UsdGeom.Imageable) and UsdGeom.Imageable(prim).ComputePurpose() in _SKIPPED_PURPOSES:
            self.skipped += sum(1 for p in Usd.PrimRange(prim, self.predicate) if p.IsA(UsdGeom.Mesh))
            return None
        index = len(self.nodes)
        self.nodes.append(None)
        mesh = self.mesh(UsdGeom.Mesh(prim)) if prim.IsA(UsdGeom.Mesh) else None
        children = tuple(
            i for i in (self.node(c, top=False) for c in prim.GetFilteredChildren(self.predicate)) if i is not None
        )
        if mesh is None and not children:
            del self.nodes[index:]
            return None
        self.nodes[index] = Node(prim.GetName(), self.matrix(prim, top), mesh, children)
        return index

    def matrix(self, prim: Usd.Prim, top: bool) -> np.ndarray:
        """(4, 4) column-vector matrix of `prim` relative to its parent node (world for a top node)."""
        if top:
            m = self.xforms.GetLocalToWorldTransform(prim)
        elif not prim.IsA(UsdGeom.Xformable):
            return np.eye(4)
        else:
            m, resets = self.xforms.GetLocalTransformation(prim)
            if resets:
                parent = self.xforms.GetLocalToWorldTransform(prim.GetParent())
                m = self.xforms.GetLocalToWorldTransform(prim) * parent.GetInverse()
        # USD matrices act on row vectors (p' = p M); Scene matrices on column vectors.
        return np.array(m, dtype=np.float64).T

    def mesh(self, mesh: UsdGeom.Mesh) -> int:
        prim = mesh.GetPrim()
        where = f"in mesh '{prim.GetPath()}'"
        points = _array(mesh.GetPointsAttr().Get(self.time), np.float64).reshape(-1, 3)
        counts = _array(mesh.GetFaceVertexCountsAttr().Get(self.time), np.int64)
        indices = _array(mesh.GetFaceVertexIndicesAttr().Get(self.time), np.int64)
        n = len(points)
        bad = int(np.count_nonzero(~np.isfinite(points).all(axis=1)))
        if bad:
            raise AssetError(self.path, f"non-finite vertex positions ({bad} of {n}) {where}")
        if counts.size and counts.min() < 0:
            raise AssetError(self.path, f"negative faceVertexCount {int(counts.min())} {where}")
        if int(counts.sum()) != len(indices):
            raise AssetError(self.path, f"faceVertexCounts sum to {int(counts.sum())} but faceVertexIndices has "
                                        f"{len(indices)} entries {where}")
        if indices.size and indices.min() < 0:
            raise AssetError(self.path, f"negative face index {int(indices.min())} {where}")
        if indices.size and indices.max() >= n:
            raise AssetError(self.path, f"face index {int(indices.max())} out of range for {n} vertices {where}")

        holes = _array(mesh.GetHoleIndicesAttr().Get(self.time), np.int64)
        corners, face_of = _triangulate(counts, holes[(holes >= 0) & (holes < len(counts))])
        if mesh.GetOrientationAttr().Get(self.time) == UsdGeom.Tokens.leftHanded:
            corners = corners[:, [0, 2, 1]]

        data = self.vertex_data(mesh, counts, n, len(indices), where)
        positions, faces, attributes = _split_vertices(points, indices, corners, data)
        uv_names = [name for name in attributes if name.startswith("uv:")]
        normals = attributes.get("normals")
        uvs = tuple(np.column_stack([attributes[k][:, 0], 1.0 - attributes[k][:, 1]]) for k in uv_names)
        colors = None
        if "color" in attributes:
            opacity = attributes.get("opacity", np.ones((len(positions), 1)))
            colors = np.column_stack([attributes["color"], opacity])

        face_material = self.face_materials(mesh, len(counts))
        tri_material = face_material[face_of]
        used = np.unique(tri_material)

        def primitive(keep: np.ndarray, local: np.ndarray, material: int) -> Primitive:
            return Primitive(
                positions=positions[keep],
                faces=local.astype(np.int64),
                normals=None if normals is None else normals[keep],
                uvs=tuple(uv[keep] for uv in uvs),
                colors=None if colors is None else colors[keep],
                material=None if material < 0 else int(material),
            )

        if len(used) <= 1:
            material = used[0] if len(used) else (face_material[0] if len(face_material) else -1)
            primitives = [primitive(np.arange(len(positions)), faces, material)]
        else:
            primitives = []
            for material in used:
                keep, inverse = np.unique(faces[tri_material == material], return_inverse=True)
                primitives.append(primitive(keep, inverse.reshape(-1, 3), material))
        # bound to a skeleton (skel:skeleton, inherited from an ancestor) or carrying blend shapes
        binding = UsdSkel.BindingAPI(prim)
        deforming = bool(binding.GetInheritedSkeleton()) or bool(binding.GetBlendShapeTargetsRel().GetTargets())
        self.meshes.append(Mesh(prim.GetName(), tuple(primitives), deforming=deforming))
        return len(self.meshes) - 1

    def vertex_data(self, mesh: UsdGeom.Mesh, counts: np.ndarray, n: int, corners: int, where: str) -> dict:
        """Normals, texture coordinates and colours as ``name -> (values (k, c), per_corner)``.

        ``per_corner`` False: one row per point (k = n); True: one row per face corner (k =
        `corners`). Constant values are broadcast to the points, uniform ones to the corners.
        """
        api = UsdGeom.PrimvarsAPI(mesh)
        sources: list[tuple[str, UsdGeom.Primvar | None]] = []
        normals_pv = api.GetPrimvar("normals")
        if normals_pv.HasAuthoredValue():
            sources.append(("normals", normals_pv))
        elif mesh.GetNormalsAttr().HasAuthoredValue():
            sources.append(("normals", None))
        uv_names = sorted(
            (pv.GetPrimvarName() for pv in api.GetPrimvarsWithAuthoredValues() if _is_uv(pv)),
            key=lambda name: (name != "st", _natural(name)),
        )
        sources += [(f"uv:{name}", api.GetPrimvar(name)) for name in uv_names]
        color_pv = api.GetPrimvar("displayColor")
        if color_pv.HasAuthoredValue() and color_pv.GetInterpolation() != UsdGeom.Tokens.constant:
            sources.append(("color", color_pv))
            opacity_pv = api.GetPrimvar("displayOpacity")
            if opacity_pv.HasAuthoredValue():
                sources.append(("opacity", opacity_pv))

        out = {}
        for name, pv in sources:
            if pv is None:
                values, interpolation = mesh.GetNormalsAttr().Get(self.time), mesh.GetNormalsInterpolation()
            else:
                if pv.GetElementSize() != 1:
                    raise AssetError(self.path, f"primvar '{pv.GetPrimvarName()}' has elementSize "
                                                f"{pv.GetElementSize()}, only 1 is supported {where}")
                values, interpolation = pv.ComputeFlattened(self.time), pv.GetInterpolation()
                if values is None:
                    raise AssetError(self.path, f"primvar '{pv.GetPrimvarName()}' has indices out of range {where}")
            values = _array(values, np.float64)
            values = values.reshape(len(values), -1)
            label = pv.GetName() if pv is not None else "normals"
            expected = {
                UsdGeom.Tokens.constant: 1, UsdGeom.Tokens.uniform: len(counts), UsdGeom.Tokens.vertex: n,
                UsdGeom.Tokens.varying: n, UsdGeom.Tokens.faceVarying: corners,
            }.get(interpolation)
            if expected is None:
                raise AssetError(self.path, f"{label} has unknown interpolation {interpolation!r} {where}")
            if len(values) != expected:
                raise AssetError(self.path, f"{label} has {len(values)} values, {interpolation} interpolation "
                                            f"needs {expected} {where}")
            if not np.all(np.isfinite(values)):
                raise AssetError(self.path, f"{label} has non-finite values {where}")
            if interpolation == UsdGeom.Tokens.constant:
                out[name] = (np.repeat(values, n, axis=0), False)
            elif interpolation == UsdGeom.Tokens.uniform:
                out[name] = (np.repeat(values, counts, axis=0), True)
            else:
                out[name] = (values, interpolation == UsdGeom.Tokens.faceVarying)
        return out

    def face_materials(self, mesh: UsdGeom.Mesh, faces: int) -> np.ndarray:
        """(faces,) int64 material index per polygon, -1 for none."""
        binding = UsdShade.MaterialBindingAPI(mesh.GetPrim())
        double_sided = bool(mesh.GetDoubleSidedAttr().Get(self.time))
        fallback = self.material(binding.ComputeBoundMaterial()[0], double_sided)
        if fallback < 0:
            fallback = self.display_color_material(mesh)
        out = np.full(faces, fallback, dtype=np.int64)
        for subset in binding.GetMaterialBindSubsets():
            material = self.material(UsdShade.MaterialBindingAPI(subset.GetPrim()).ComputeBoundMaterial()[0],
                                     double_sided)
            if material >= 0:
                ids = _array(subset.GetIndicesAttr().Get(self.time), np.int64)
                out[ids[(ids >= 0) & (ids < faces)]] = material
        return out

    def material(self, material: UsdShade.Material, double_sided: bool) -> int:
        """Index of the SourceMaterial for a bound material, -1 when there is none."""
        if not material:
            return -1
        key = (str(material.GetPath()), double_sided)
        if key not in self.material_index:
            self.material_index[key] = len(self.materials)
            self.materials.append(self.source_material(material, double_sided))
        return self.material_index[key]

    def source_material(self, material: UsdShade.Material, double_sided: bool) -> SourceMaterial:
        values = dict(_PREVIEW_DEFAULTS)
        ior = None
        shader = material.ComputeSurfaceSource()[0]
        if shader and shader.GetIdAttr().Get() == "UsdPreviewSurface":
            for name in (*_PREVIEW_DEFAULTS, "ior"):
                inp = shader.GetInput(name)
                value = inp.Get(self.time) if inp and not inp.HasConnectedSource() else None
                if value is not None:
                    values[name] = tuple(float(c) for c in value) if isinstance(value, Gf.Vec3f) else float(value)
                    if name == "ior":
                        ior = float(value)
        prim = material.GetPrim()
        volume = diffuse_transmission = None
        fb = {name: prim.GetAttribute("sss:fallback:" + name).Get() for name in (
            "thicknessFactor", "attenuationColor", "attenuationDistance",
            "diffuseTransmissionFactor", "diffuseTransmissionColor")}
        if fb["thicknessFactor"] is not None and fb["attenuationColor"] is not None:
            volume = {"thicknessFactor": float(fb["thicknessFactor"]),
                      "attenuationColor": [float(c) for c in fb["attenuationColor"]]}
            if fb["attenuationDistance"] is not None:
                volume["attenuationDistance"] = float(fb["attenuationDistance"])
        if fb["diffuseTransmissionFactor"] is not None:
            diffuse_transmission = {"diffuseTransmissionFactor": float(fb["diffuseTransmissionFactor"])}
            if fb["diffuseTransmissionColor"] is not None:
                diffuse_transmission["diffuseTransmissionColorFactor"] = [
                    float(c) for c in fb["diffuseTransmissionColor"]]
        return SourceMaterial(
            name=prim.GetName(),
            base_color_factor=(*values["diffuseColor"], values["opacity"]),
            metallic_factor=values["metallic"],
            roughness_factor=values["roughness"],
            emissive_factor=values["emissiveColor"],
            double_sided=double_sided,
            ior=ior,
            volume=volume,
            diffuse_transmission=diffuse_transmission,
        )

    def display_color_material(self, mesh: UsdGeom.Mesh) -> int:
        """A material for a constant displayColor (and displayOpacity), -1 when there is none."""
        api = UsdGeom.PrimvarsAPI(mesh)
        color_pv = api.GetPrimvar("displayColor")
        if not (color_pv.HasAuthoredValue() and color_pv.GetInterpolation() == UsdGeom.Tokens.constant):
            return -1
        color = _array(color_pv.ComputeFlattened(self.time), np.float64).reshape(-1)
        opacity_pv = api.GetPrimvar("displayOpacity")
        opacity = _array(opacity_pv.ComputeFlattened(self.time), np.float64).reshape(-1) \
            if opacity_pv.HasAuthoredValue() and opacity_pv.GetInterpolation() == UsdGeom.Tokens.constant else [1.0]
        if color.size != 3 or len(opacity) != 1 or not np.all(np.isfinite(color)):
            return -1
        rgba = (*(float(c) for c in color), float(opacity[0]))
        key = ("displayColor", rgba)
        if key not in self.material_index:
            self.material_index[key] = len(self.materials)
            self.materials.append(SourceMaterial("displayColor", base_color_factor=rgba,
                                                 double_sided=bool(mesh.GetDoubleSidedAttr().Get(self.time))))
        return self.material_index[key]


def _triangulate(counts: np.ndarray, holes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Fan triangulation of polygons.

    Parameters
    ----------
    counts : (f,) int
        Corners per polygon.
    holes : (h,) int
        Polygons to leave out.

    Returns
    -------
    corners : (t, 3) int64
        Indices into the face-vertex (corner) list.
    face_of : (t,) int64
        Polygon of each triangle.
    """
    starts = np.cumsum(counts) - counts
    per_face = np.maximum(counts - 2, 0)
    per_face[holes] = 0
    face_of = np.repeat(np.arange(len(counts)), per_face)
    k = np.arange(len(face_of)) - np.repeat(np.cumsum(per_face) - per_face, per_face)
    first = starts[face_of]
    return np.stack([first, first + k + 1, first + k + 2], axis=1), face_of


def _split_vertices(points: np.ndarray, indices: np.ndarray, corners: np.ndarray,
                    data: dict) -> tuple[np.ndarray, np.ndarray, dict]:
    """Output vertices, faces and per-vertex data.

    Parameters
    ----------
    points : (n, 3) float64
    indices : (c,) int64
        faceVertexIndices: the point of each corner.
    corners : (t, 3) int64
        Triangles as corner indices.
    data : dict
        name -> (values (n or c, k), per_corner), see `_Reader.vertex_data`.

    Returns
    -------
    positions : (v, 3) float64
    faces : (t, 3) int64
    attributes : dict
        name -> (v, k) float64.
    """
    if not any(per_corner for _, per_corner in data.values()):
        return points, indices[corners], {name: values for name, (values, _) in data.items()}
    # Per-corner vertices, welded where the point and every attribute agree exactly.
    columns = [indices[:, None].astype(np.float64)]
    columns += [values if per_corner else values[indices] for values, per_corner in data.values()]
    rows = np.concatenate(columns, axis=1)
    _, first, inverse = np.unique(rows, axis=0, return_index=True, return_inverse=True)
    inverse = inverse.reshape(-1)
    attributes = {}
    for name, (values, per_corner) in data.items():
        attributes[name] = values[first] if per_corner else values[indices[first]]
    return points[indices[first]], inverse[corners], attributes


def _is_uv(pv: UsdGeom.Primvar) -> bool:
    """Texture coordinates: texCoord2 primvars, or float2/double2 ones named st<k>."""
    type_name = str(pv.GetTypeName())
    if type_name in ("texCoord2f[]", "texCoord2d[]", "texCoord2h[]"):
        return True
    return type_name in ("float2[]", "double2[]") and re.fullmatch(r"st\d*", pv.GetPrimvarName()) is not None


def _natural(name: str) -> tuple:
    return tuple(int(p) if p.isdigit() else p for p in re.split(r"(\d+)", name))


def _array(value, dtype) -> np.ndarray:
    """A Vt array (or None: nothing authored) as a numpy array."""
    return np.zeros(0, dtype=dtype) if value is None else np.asarray(value, dtype=dtype)


def usd_error_message(error: Tf.ErrorException, path: str) -> str:
    """The first USD error of `error` on one line, without C++ namespaces and source locations."""
    # Each error reads "Error in '<function>' at line N in file F : '<message>'", messages may span lines.
    parts = [p.split(" : '", 1)[1] for p in re.split(r"\n\s*Error in ", str(error)) if " : '" in p]
    message = " ".join((parts[0].strip().removesuffix("'") if parts else str(error)).split())
    message = re.sub(r"pxrInternal_[A-Za-z0-9_]*::", "", message)
    return message.replace(f"{path}:", "line ") or type(error).__name__
