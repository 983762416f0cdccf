"""What the exporters consume: a cleaned scene plus the scattering data baked for it.

Exporters depend on this data only, never on the stages that made it.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from sssbake.pipeline.core.materials import Material
from sssbake.pipeline.mesh.scene import Scene, TextureRef

SCHEMA_VERSION = "2.1.0"


@dataclass(frozen=True, eq=False)
class VertexAttribute:
    """A per-vertex array of sssbake data.

    The key names the data in every format: glTF attribute ``"_" + key.upper()`` with ``:``
    turned into ``_`` (``thickness`` → ``_THICKNESS``, ``sss:prt:ref`` → ``_SSS_PRT_REF``), USD
    primvar ``primvars:sss:<key>`` with an ``sss:`` prefix of the key not repeated
    (``primvars:sss:thickness``, ``primvars:sss:prt:ref``).

    Attributes
    ----------
    key : str
    data : (n,) or (n, k) float64
        Values in `unit`; finite.
    unit : str
        e.g. ``"mm"``; ``""`` for unitless.
    encoding : str
        How glTF stores it: ``"float32"``, a normalized type ``"snorm8"``, ``"snorm16"``,
        ``"unorm8"``, ``"unorm16"`` (data must then lie in [-1, 1] or [0, 1]), or ``"uint8"``,
        ``"uint16"`` (integers in [0, 255], [0, 65535], e.g. indices). USD's primvar type follows
        from it (`exporters.usd.primvar_layout`).
    description : str
    """

    key: str
    data: np.ndarray
    unit: str = ""
    encoding: str = "float32"
    description: str = ""

    @property
    def gltf_name(self) -> str:
        return "_" + self.key.upper().replace(":", "_")

    @property
    def usd_name(self) -> str:
        return "primvars:sss:" + self.key.removeprefix("sss:")


@dataclass(frozen=True)
class Fallback:
    """Standard-extension parameters that make ordinary viewers look plausible.

    All lengths are in the mesh's file units (what glTF's KHR_materials_volume expects).

    Attributes
    ----------
    base_color : (3,) float
        Linear RGB total diffuse reflectance R_d of the material.
    thickness_texture : TextureRef or None
        Texture whose G channel holds thickness / `thickness_factor` (atlas TEXCOORD set).
    thickness_factor : float
        Largest baked thickness, file units.
    attenuation_color : (3,) float in (0, 1]
    attenuation_distance : float
        File units; light travelling this far is tinted by `attenuation_color`.
    diffuse_transmission_factor : float in [0, 1]
    diffuse_transmission_color : (3,) float in [0, 1]
    ior : float
    transmission_factor : float in [0, 1]
        KHR_materials_transmission's factor: the share of the light the object transmits
        rather than reflects diffusely (0: opaque).
    slab_transmittance : (3,) float in [0, 1]
        Total diffuse transmittance T of a slab of the median thickness, which the diffuse
        transmission lobe carries only in part (`bake.fallback.diffuse_transmission_share`);
        zeros when nothing is transmitted.
    """

    base_color: tuple[float, float, float]
    thickness_texture: TextureRef | None
    thickness_factor: float
    attenuation_color: tuple[float, float, float]
    attenuation_distance: float
    diffuse_transmission_factor: float
    diffuse_transmission_color: tuple[float, float, float]
    ior: float
    transmission_factor: float = 0.0
    slab_transmittance: tuple[float, float, float] = (0.0, 0.0, 0.0)


@dataclass(frozen=True)
class ScatteringMaterial:
    """The scattering parameters assigned to one material of the output scene."""

    material: Material
    fallback: Fallback
    source_name: str
    keep_base_color_texture: bool = True


@dataclass(frozen=True, eq=False)
class BakedAsset:
    """A scene ready for export.

    Attributes
    ----------
    scene : Scene
        Cleaned geometry. Where an atlas was made, primitives are already re-indexed through it
        and the atlas UVs are the last TEXCOORD set; the thickness images and textures are appended.
    vertex_attributes : dict
        ``(mesh index, primitive index) -> tuple[VertexAttribute, ...]``.
    scattering : dict
        Scene material index -> ScatteringMaterial; materials not listed are opaque.
    scale_mm : dict
        Mesh index -> millimetres per file unit in world space (node scale included).
    extras : dict
        Asset-level JSON written into the root's ``SSSBAKE_subsurface`` extension (glTF; schema
        version added by exporters).
    mesh_extras : dict
        Mesh index -> JSON-able dict of technique data for that mesh (e.g. ``{"prt": {...}}``),
        written into the mesh's ``SSSBAKE_subsurface`` extension (glTF) and onto each of its USD Mesh prims.
        Numpy arrays in it become binary tables (glTF accessors, USD array attributes).
    material_extras : dict
        Scene material index -> JSON-able dict of technique data for that material (e.g.
        ``{"screen": {...}}``), written into the material's ``SSSBAKE_subsurface`` extension (glTF) and onto its
        USD Material prim (``sss:extras`` JSON, tables as ``sss:<technique>:<key>`` attributes).
    """

    scene: Scene
    vertex_attributes: dict[tuple[int, int], tuple[VertexAttribute, ...]] = field(default_factory=dict)
    scattering: dict[int, ScatteringMaterial] = field(default_factory=dict)
    scale_mm: dict[int, float] = field(default_factory=dict)
    extras: dict = field(default_factory=dict)
    mesh_extras: dict[int, dict] = field(default_factory=dict)
    material_extras: dict[int, dict] = field(default_factory=dict)


def check_material_references(asset: BakedAsset) -> None:
    """Raise ValueError when `asset.scattering` or `asset.material_extras` names a material the
    scene lacks, or technique data sits on a material with no scattering material."""
    count = len(asset.scene.materials)
    for what, refs in (("scattering", asset.scattering), ("material_extras", asset.material_extras)):
        unknown = set(refs) - set(range(count))
        if unknown:
            raise ValueError(f"{what} refers to materials {sorted(unknown)} not in the scene")
    bare = sorted(set(asset.material_extras) - set(asset.scattering))
    if bare:
        raise ValueError(f"material_extras of materials {bare} that have no scattering material")


def index_table(values: np.ndarray) -> np.ndarray:
    """Non-negative indices as uint16 when they fit (the exporters store uint16 as is), else int64
    (stored as uint32)."""
    values = np.asarray(values)
    return values.astype(np.uint16 if values.size == 0 or values.max() < 65536 else np.int64, copy=False)


#: Components of every vertex attribute sssbake writes, all float32: Blender's glTF importer (4.5)
#: keeps custom attributes exactly only as float32 (others it drops or turns into 8-bit sRGB
#: colours), and crashes, depending on the hash seed, on a mesh whose custom attributes differ in
#: width; Bevy and Godot take float32 of any width (benchmarks/README.md#vertex-attribute-encodings).
ATTRIBUTE_WIDTH = 3
#: Integers float32 holds exactly: ids stored in float attributes stay below this.
FLOAT_INTEGERS = 1 << 24


def padded(values: np.ndarray) -> np.ndarray:
    """(p, `ATTRIBUTE_WIDTH`) float64: (p,) or (p, k <= 3) values with zero columns appended."""
    values = np.asarray(values, dtype=np.float64)
    values = values.reshape(len(values), -1)
    if values.shape[1] > ATTRIBUTE_WIDTH:
        raise ValueError(f"vertex attribute with {values.shape[1]} components; at most {ATTRIBUTE_WIDTH}")
    return np.pad(values, ((0, 0), (0, ATTRIBUTE_WIDTH - values.shape[1])))


def welded_vertex_attribute(key: str, vertices: np.ndarray, count: int, description: str) -> VertexAttribute:
    """A per-vertex attribute holding each render vertex's welded surface vertex.

    Parameters
    ----------
    key : str
    vertices : (p,) int64
        The welded vertex of each render vertex of the primitive (``Surface.weld[j][vmapping]``).
    count : int
        Welded surface vertices of the mesh, below `FLOAT_INTEGERS`.
    description : str

    Returns
    -------
    VertexAttribute
        (p, 3) float32 ``(vertex, 0, 0)`` (`ATTRIBUTE_WIDTH`; float32 holds the ids exactly).
    """
    vertices = np.asarray(vertices, dtype=np.int64)
    if vertices.ndim != 1 or (vertices.size and (vertices.min() < 0 or vertices.max() >= count)):
        raise ValueError(f"{key}: vertices must be (p,) indices of the {count} welded vertices")
    if count > FLOAT_INTEGERS:
        raise ValueError(f"{key}: {count} welded vertices; float32 vertex attributes hold ids below {FLOAT_INTEGERS}")
    return VertexAttribute(key, padded(vertices), "", "float32", description)
