"""How the spectral technique's normals (Patro 2007) are laid out in the exported files.

Per render vertex (glTF attribute / USD primvar): ``sss:normal`` → ``_SSS_NORMAL`` /
``primvars:sss:normal``, the spectral subsurface normal, VEC3 float32 (snorm16 would be 8 bytes
instead of 12, but Blender drops it and Bevy has no 3 x 16-bit vertex format); with the basis
exported also ``sss:spectral:vertex`` → ``_SSS_SPECTRAL_VERTEX``, the welded surface vertex of the
render vertex (what the tables' rows are), laid out as ``_SSS_KERNELS_VERTEX`` is
(`baked.welded_vertex_attribute`).

Per mesh, with the basis exported, under ``extras.sssbake.spectral`` (glTF: accessors; USD: table
attributes on each Mesh prim of the mesh), see `spectral_tables`: the spectrum of the normal field,
from which a runtime filters again for another width (`spectral_normals.NormalSpectrum.filtered`).

`normals_variant` makes the asset of ``<stem>.sss_normals.glb``: standard NORMAL replaced by the
spectral normal, so that a stock viewer shows the effect.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from sssbake.pipeline.mesh.baked import BakedAsset, VertexAttribute, welded_vertex_attribute
from sssbake.pipeline.mesh.scene import Mesh
from sssbake.pipeline.techniques.spectral.normals import NormalSpectrum

NORMAL_KEY, VERTEX_KEY = "sss:normal", "sss:spectral:vertex"
NORMAL_ATTRIBUTE = VertexAttribute(NORMAL_KEY, np.zeros(0)).gltf_name
VERTEX_ATTRIBUTE = VertexAttribute(VERTEX_KEY, np.zeros(0)).gltf_name
#: Vertex attributes the normals variant keeps: the fallback's and the normal itself (every other
#: technique's attributes index tables the variant does not carry).
VARIANT_KEYS = ("thickness", NORMAL_KEY)

#: Bytes per render vertex of ``_SSS_NORMAL`` and of ``_SSS_SPECTRAL_VERTEX`` (VEC3 float32 each).
NORMAL_BYTES, VERTEX_BYTES = 12, 12


def spectral_vertex_attributes(normals: np.ndarray, vertices: np.ndarray,
                               with_vertex: bool) -> tuple[VertexAttribute, ...]:
    """The per-vertex attributes of one primitive.

    Parameters
    ----------
    normals : (n, 3) float64
        Unit spectral normals of the mesh's welded surface vertices.
    vertices : (p,) int64
        The welded vertex of each render vertex of the primitive (``Surface.weld[j][vmapping]``).
    with_vertex : bool
        Also ``sss:spectral:vertex`` (when the tables are exported).

    Returns
    -------
    tuple of VertexAttribute
        ``sss:normal`` (p, 3) float32, then ``sss:spectral:vertex``.
    """
    vertices = np.asarray(vertices, dtype=np.int64)
    # first: it refuses vertices outside the surface with a clear message
    ids = (welded_vertex_attribute(VERTEX_KEY, vertices, len(normals),
                                   "welded surface vertex of the render vertex (spectral tables); components "
                                   "1, 2 are 0"),) if with_vertex else ()
    return (VertexAttribute(NORMAL_KEY, normals[vertices], "", "float32",
                            "spectral subsurface normal (Patro 2007)"),) + ids


def spectral_tables(spectrum: NormalSpectrum, width_mm: float, gamma: float) -> dict:
    """The per-mesh tables and parameters, JSON-able with numpy arrays for the binary tables.

    Parameters
    ----------
    spectrum : NormalSpectrum
        Over the mesh's n welded surface vertices, m harmonics.
    width_mm, gamma : float
        The filter the bake applied and its residual factor.

    Returns
    -------
    dict
        Parameters ``technique`` ("spectral"), ``vertexCount`` (n), ``eigenpairs`` (m),
        ``widthMm``, ``gamma``, ``nyquist`` (ω_M, 1/mm), ``attributes`` {``normal``:
        ``_SSS_NORMAL``, ``vertex``: ``_SSS_SPECTRAL_VERTEX``}, ``units``; tables (float32)
        ``values`` (m,) λ, ``coefficients`` (m, 3) η, ``residual`` (n, 3) Δn, ``basis`` (n·m,) Φ
        row-major (row j·m + k: φ_k at vertex j; a glTF accessor has at most 4 columns).
    """
    n, m = spectrum.basis.shape
    return {
        "technique": "spectral",
        "vertexCount": int(n),
        "eigenpairs": int(m),
        "widthMm": float(width_mm),
        "gamma": float(gamma),
        "nyquist": float(spectrum.nyquist),
        "attributes": {"normal": NORMAL_ATTRIBUTE, "vertex": VERTEX_ATTRIBUTE},
        "units": "values: 1/mm^2; nyquist: 1/mm; widthMm: mm; basis: 1/mm (orthonormal under the lumped vertex areas "
                 "in mm^2); coefficients: mm; residual: unitless",
        "values": spectrum.values.astype(np.float32),
        "coefficients": spectrum.coefficients.astype(np.float32),
        "residual": spectrum.residual.astype(np.float32),
        "basis": spectrum.basis.astype(np.float32).reshape(-1),
    }


def spectral_bytes(vertices: int, eigenpairs: int, with_tables: bool) -> dict:
    """Bytes the spectral data spends in the glTF binary (float32 tables; USD the same).

    Parameters
    ----------
    vertices, eigenpairs : int
        n welded surface vertices, m harmonics.
    with_tables : bool
        Whether the tables (and ``_SSS_SPECTRAL_VERTEX``) are exported.

    Returns
    -------
    dict
        One int per table (``values``, ``coefficients``, ``residual``, ``basis``; 0 when not
        exported), ``total`` (their sum), ``perVertex`` (total / n), and per render vertex, not
        in ``total``: ``normalPerRenderVertex`` (`NORMAL_BYTES`), ``vertexIdsPerRenderVertex``
        (`VERTEX_BYTES`, 0 without the tables).
    """
    n, m = vertices, eigenpairs
    sizes = {"values": 4 * m, "coefficients": 12 * m, "residual": 12 * n, "basis": 4 * n * m}
    out = {name: size if with_tables else 0 for name, size in sizes.items()}
    total = sum(out.values())
    out.update(total=total, perVertex=total / n, normalPerRenderVertex=NORMAL_BYTES,
               vertexIdsPerRenderVertex=VERTEX_BYTES if with_tables else 0)
    return out


def normals_variant(asset: BakedAsset) -> BakedAsset:
    """`asset` for stock viewers: NORMAL replaced by ``sss:normal`` wherever a primitive has it.

    Keeps the geometry, materials (the standard fallback), textures and the `VARIANT_KEYS`
    attributes; drops the per-mesh technique tables, which no stock viewer reads, and the
    attributes that index them. The asset extras get ``variant``: ``"sss_normals"``.
    """
    meshes = list(asset.scene.meshes)
    attributes = {}
    for (mi, pi), attrs in asset.vertex_attributes.items():
        attributes[(mi, pi)] = tuple(a for a in attrs if a.key in VARIANT_KEYS)
        normal = next((a for a in attrs if a.key == NORMAL_KEY), None)
        if normal is not None:
            prims = list(meshes[mi].primitives)
            prims[pi] = replace(prims[pi], normals=normal.data)
            meshes[mi] = Mesh(meshes[mi].name, tuple(prims))
    return replace(asset, scene=replace(asset.scene, meshes=tuple(meshes)), vertex_attributes=attributes,
                   mesh_extras={}, material_extras={}, extras={**asset.extras, "variant": "sss_normals"})
