"""Source data of an asset as read from disk: meshes, node hierarchy, materials, textures.

Derived data (welded surfaces, areas, thickness, atlases) lives in the stages' own dataclasses;
nothing here is computed.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass(frozen=True)
class Image:
    """An encoded image kept byte-for-byte for re-export.

    Attributes
    ----------
    name : str
    mime_type : str
        ``image/png`` or ``image/jpeg``.
    data : bytes
    """

    name: str
    mime_type: str
    data: bytes


@dataclass(frozen=True)
class Texture:
    """A texture reference: an image plus sampler state (glTF enums)."""

    image: int
    mag_filter: int | None = None
    min_filter: int | None = None
    wrap_s: int = 10497
    wrap_t: int = 10497


#: The glTF extension a `TextureTransform` is read from and written back as.
TEXTURE_TRANSFORM = "KHR_texture_transform"


@dataclass(frozen=True)
class TextureTransform:
    """A texture slot's glTF KHR_texture_transform: uv' = translate(offset) rotate(rotation) scale(scale) uv.

    Attributes
    ----------
    offset, scale : (float, float)
    rotation : float
        Radians, counter-clockwise in UV space.
    tex_coord : int or None
        The TEXCOORD set the transform reads instead of the slot's own (None: the slot's).
    """

    offset: tuple[float, float] = (0.0, 0.0)
    rotation: float = 0.0
    scale: tuple[float, float] = (1.0, 1.0)
    tex_coord: int | None = None

    def to_json(self) -> dict:
        """The extension object, defaults left out."""
        out: dict = {}
        if self.offset != (0.0, 0.0):
            out["offset"] = list(self.offset)
        if self.rotation != 0.0:
            out["rotation"] = self.rotation
        if self.scale != (1.0, 1.0):
            out["scale"] = list(self.scale)
        if self.tex_coord is not None:
            out["texCoord"] = self.tex_coord
        return out


@dataclass(frozen=True)
class TextureRef:
    """A material slot's texture: which texture, which TEXCOORD set and its KHR_texture_transform, if any."""

    texture: int
    tex_coord: int = 0
    transform: TextureTransform | None = None

    @property
    def uv_set(self) -> int:
        """The TEXCOORD set the texture is sampled with (the transform's override, else `tex_coord`)."""
        if self.transform is not None and self.transform.tex_coord is not None:
            return self.transform.tex_coord
        return self.tex_coord


@dataclass(frozen=True)
class SourceMaterial:
    """A surface material as authored (glTF metallic-roughness terms).

    `volume`, `diffuse_transmission` and `volume_scatter` hold the KHR_materials_volume /
    KHR_materials_diffuse_transmission / KHR_materials_volume_scatter (Khronos draft) JSON
    objects of the input when present, so the material stage can map them to scattering parameters.
    """

    name: str
    base_color_factor: tuple[float, float, float, float] = (1.0, 1.0, 1.0, 1.0)
    base_color_texture: TextureRef | None = None
    metallic_factor: float = 0.0
    roughness_factor: float = 0.5
    metallic_roughness_texture: TextureRef | None = None
    normal_texture: TextureRef | None = None
    occlusion_texture: TextureRef | None = None
    emissive_factor: tuple[float, float, float] = (0.0, 0.0, 0.0)
    emissive_texture: TextureRef | None = None
    double_sided: bool = False
    ior: float | None = None
    volume: dict | None = None
    diffuse_transmission: dict | None = None
    volume_scatter: dict | None = None


@dataclass(frozen=True, eq=False)
class Primitive:
    """One triangle list with one material, as stored (seams split vertices).

    Attributes
    ----------
    positions : (n, 3) float64
        File units, in the mesh's local frame.
    faces : (m, 3) int64
    normals : (n, 3) float64 or None
    uvs : tuple of (n, 2) float64
        TEXCOORD_0, TEXCOORD_1, ... in glTF convention (v down from the image's top).
    colors : (n, 4) float64 or None
    material : int or None
        Index into ``Scene.materials``.
    tangents : (n, 4) float64 or None
        glTF TANGENT: unit xyz and handedness w = ±1, bitangent = cross(normal, xyz) * w.
    """

    positions: np.ndarray
    faces: np.ndarray
    normals: np.ndarray | None = None
    uvs: tuple[np.ndarray, ...] = ()
    colors: np.ndarray | None = None
    material: int | None = None
    tangents: np.ndarray | None = None


@dataclass(frozen=True)
class Mesh:
    """A named object made of one or more primitives, sharing one local frame.

    Attributes
    ----------
    deforming : bool
        The file deforms it at runtime (glTF skin or morph targets, USD skeleton binding or
        blend shapes): a per-vertex bake of its rest pose would not hold.
    """

    name: str
    primitives: tuple[Primitive, ...]
    deforming: bool = False


@dataclass(frozen=True, eq=False)
class Node:
    """A node of the scene graph.

    Attributes
    ----------
    matrix : (4, 4) float64
        Local transform (column vectors: world = parent @ matrix @ p).
    """

    name: str
    matrix: np.ndarray = field(default_factory=lambda: np.eye(4))
    mesh: int | None = None
    children: tuple[int, ...] = ()


@dataclass(frozen=True)
class Scene:
    """Everything read from one asset file.

    Attributes
    ----------
    source : str
        Path the scene was read from (for error messages and reports).
    roots : tuple of int
        Indices of the root nodes.
    up_axis : str
        ``"Y"`` or ``"Z"`` as the file declares (glTF, OBJ, PLY, STL: ``"Y"``).
    meters_per_unit : float or None
        What the file claims, if anything; never trusted for scattering (the asset's
        ``scale_mm`` decides), but reported.
    warnings : tuple of str
        What the reader went past without refusing (e.g. a GLB chunk of unknown type, which
        the glTF spec says to ignore), one line each, for the asset's report.
    dependencies : tuple of (str, str)
        (real path, SHA-256 of its bytes, `cache.file_digest`) of each file the reader read
        besides `source` (glTF buffers and images, USD layers, OBJ material libraries and
        textures, a PLY's texture), once each, in the order read: the outputs and the cached
        scene are stale when one of them no longer has its digest. The digest is ``""`` for a
        referenced file that was missing and gone without (an OBJ's texture): stale once it exists.
    """

    source: str
    meshes: tuple[Mesh, ...]
    nodes: tuple[Node, ...]
    roots: tuple[int, ...]
    materials: tuple[SourceMaterial, ...] = ()
    textures: tuple[Texture, ...] = ()
    images: tuple[Image, ...] = ()
    up_axis: str = "Y"
    meters_per_unit: float | None = None
    warnings: tuple[str, ...] = ()
    dependencies: tuple[tuple[str, str], ...] = ()

    def world_matrices(self) -> dict[int, np.ndarray]:
        """World transform (4, 4) of every node reachable from the roots."""
        out: dict[int, np.ndarray] = {}
        stack = [(r, np.eye(4)) for r in self.roots]
        while stack:
            i, parent = stack.pop()
            world = parent @ self.nodes[i].matrix
            out[i] = world
            stack.extend((c, world) for c in self.nodes[i].children)
        return out

    def mesh_instances(self) -> dict[int, list[np.ndarray]]:
        """World matrices of every node that instances each mesh, by mesh index."""
        out: dict[int, list[np.ndarray]] = {}
        for i, world in sorted(self.world_matrices().items()):
            m = self.nodes[i].mesh
            if m is not None:
                out.setdefault(m, []).append(world)
        return out
