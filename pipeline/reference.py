"""The offline reference every technique's ``verify`` compares against: the dipole sum over exact
vertex pairs (no clustering, no precomputed directions) for one light, with visibility.

    L_c(x_o) = Σ_i ḡ_c(|x_i - x_o|, a_i) ΔA_i · F_t(η, n_i·ω_i) max(0, n_i·ω_i) vis(x_i) E(x_i) / π

each source's Rd averaged over its area as a disc (`disc_average`), the self term the exact
integral over the vertex's own disc, no source sending out more than R_d, sources within the radius that drops at most
`energy_dropped` of R_d (1e-4 by default, 100× tighter than the bake's). The view-side Fresnel
factor F_t(η, ω_o) is the renderer's, as for the runtime.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from .clean import Surface
from .dipole import DipoleParams, disc_integral, radius_for_energy
from .disc_average import DiscMean
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
    disc = DiscMean.build(p, np.sqrt(area / np.pi))
    active = np.flatnonzero(source > 0)
    if len(active) == 0:
        return np.zeros((3, len(x)))
    normals = surface.normals
    own = disc_integral(np.sqrt(area / np.pi), p)
    out, fraction = _gather(x, area, normals, own, np.repeat(source[active, None], 3, axis=1), active, radius, disc, p)
    # As in the bake (`scatter_operator._limit_energy`): no source sends out more than R_d.
    rd = 0.5 * p.alpha_prime * (np.exp(-p.sigma_tr * p.z_r) + np.exp(-p.sigma_tr * p.z_v))
    excess = fraction - (1.0 - 1e-6) * rd[None, :]
    over = np.flatnonzero((excess > 0).any(axis=1))
    if len(over):
        cut = np.clip(excess[over] / fraction[over], 0.0, 1.0)  # share of each source to take away
        less, _ = _gather(x, area, normals, own, source[active[over], None] * cut, active[over], radius, disc, p)
        out -= less
    return np.maximum(out, 0.0)


def _gather(x: np.ndarray, area: np.ndarray, normals: np.ndarray, own: np.ndarray, weight: np.ndarray,
            sources: np.ndarray, radius: np.ndarray, disc: DiscMean, p: DipoleParams) -> tuple[np.ndarray, np.ndarray]:
    """Σ_i ḡ_c weight_ic over `sources` at every vertex (ḡ: Rd averaged over the source's disc
    in its tangent plane; `own` (n, 3), the integral over its own disc, for the vertex itself),
    and each source's outgoing fraction Σ_o ΔA_o ḡ_c.

    Parameters
    ----------
    weight : (s, 3) float64
        Flux per source and channel (ΔA_i E_i).
    sources : (s,) int64

    Returns
    -------
    out : (3, n) float64
    fraction : (s, 3) float64
    """
    n = len(x)
    out = np.zeros((3, n))
    fraction = np.zeros((len(sources), 3))
    tree = cKDTree(x[sources])
    # Pairs per target ~ sources within the radius: size the chunks from a sample.
    probe = tree.query_ball_point(x[:: max(1, n // 200)], radius.max(), return_length=True)
    chunk = max(1, int(PAIRS_PER_CHUNK / max(float(np.mean(probe)), 1.0)))
    for s in range(0, n, chunk):
        targets = np.arange(s, min(n, s + chunk))
        lists = tree.query_ball_point(x[targets], radius.max())
        counts = np.fromiter((len(lst) for lst in lists), dtype=np.int64, count=len(lists))
        if counts.sum() == 0:
            continue
        rows = np.repeat(targets, counts)
        which = np.concatenate([np.asarray(lst, dtype=np.int64) for lst in lists])
        cols = sources[which]
        delta = x[rows] - x[cols]
        d = np.linalg.norm(delta, axis=1)
        itself = rows == cols
        mean = disc(d, np.sqrt(area[cols] / np.pi), np.abs(np.einsum("ij,ij->i", delta, normals[cols])))
        for c in range(3):
            per_area = mean[:, c]
            per_area[d > radius[c]] = 0.0
            per_area[itself] = np.divide(own[rows[itself], c], area[rows[itself]], out=np.zeros(int(itself.sum())),
                                         where=area[rows[itself]] > 0)
            out[c] += np.bincount(rows, weights=per_area * weight[which, c], minlength=n)
            fraction[:, c] += np.bincount(which, weights=per_area * area[rows], minlength=len(sources))
    return out, fraction
