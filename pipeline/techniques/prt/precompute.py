"""The prt precompute (Hao & Varshney 2004 §3): per vertex and light direction, the scattered
radiance per unit irradiance

    q_j(x_o) = Σ_i F_t(η, n_i·ω_j) (1/π) Rd(|x_i - x_o|) max(0, n_i·ω_j) vis_j(x_i) ΔA(x_i)

for K directions, each colour channel separately.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numba
import numpy as np

from sssbake.pipeline.core.profile import profile_for
from sssbake.pipeline.core.freed_memory import release_freed_memory
from sssbake.pipeline.core.materials import Material
from sssbake.pipeline.core.scatter_operator import SCATTER_DEFAULTS, ScatterOperator, ScatterOptions, scatter_operator
from sssbake.pipeline.core.surface import Surface
from sssbake.pipeline.core.visibility import direction_visibility


@dataclass(frozen=True)
class PrtPrecomputeOptions:
    """Attributes
    ----------
    scatter : ScatterOptions
        The gather's energy bound and hierarchy.
    chunk : int
        Most directions gathered at once (bounds temporary memory); the K directions go in
        chunks of equal size. 64, the scatter's threads × block, is one pass of
        `ScatterOperator.apply` over the operator (benchmarks/README.md#prt-precompute-chunk).
    """

    scatter: ScatterOptions = SCATTER_DEFAULTS
    chunk: int = 64


PRT_PRECOMPUTE_DEFAULTS = PrtPrecomputeOptions()


@dataclass(frozen=True, eq=False)
class PrtIntegrals:
    """Attributes
    ----------
    q : (3, n, K) float32 or float64
        Radiance per unit irradiance (1/sr) per channel, surface vertex and direction, in the
        gather's dtype (`ScatterOptions.float32`): its products round to float32 already, so a
        float32 q is exact and half the stage's largest array (0.5 GB at 200k vertices, K = 200).
        A view of a vertex-major (n, 3, K) array.
    directions : (K, 3) float64
    radius_mm : (3,) float64
        Gather radius per channel.
    dropped_fraction : (3,) float64
        Fraction of R_d beyond the radius.
    seconds : dict
        ``visibility``, ``operator``, ``gather``.
    stats : dict
        The operator's statistics, its entries and bytes.
    """

    q: np.ndarray
    directions: np.ndarray
    radius_mm: np.ndarray
    dropped_fraction: np.ndarray
    seconds: dict = field(default_factory=dict)
    stats: dict = field(default_factory=dict)


def irradiance_signal(normals: np.ndarray, directions: np.ndarray, visible: np.ndarray, eta: float) -> np.ndarray:
    """(n, K) F_t(η, n·ω) max(0, n·ω) vis / π: what each vertex lets into the material per unit
    irradiance from each direction.

    Compiled (`_transmitted`): numpy's ~15 passes over (n, K) temporaries for the Fresnel factor
    took a third of the gather's time; the numpy form is kept in tests as the oracle."""
    out = np.empty((len(normals), len(directions)))
    _transmitted(np.asarray(normals, dtype=np.float64) @ np.asarray(directions, dtype=np.float64).T,
                 np.asarray(visible, dtype=bool), float(eta), out)
    return out


@numba.njit(cache=True, nogil=True)
def _transmitted(dots, visible, eta, out):
    """out = F_t(η, cos) cos vis / π with cos = max(0, dots), operation for operation as
    `fresnel.fresnel_transmittance` (so equal bit for bit)."""
    for v in range(dots.shape[0]):
        for j in range(dots.shape[1]):
            if not visible[v, j]:
                out[v, j] = 0.0
                continue
            cos = max(dots[v, j], 0.0)
            ci = min(cos, 1.0)
            ct = math.sqrt(min(max(1.0 - (1.0 - ci * ci) / (eta * eta), 0.0), 1.0))
            rs = rp = 1.0  # grazing incidence: total reflection
            if ci > 0.0:
                rs = (ci - eta * ct) / (ci + eta * ct)
                rp = (eta * ci - ct) / (eta * ci + ct)
            out[v, j] = min(max(1.0 - 0.5 * (rs * rs + rp * rp), 0.0), 1.0) * cos / np.pi


def precompute_prt(surface: Surface, mm_per_unit: float, material: Material, directions: np.ndarray,
                   options: PrtPrecomputeOptions = PRT_PRECOMPUTE_DEFAULTS,
                   operator: ScatterOperator | None = None) -> PrtIntegrals:
    """q for every surface vertex and direction.

    Parameters
    ----------
    surface : Surface
        Welded surface, file units.
    mm_per_unit : float
    material : Material
    directions : (K, 3) float64
        Unit directions towards the lights, in the surface's frame.
    options : PrtPrecomputeOptions
    operator : ScatterOperator, optional
        A gather already built for this surface and material (sweeps reuse it).
    """
    if not (np.isfinite(mm_per_unit) and mm_per_unit > 0):
        raise ValueError(f"prt: mm_per_unit must be a positive finite number, got {mm_per_unit}")
    directions = np.asarray(directions, dtype=np.float64)
    seconds = {}
    t = time.perf_counter()
    visible = direction_visibility(surface.positions, surface.faces, surface.normals, directions)
    seconds["visibility"] = time.perf_counter() - t
    params = profile_for(material)
    t = time.perf_counter()
    if operator is None:
        operator = scatter_operator(surface.positions * mm_per_unit, surface.faces, surface.normals, params,
                                    options.scatter)
    seconds["operator"] = time.perf_counter() - t
    t = time.perf_counter()
    # Vertex-major memory under the (3, n, K) view: the compression reads q a vertex (3·K
    # values) at a time, gathered rows then copy whole contiguous runs.
    q = np.empty((len(surface.positions), 3, len(directions)), dtype=operator.near.dtype).transpose(1, 0, 2)
    edges = np.linspace(0, len(directions), -(-len(directions) // options.chunk) + 1).round().astype(int)
    for a, b in zip(edges[:-1], edges[1:]):
        block = slice(a, b)
        signal = irradiance_signal(surface.normals, directions[block], visible[:, block], material.eta)
        operator.apply(signal, out=q[:, :, block])
        if material.back_gain != (1.0, 1.0, 1.0):  # light from behind a vertex crossed the object (core.back_share)
            behind = surface.normals @ directions[block].T < 0.0
            for c, gain in enumerate(material.back_gain):  # a channel at a time: float32 factors, not a (3, n, chunk) array
                q[c, :, block] *= np.where(behind, np.float32(gain), np.float32(1.0))
        release_freed_memory()  # the threads' temporaries stay in their arenas otherwise (~0.9 GB at 150k)
    seconds["gather"] = time.perf_counter() - t
    stats = {**{k: v for k, v in operator.stats.items() if k != "seconds"}, "entries": operator.nnz,
             "operator_bytes": operator.nbytes, "visible_fraction": float(visible.mean())}
    return PrtIntegrals(q, directions, operator.radius_mm, operator.dropped_fraction, seconds, stats)
