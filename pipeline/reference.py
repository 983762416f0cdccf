"""The offline reference every technique's ``verify`` compares against: the dipole sum over exact
vertex pairs (no clustering, no precomputed directions) for one light, with visibility.

    L_c(x_o) = Σ_i Rd_c(|x_i - x_o|) ΔA_i · F_t(η, n_i·ω_i) max(0, n_i·ω_i) vis(x_i) E(x_i) / π

the self term from the exact disc integral, sources within the radius that drops at most
`energy_dropped` of R_d (1e-4 by default, 100× tighter than the bake's). The view-side Fresnel
factor F_t(η, ω_o) is the renderer's, as for the runtime.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from .clean import Surface
from .dipole import DipoleParams, diffuse_reflectance_profile, disc_integral, radius_for_energy
from .fresnel import fresnel_transmittance
from .materials import Material
from .visibility import direction_visibility, point_visibility

#: Vertex pairs evaluated at once (bounds memory: ~100 bytes per pair).
PAIRS_PER_CHUNK = 4_000_000


@dataclass(frozen=True)
class Light:
    """A light in the surface's frame.

    Attributes
    ----------
    kind : str
        ``"directional"`` or ``"point"``.
    direction : (3,) float
        Unit direction towards a directional light.
    position : (3,) float
        Point light position, file units.
    intensity : float
        Irradiance (directional), or irradiance at 1 mm (point; falls off as 1/d², d in mm).
    """

    kind: str = "directional"
    direction: tuple[float, float, float] = (0.0, 0.0, 1.0)
    position: tuple[float, float, float] = (0.0, 0.0, 0.0)
    intensity: float = 1.0

    def __post_init__(self):
        if self.kind not in ("directional", "point"):
            raise ValueError(f"light: kind must be 'directional' or 'point', got {self.kind!r}")
        if self.kind == "directional":
            d = np.asarray(self.direction, dtype=np.float64)
            if d.shape != (3,) or not np.all(np.isfinite(d)) or np.linalg.norm(d) == 0:
                raise ValueError(f"light: direction must be a finite non-zero 3-vector, got {self.direction}")
            object.__setattr__(self, "direction", tuple(d / np.linalg.norm(d)))
        if not (np.isfinite(self.intensity) and self.intensity >= 0):
            raise ValueError(f"light: intensity must be finite and >= 0, got {self.intensity}")


def incident_signal(surface: Surface, mm_per_unit: float, material: Material, light: Light) -> np.ndarray:
    """(n,) F_t(η, n·ω) max(0, n·ω) vis E / π at each vertex for `light`."""
    if light.kind == "directional":
        omega = np.broadcast_to(np.asarray(light.direction), surface.positions.shape)
        visible = direction_visibility(surface.positions, surface.faces, surface.normals,
                                       np.asarray(light.direction)[None, :])[:, 0]
        irradiance = np.full(len(omega), light.intensity)
    else:
        to_light = np.asarray(light.position, dtype=np.float64) - surface.positions
        distance = np.linalg.norm(to_light, axis=1)
        omega = to_light / np.maximum(distance, 1e-300)[:, None]
        visible = point_visibility(surface.positions, surface.faces, surface.normals, np.asarray(light.position))
        irradiance = light.intensity / np.maximum(distance * mm_per_unit, 1e-300) ** 2
    cos = np.clip(np.einsum("ij,ij->i", surface.normals, omega), 0.0, None)
    return fresnel_transmittance(material.eta, cos) * cos * visible * irradiance / np.pi


def reference_scattering(surface: Surface, mm_per_unit: float, material: Material, light: Light,
                         energy_dropped: float = 1e-4) -> np.ndarray:
    """(3, n) float64 scattered radiance at every surface vertex (before the view Fresnel)."""
    p = DipoleParams.from_material(material)
    x = surface.positions * mm_per_unit
    area = surface.vertex_areas * mm_per_unit**2
    source = incident_signal(surface, mm_per_unit, material, light) * area
    radius = radius_for_energy(energy_dropped, p)
    tree = cKDTree(x)
    active = np.flatnonzero(source > 0)
    n = len(x)
    out = np.zeros((3, n))
    if len(active) == 0:
        return out
    # Pairs per target ~ sources within the radius: size the chunks from a sample.
    probe = tree.query_ball_point(x[:: max(1, n // 200)], radius.max(), return_length=True)
    chunk = max(1, int(PAIRS_PER_CHUNK / max(float(np.mean(probe)), 1.0)))
    source_tree = cKDTree(x[active])
    for s in range(0, n, chunk):
        targets = np.arange(s, min(n, s + chunk))
        lists = source_tree.query_ball_point(x[targets], radius.max())
        counts = np.fromiter((len(lst) for lst in lists), dtype=np.int64, count=len(lists))
        if counts.sum() == 0:
            continue
        rows = np.repeat(targets, counts)
        cols = active[np.concatenate([np.asarray(lst, dtype=np.int64) for lst in lists])]
        d = np.linalg.norm(x[rows] - x[cols], axis=1)
        rd = diffuse_reflectance_profile(d, p) * source[cols, None]  # (pairs, 3)
        rd[d[:, None] > radius[None, :]] = 0.0
        own = rows == cols
        # The vertex's own area: the exact disc integral instead of Rd(0) ΔA.
        own_area = area[rows[own]]
        per_area = np.divide(source[rows[own]], own_area, out=np.zeros(len(own_area)), where=own_area > 0)
        rd[own] = disc_integral(np.sqrt(own_area / np.pi), p) * per_area[:, None]
        for c in range(3):
            out[c] += np.bincount(rows, weights=rd[:, c], minlength=n)
    return out
