"""The offline reference every technique's ``verify`` compares against: the diffusion profile's sum over exact
vertex pairs (no clustering, no precomputed directions) for one light, with visibility.

    L_c(x_o) = Σ_i ∫_{cell_i} Rd_c(|p - x_o|) dp · F_t(η, n_i·ω_i) max(0, n_i·ω_i) vis(x_i) E(x_i) / π

with the cells' integrals as in the bake (`near_field`), no source sending out more than R_d,
sources within the radius that drops at most `energy_dropped` of R_d (1e-4 by default, 100×
tighter than the bake's). The view-side Fresnel
factor F_t(η, ω_o) is the renderer's, as for the runtime.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from sssbake.pipeline.core.profile import profile_for, profile_total, radius_for_energy
from sssbake.pipeline.core.fresnel import fresnel_transmittance
from sssbake.pipeline.core.materials import Material
from sssbake.pipeline.core.near_field import NearField
from sssbake.pipeline.core.scatter_operator import ScatterOptions, scatter_operator
from sssbake.pipeline.core.surface import Surface
from sssbake.pipeline.core.visibility import direction_visibility, point_visibility

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
                         energy_dropped: float = 1e-4, clustered: bool = False) -> np.ndarray:
    """(3, n) float64 scattered radiance at every surface vertex (before the view Fresnel).

    The exact pair sum costs O(n · sources within the radius): ~4-5 minutes for 50k marble
    vertices at 10 mm/unit. ``clustered=True`` sums far sources through the bake's clusters
    instead, in float64 at separation 3 (~1e-3 of q from the exact sum), for meshes where the
    exact sum would take hours; the near field and energy limit are the same.
    """
    scattered = _scattering(surface, mm_per_unit, material, light, energy_dropped, clustered)
    if material.back_gain == (1.0, 1.0, 1.0):
        return scattered
    return scattered * back_gain(surface, material, light)


def back_gain(surface: Surface, material: Material, light: Light) -> np.ndarray:
    """(3, n) factor of light from behind each vertex's tangent plane (`Material.back_gain`), 1 in front:
    that light crossed the object (core.back_share)."""
    if material.back_gain == (1.0, 1.0, 1.0):
        return np.ones((3, len(surface.positions)))
    towards = (np.broadcast_to(np.asarray(light.direction), surface.positions.shape) if light.kind == "directional"
               else np.asarray(light.position, dtype=np.float64) - surface.positions)
    behind = np.einsum("ij,ij->i", surface.normals, towards) < 0.0
    return np.where(behind[None, :], np.asarray(material.back_gain)[:, None], 1.0)


def _scattering(surface: Surface, mm_per_unit: float, material: Material, light: Light, energy_dropped: float,
                clustered: bool) -> np.ndarray:
    """`reference_scattering` before the back gain."""
    p = profile_for(material)
    x = surface.positions * mm_per_unit
    if clustered:
        options = ScatterOptions(energy_dropped=energy_dropped, separation=3, float32=False)
        operator = scatter_operator(x, surface.faces, surface.normals, p, options)
        return operator.apply(incident_signal(surface, mm_per_unit, material, light)[:, None])[:, :, 0]
    field = NearField.build(x, surface.faces, surface.normals, p)
    irradiance = incident_signal(surface, mm_per_unit, material, light)
    radius = radius_for_energy(energy_dropped, p)
    active = np.flatnonzero(irradiance * field.area > 0)
    if len(active) == 0:
        return np.zeros((3, len(x)))
    out, fraction = _gather(field, np.repeat(irradiance[active, None], 3, axis=1), active, radius)
    # As in the bake (`scatter_operator._limit_energy`): a source sending out more than R_d in
    # all is scaled down as a whole.
    limit = (1.0 - 1e-6) * profile_total(p)[None, :]
    over = np.flatnonzero((fraction > limit).any(axis=1))
    if len(over):
        cut = 1.0 - np.minimum(1.0, limit / np.maximum(fraction[over], 1e-300))  # share taken away
        less, _ = _gather(field, irradiance[active[over], None] * cut, active[over], radius)
        out -= less
    return np.maximum(out, 0.0)


def _gather(field: NearField, signal: np.ndarray, sources: np.ndarray,
            radius: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Σ_i W_c(o, i) signal_ic over `sources` at every vertex o, W = ∫_{cell_i} Rd_c(|p - x_o|) dp
    (`NearField.weights`), and each source's outgoing fraction Σ_o ΔA_o W_c(o, i) / ΔA_i.

    Parameters
    ----------
    signal : (s, 3) float64
        Irradiance entering per unit area, per source and channel.
    sources : (s,) int64

    Returns
    -------
    out : (3, n) float64
    fraction : (s, 3) float64
    """
    x, area = field.positions, field.area
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
        d = np.linalg.norm(x[rows] - x[cols], axis=1)
        weight = field.weights(rows, cols)
        for c in range(3):
            w = np.where(d <= radius[c], weight[:, c], 0.0)
            out[c] += np.bincount(rows, weights=w * signal[which, c], minlength=n)
            fraction[:, c] += np.bincount(which, weights=w * area[rows], minlength=len(sources))
    fraction /= np.where(area[sources] > 0, area[sources], 1.0)[:, None]
    return out, fraction
