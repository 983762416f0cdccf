"""A heterogeneous material for the lpv technique: veined marble, a procedural 3-D field.

The vein weight at a point p (mm) is the classic turbulent-sine marble (Perlin 1985):

    w(p) = |cos(π (p·axis / vein_mm + turbulence · fbm(p / vein_mm)))|^sharpness   in [0, 1],

so without turbulence the veins (w = 1) are planes normal to `axis`, one every `vein_mm`, and the
fBm (`octaves` octaves of gradient noise, frequency ×2 and amplitude ×½ each) bends them by up to
about `turbulence` vein periods. Over a large region the phase is spread evenly, so the mean weight
is that of |cos|^sharpness over a period, Γ((s + 1)/2) / (√π Γ(s/2 + 1)) (`mean_vein_weight`).

The coefficients blend linearly, σ = (1 - w) σ_base + w σ_vein per channel, so each lies between
the two materials' values. The default vein material (`vein_material=None`) is the base with
`VEIN_ABSORPTION` times its absorption and the same scattering: dark grey veins that keep marble's
mean free path, so only the absorbing part of the medium changes.

The noise is deterministic in the seed (numpy's PCG64 draws the permutation and the gradients),
C² (quintic fade), and Lipschitz with |∇noise| <= `NOISE_GRADIENT_BOUND`, so
|∇w| <= sharpness · π / vein_mm · (1 + turbulence · octaves · NOISE_GRADIENT_BOUND) per mm.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from sssbake.pipeline.core.materials import Material, preset
from sssbake.pipeline.techniques.lpv.options import MARBLE_DEFAULTS, MarbleOptions

#: Default vein material: the base's absorption times this, its scattering unchanged.
VEIN_ABSORPTION = 10.0
#: Bound on the gradient of `gradient_noise` (unit gradients, quintic fade): per axis, the blend of
#: the corner gradients contributes at most 1 and the fade's slope (<= 15/8, over two corners)
#: times the corner terms (<= √3) at most 2 · 15/8 · √3; over three axes, × √3.
NOISE_GRADIENT_BOUND = math.sqrt(3.0) * (1.0 + 2.0 * 15.0 / 8.0 * math.sqrt(3.0))
#: Size of the noise's permutation and gradient tables (a power of two): its period, in vein periods.
TABLE = 256


def materials(options: MarbleOptions = MARBLE_DEFAULTS) -> tuple[Material, Material]:
    """(base, vein) materials of the marble."""
    base = preset(options.base) if isinstance(options.base, str) else options.base
    vein = options.vein_material
    if vein is None:
        vein = Material(f"{base.name} vein", base.sigma_s_prime, tuple(VEIN_ABSORPTION * base.a), base.eta, base.profile)
    elif isinstance(vein, str):
        vein = preset(vein, base.profile)
    return base, vein


def marble_field(mm_per_unit: float, options: MarbleOptions = MARBLE_DEFAULTS
                 ) -> Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]]:
    """A material field (`lpv_grid.MaterialField`) of veined marble for an object in file units.

    Returns
    -------
    callable
        (p, 3) float64 object-space points, file units -> (σ'_s (p, 3), σ_a (p, 3)) in 1/mm.
    """
    options.check()
    if not (isinstance(mm_per_unit, (int, float)) and math.isfinite(mm_per_unit) and mm_per_unit > 0):
        raise ValueError(f"marble: mm_per_unit must be a positive number, got {mm_per_unit!r}")
    base, vein = materials(options)
    tables = noise_tables(options.seed, options.octaves)

    def field(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        w = vein_weight(np.asarray(points, dtype=np.float64) * mm_per_unit, options, tables)[:, None]
        return (1.0 - w) * base.s + w * vein.s, (1.0 - w) * base.a + w * vein.a

    return field


def vein_weight(points_mm: np.ndarray, options: MarbleOptions = MARBLE_DEFAULTS,
                tables: tuple | None = None) -> np.ndarray:
    """(p,) vein weight w in [0, 1] at (p, 3) points in mm (module docstring).

    `tables` (from ``noise_tables(options.seed, options.octaves)``) saves rebuilding them per call.
    """
    tables = tables if tables is not None else noise_tables(options.seed, options.octaves)
    axis = np.asarray(options.axis, dtype=np.float64)
    axis = axis / np.linalg.norm(axis)
    q = points_mm / options.vein_mm
    phase = np.pi * (q @ axis + options.turbulence * fbm(q, tables))
    return np.abs(np.cos(phase)) ** options.sharpness


def mean_vein_weight(sharpness: float) -> float:
    """Mean of |cos|^sharpness over a period: the vein weight's mean over a large region."""
    return math.exp(math.lgamma((sharpness + 1) / 2) - math.lgamma(sharpness / 2 + 1)) / math.sqrt(math.pi)


def noise_tables(seed: int, octaves: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Random tables of the noise: permutation (2 · TABLE,) int64, unit gradients (TABLE, 3) and one
    offset (octaves, 3) per octave, which decorrelates the octaves' lattices."""
    rng = np.random.default_rng(seed)
    perm = rng.permutation(TABLE)
    g = rng.normal(size=(TABLE, 3))
    g /= np.linalg.norm(g, axis=1, keepdims=True)
    offsets = rng.uniform(0.0, TABLE, size=(octaves, 3))
    return np.concatenate([perm, perm]), g, offsets


def fbm(q: np.ndarray, tables: tuple) -> np.ndarray:
    """(p,) fractal sum Σ_o 2^-o noise(2^o q + offset_o) at (p, 3) points q, one term per offset."""
    perm, grads, offsets = tables
    out = np.zeros(len(q))
    for o, offset in enumerate(offsets):
        out += 0.5**o * gradient_noise(q * 2.0**o + offset, perm, grads)
    return out


def gradient_noise(q: np.ndarray, perm: np.ndarray, grads: np.ndarray) -> np.ndarray:
    """(p,) Perlin gradient noise at (p, 3) points q: 0 on the integer lattice, period TABLE."""
    cell = np.floor(q)
    f = q - cell
    i = cell.astype(np.int64) & (TABLE - 1)
    u = f * f * f * (f * (f * 6.0 - 15.0) + 10.0)  # quintic fade: C² across lattice faces
    out = np.zeros(len(q))
    for corner in np.ndindex(2, 2, 2):
        c = np.array(corner)
        ci = (i + c) & (TABLE - 1)
        h = perm[perm[perm[ci[:, 0]] + ci[:, 1]] + ci[:, 2]]
        dot = np.einsum("pk,pk->p", grads[h], f - c)
        weight = np.prod(np.where(c == 1, u, 1.0 - u), axis=1)
        out += weight * dot
    return out
