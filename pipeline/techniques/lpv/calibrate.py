"""The lpv rendering's scale: what turns the paper's area-light estimate into the profile's radiance.

The paper's L_i = (2/A)(√(1/4π) c00 + ½ √(3/4π) c10^(n)) reads the accumulation grid, the sum of
the intensity a boundary cell holds over all steps; its absolute level depends on the cell size
and the step count (the paper scales its Figure 8 by hand, by 3, 2 and 1.2). Here the level is
set once per grid and step count: a slab of the grid's mean medium, infinite in x and y (a 1 × 1
periodic column), lit at normal incidence by unit irradiance, must give the diffusion profile's radiance
R_d F_t(η, 1) / π at its surface (R_d the profile's own total, `profile.profile_total`). Without the scale the radiance is several times too bright,
growing with resolution and steps (benchmarks/README.md#lpv-calibration).
"""

from __future__ import annotations

import numpy as np

from sssbake.pipeline.core.profile import profile_of, profile_total
from sssbake.pipeline.core.fresnel import fresnel_transmittance
from sssbake.pipeline.techniques.lpv.data import LpvGrid
from sssbake.pipeline.techniques.lpv.inject import LOBE
from sssbake.pipeline.techniques.lpv.matrices import lpv_basis
from sssbake.pipeline.techniques.lpv.propagate import propagation_steps, radiance


def render_scales(grid: LpvGrid, max_steps: int, profile: str, escape_gain: tuple = (1.0, 1.0, 1.0)) -> np.ndarray:
    """The rendering's scale per colour channel for 1 .. `max_steps` propagation steps.

    Parameters
    ----------
    grid : LpvGrid
        At least one cell with medium; its occupancy-weighted mean medium makes the slab.
    max_steps : int
        >= 1.
    profile : str
        The diffusion profile model whose slab radiance the scale matches (`materials.PROFILE_MODELS`).
    escape_gain : (3,) float
        The material's `Material.escape_gain`, which scales that radiance.

    Returns
    -------
    (max_steps, 3) float64
        Row s - 1: the factor for s steps (finite and positive).
    """
    if not (isinstance(max_steps, int) and max_steps >= 1):
        raise ValueError(f"lpv calibrate: max_steps must be a whole number >= 1, got {max_steps!r}")
    weight = grid.occupancy.astype(np.float64)
    if not weight.sum() > 0:
        raise ValueError("lpv calibrate: the grid holds no medium")
    mean = {name: np.einsum("zyx,zyxc->c", weight, getattr(grid, name).astype(np.float64)) / weight.sum()
            for name in ("sigma_t", "albedo", "g")}
    depth = max_steps + 2  # medium cells below the surface: light never reaches the bottom
    column = (depth + 1, 1, 1)
    medium = np.ones(column, np.float32)
    medium[-1] = 0.0  # the cell above the surface: outside

    def field(value):
        return (medium[..., None] * value).astype(np.float32)

    slab = LpvGrid(origin=np.zeros(3), cell=grid.cell, mm_per_unit=grid.mm_per_unit, occupancy=medium,
                   sigma_t=field(mean["sigma_t"]), albedo=field(mean["albedo"]), g=field(mean["g"]), eta=grid.eta)
    transmitted = fresnel_transmittance(grid.eta, 1.0) * grid.cell_mm**2  # unit irradiance on one cell
    injected = np.zeros((*column, 3, 4))
    injected[depth - 1, 0, 0] = transmitted * LOBE[[0, 1, 1, 1]] * lpv_basis(np.array([[0.0, 0.0, -1.0]]))[0]
    surface = np.array([[0.5 * grid.cell, 0.5 * grid.cell, depth * grid.cell]])
    up = np.array([[0.0, 0.0, 1.0]])
    want = profile_total(profile_of(tuple(mean["albedo"]), tuple(1.0 - mean["albedo"]), grid.eta, profile,
                                    tuple(escape_gain)))
    want = want * fresnel_transmittance(grid.eta, 1.0) / np.pi
    # The injected lobe about -z renders nothing along +z (Φ/4π - Φ/4π), so only the propagated
    # light is summed: the lobe's rounding (1e-16 Φ) would swamp it where a step keeps ~1e-34.
    accumulated = np.zeros_like(injected)
    out = np.zeros((max_steps, 3))
    for s, current in enumerate(propagation_steps(slab, injected, max_steps, periodic=(True, True, False))):
        accumulated += current
        out[s] = want / np.maximum(radiance(slab, accumulated, surface, up)[0], 1e-300)
    return out
