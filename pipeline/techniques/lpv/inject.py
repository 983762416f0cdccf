"""Injection of the lpv technique (Børlum et al. 2011, §3.1): the flux a light sends through the
texels of a shadow map, entering the object at the surface points the texels see, as one virtual
point light per texel with a clamped-cosine lobe about the refracted direction, summed per cell.

The numpy reference casts the shadow map's rays with embree (`light_samples`); the GLSL runtime
rasterises the same map. A directional light's texel carries irradiance × texel area; a point
light's texel its intensity × the solid angle it subtends, Δω = A cos³θ / f² on a virtual plane at
distance f (the paper's 4α tan²(FOV) cos³θ / (N_x N_y) for a plane at distance 1).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import trimesh
from trimesh.ray.ray_pyembree import RayMeshIntersector

from sssbake.pipeline.core.fresnel import fresnel_transmittance
from sssbake.pipeline.core.reference import Light
from sssbake.pipeline.core.surface import Surface
from sssbake.pipeline.techniques.lpv.data import LpvGrid
from sssbake.pipeline.techniques.lpv.grid import cell_of
from sssbake.pipeline.techniques.lpv.matrices import lpv_basis

#: A clamped-cosine lobe Φ/π max(0, n·ω) about unit n has coefficients Φ · LOBE[l] · y_lm(n):
#: (1/π) ∫ (n·ω) y_lm(ω) dω is y_00 for l = 0 and (2/3) y_1m(n) for l = 1 (Funk-Hecke).
LOBE = np.array([1.0, 2.0 / 3.0])
#: How far, in cells, a surface point moves inwards before its cell is looked up.
INWARD = 1e-3
#: Largest tan(half field of view) of a point light's map (80°), as the renderer's shadow maps.
MAX_TAN = float(np.tan(np.radians(80.0)))


@dataclass(frozen=True, eq=False)
class LightSamples:
    """The surface points a light's shadow map sees, one per covered texel.

    Attributes
    ----------
    positions : (p, 3) float64
        Object-space points, file units.
    normals : (p, 3) float64
        Unit outward normals there (interpolated vertex normals).
    towards : (p, 3) float64
        Unit directions towards the light.
    flux : (p,) float64
        Flux through the texel (irradiance × mm², or intensity × sr).
    """

    positions: np.ndarray
    normals: np.ndarray
    towards: np.ndarray
    flux: np.ndarray


def light_samples(surface: Surface, mm_per_unit: float, light: Light, size: int = 256) -> LightSamples:
    """Cast a `size`² shadow map of `light` over `surface` (its bounding sphere) and keep the hits.

    Parameters
    ----------
    surface : Surface
    mm_per_unit : float
    light : reference.Light
        In the surface's frame: directional (unit irradiance times ``intensity``) or point
        (irradiance ``intensity`` / d², d in mm).
    size : int
        Texels per side.
    """
    if not (isinstance(size, int) and 1 <= size <= 8192):
        raise ValueError(f"lpv inject: shadow map size must be a whole number in [1, 8192], got {size!r}")
    positions = surface.positions
    lo, hi = positions.min(axis=0), positions.max(axis=0)
    centre, radius = 0.5 * (lo + hi), 0.5 * float(np.linalg.norm(hi - lo)) * 1.01
    t = (np.arange(size) + 0.5) / size * 2.0 - 1.0
    u, v = (a.reshape(-1) for a in np.meshgrid(t, t, indexing="xy"))
    if light.kind == "directional":
        forward = -np.asarray(light.direction, dtype=np.float64)
        right, up = _frame(forward)
        origins = centre - 2.0 * radius * forward + radius * (u[:, None] * right + v[:, None] * up)
        rays = np.broadcast_to(forward, origins.shape)
        texel_mm2 = (2.0 * radius / size * mm_per_unit) ** 2
        flux = np.full(len(origins), light.intensity * texel_mm2)
    else:
        source = np.asarray(light.position, dtype=np.float64)
        offset = centre - source
        distance = float(np.linalg.norm(offset))
        forward = offset / distance if distance > 0 else np.array([0.0, 0.0, -1.0])
        gap = distance * distance - radius * radius
        tan_half = min(radius / np.sqrt(gap), MAX_TAN) if gap > 0 else MAX_TAN
        right, up = _frame(forward)
        plane = forward + tan_half * (u[:, None] * right + v[:, None] * up)  # a plane at distance 1
        length = np.linalg.norm(plane, axis=1)
        rays = plane / length[:, None]
        origins = np.broadcast_to(source, rays.shape)
        # Δω = A cos θ / r² with cos θ = 1 / r on the plane at distance 1
        flux = light.intensity * (2.0 * tan_half / size) ** 2 / length**3
    mesh = trimesh.Trimesh(positions, surface.faces, process=False)
    tri, ray, points = RayMeshIntersector(mesh).intersects_id(origins, rays, multiple_hits=False,
                                                              return_locations=True)
    weights = trimesh.triangles.points_to_barycentric(mesh.triangles[tri], points)
    normals = np.einsum("pa,pad->pd", weights, surface.normals[surface.faces[tri]])
    normals /= np.maximum(np.linalg.norm(normals, axis=1), 1e-300)[:, None]
    return LightSamples(points, normals, -rays[ray], flux[ray])


def inject(grid: LpvGrid, samples: LightSamples) -> np.ndarray:
    """The injected intensity per cell: each sample's transmitted flux T Φ as a clamped-cosine
    lobe about its refracted direction, summed in the sample's cell (cells without medium keep
    nothing: the grid puts medium wherever the surface passes).

    Returns
    -------
    (nz, ny, nx, 3, 4) float64
        SH coefficients (`lpv_matrices.lpv_basis` order) per cell and colour channel.
    """
    nx, ny, nz = grid.shape
    out = np.zeros((nz, ny, nx, 4))
    cos_i = np.clip(np.einsum("pd,pd->p", samples.normals, samples.towards), 0.0, 1.0)
    transmitted = fresnel_transmittance(grid.eta, cos_i) * samples.flux
    lobe = transmitted[:, None] * LOBE[[0, 1, 1, 1]] * lpv_basis(refracted(samples.towards, samples.normals,
                                                                            grid.eta))
    # a hair inside, so a point on a cell face between medium and empty space lands in the medium
    cells = cell_of(grid, samples.positions - INWARD * grid.cell * samples.normals)
    inside = np.all(cells >= 0, axis=1)
    flat = np.ravel_multi_index((cells[inside, 2], cells[inside, 1], cells[inside, 0]), (nz, ny, nx))
    for k in range(4):
        out.reshape(-1, 4)[:, k] += np.bincount(flat, weights=lobe[inside, k], minlength=nz * ny * nx)
    out *= (grid.occupancy > 0)[..., None]
    return np.repeat(out[:, :, :, None, :], 3, axis=3)


def refracted(towards: np.ndarray, normals: np.ndarray, eta: float) -> np.ndarray:
    """(p, 3) unit directions of light arriving from unit `towards` (pointing at the light) after
    refraction into a medium of relative index `eta` through a surface of unit outward `normals`
    (Snell; light grazing or from behind goes straight in along -n)."""
    cos_i = np.clip(np.einsum("pd,pd->p", normals, towards), 0.0, 1.0)
    cos_t = np.sqrt(np.clip(1.0 - (1.0 - cos_i**2) / eta**2, 0.0, 1.0))
    out = -towards / eta + (cos_i / eta - cos_t)[:, None] * normals
    return out / np.maximum(np.linalg.norm(out, axis=1), 1e-300)[:, None]


def _frame(forward: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors completing unit `forward` to an orthonormal frame."""
    helper = np.array([0.0, 1.0, 0.0]) if abs(forward[1]) < 0.9 else np.array([0.0, 0.0, 1.0])
    right = np.cross(forward, helper)
    right /= np.linalg.norm(right)
    return right, np.cross(right, forward)
