"""Propagation and rendering of the lpv technique (Børlum et al. 2011, §3.2-3.3) in numpy: the
reference implementation the GLSL runtime is checked against.

Each step, in every cell with medium, the intensity (two SH bands per colour channel) is
scattered, ((1 - s) + s g^l) per band l with s = 1 - e^(-σ'_s Δx) the share of light scattered
within one cell, attenuated and moved to the six neighbours by the propagation matrices
(`lpv_matrices`); what moves into a cell without medium has left the object. The accumulation
grid sums the steps; rendering turns the intensity a surface point's cell sends outwards into
radiance with the paper's area light, L_i = (2/A)(√(1/4π) c00 + ½ √(3/4π) c10^(n)), A the cell's
cross-section and c10^(n) the l = 1 part along the outward normal.

Attenuation (a choice; the paper's e^(-σ_t Δx) with the material's extinction stops light within
one cell at game-grid sizes: marble's σ'_t Δx is about 10 for 4 mm cells). Light that scatters in
every cell walks the lattice; a walk that keeps a share S of its flux per step, split over six
neighbours, decays as e^(-κ r) with cosh(κ Δx) = 3 / S - 2. The matrices move all of a cell's
flux (the five faces of each neighbour cover the shared face's solid angle, 4π/6), so the
attenuation per step is S itself, set so that κ = σ_tr, the material's diffusion decay:
S = 3 / (2 + cosh(σ_tr Δx)) <= 1. Between cells of different media the attenuation is the
geometric mean of the two cells' (reciprocal).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sssbake.pipeline.techniques.lpv.data import LpvGrid
from sssbake.pipeline.techniques.lpv.matrices import DIRECTIONS, propagation_matrices
from sssbake.pipeline.techniques.lpv.options import MAX_STEPS

#: √(1/4π) and ½ √(3/4π): the rendering's weights of c00 and c10^(n).
RENDER_WEIGHTS = (np.sqrt(1.0 / (4.0 * np.pi)), 0.5 * np.sqrt(3.0 / (4.0 * np.pi)))


#: σ_tr Δx at which a step's attenuation stops falling, as in runtime_shaders/lpv_grid.glsl (where
#: cosh must stay within float32): 3 / (2 + cosh 80) ≈ 1.1e-34 leaves no light after a step
#: either way, and the rendering's scale, which grows as 1 / a (`lpv_calibrate`), stays a float32.
DECAY_LIMIT = 80.0


@dataclass(frozen=True)
class LpvPropagateOptions:
    """Attributes
    ----------
    steps : int
        Propagation steps per frame (light moves one cell per step).
    shadow_size : int
        Side of the injection's shadow map, texels.
    """

    steps: int = 16
    shadow_size: int = 256

    def check(self) -> None:
        if not (isinstance(self.steps, int) and 1 <= self.steps <= MAX_STEPS):
            raise ValueError(f"lpv: steps must be a whole number in [1, {MAX_STEPS}], got {self.steps!r}")
        if not (isinstance(self.shadow_size, int) and 1 <= self.shadow_size <= 8192):
            raise ValueError(f"lpv: shadow_size must be a whole number in [1, 8192], got {self.shadow_size!r}")


LPV_DEFAULTS = LpvPropagateOptions()


def transport_factors(grid: LpvGrid) -> tuple[np.ndarray, np.ndarray]:
    """Per-cell scattering share s and attenuation a per step (module docstring).

    Returns
    -------
    scatter : (nz, ny, nx, 3) float64
        s = 1 - e^(-σ'_s Δx), in [0, 1).
    attenuation : (nz, ny, nx, 3) float64
        a in [0, 1]; 0 where there is no medium.
    """
    dx = grid.cell_mm
    sigma_t = grid.sigma_t.astype(np.float64)
    albedo = grid.albedo.astype(np.float64)
    scatter = -np.expm1(-albedo * sigma_t * dx)
    sigma_tr = sigma_t * np.sqrt(3.0 * np.clip(1.0 - albedo, 0.0, 1.0))
    attenuation = 3.0 / (2.0 + np.cosh(np.minimum(sigma_tr * dx, DECAY_LIMIT)))
    return scatter, np.where((grid.occupancy > 0)[..., None], attenuation, 0.0)


def propagate(grid: LpvGrid, injected: np.ndarray, steps: int,
              periodic: tuple[bool, bool, bool] = (False, False, False)) -> tuple[np.ndarray, np.ndarray]:
    """Run `steps` propagation steps from the injected intensity.

    Parameters
    ----------
    grid : LpvGrid
    injected : (nz, ny, nx, 3, 4) float64
        SH coefficients per cell and channel (`lpv_inject.inject`).
    steps : int
    periodic : (3,) bool
        Axes (x, y, z) along which the grid wraps around (a slab infinite in x and y:
        `lpv_calibrate`); light leaves through the other axes' ends.

    Returns
    -------
    accumulated : (nz, ny, nx, 3, 4) float64
        The injected intensity plus every step's.
    flux : (steps + 1,) float64
        Total flux (all cells, channels summed) of the propagation grid before each step and
        after the last; it never grows.
    """
    accumulated = np.array(injected, dtype=np.float64)
    flux = [_flux(accumulated)]
    for current in propagation_steps(grid, injected, steps, periodic):
        accumulated += current
        flux.append(_flux(current))
    return accumulated, np.array(flux)


def propagation_steps(grid: LpvGrid, injected: np.ndarray, steps: int,
                      periodic: tuple[bool, bool, bool] = (False, False, False)):
    """The propagation grid after each of `steps` steps (a generator of (nz, ny, nx, 3, 4)
    float64; see `propagate`)."""
    nx, ny, nz = grid.shape
    if injected.shape != (nz, ny, nx, 3, 4):
        raise ValueError(f"lpv: injected intensity must be {(nz, ny, nx, 3, 4)}, got {injected.shape}")
    scatter, attenuation = transport_factors(grid)
    band1 = (1.0 - scatter) + scatter * grid.g.astype(np.float64)  # the l = 1 factor; l = 0 keeps 1
    root = np.sqrt(attenuation)  # a_{d<-s} = sqrt(a_s a_d)
    matrices = propagation_matrices()
    current = np.array(injected, dtype=np.float64)
    for _ in range(steps):
        source = current * root[..., None]
        source[..., 1:] *= band1[..., None]
        current = np.zeros_like(source)
        for direction, matrix in zip(DIRECTIONS, matrices):
            current += _shifted(source @ matrix.T, direction, periodic)
        current *= root[..., None]
        yield current


def radiance(grid: LpvGrid, accumulated: np.ndarray, points: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """(p, 3) incident radiance L_i under the surface at object-space `points` (p, 3) with unit
    outward `normals`, before the exit Fresnel: the accumulated intensity interpolated trilinearly
    between the cell centres around each point, over the cells with medium only (weights
    renormalised), then the paper's area-light estimate (module docstring), floored at 0."""
    nx, ny, nz = grid.shape
    coords = (np.asarray(points, dtype=np.float64) - np.asarray(grid.origin)) / grid.cell - 0.5
    base = np.floor(coords).astype(np.int64)
    frac = coords - base
    total = np.zeros((len(coords), 3, 4))
    weight = np.zeros(len(coords))
    medium = grid.occupancy > 0
    for corner in np.ndindex(2, 2, 2):
        idx = base + np.array(corner)
        w = np.prod(np.where(np.array(corner) == 1, frac, 1.0 - frac), axis=1)
        valid = np.all((idx >= 0) & (idx < np.array([nx, ny, nz])), axis=1)
        i, j, k = (np.clip(idx[:, a], 0, n - 1) for a, n in enumerate((nx, ny, nz)))
        w = np.where(valid & medium[k, j, i], w, 0.0)
        total += w[:, None, None] * accumulated[k, j, i]
        weight += w
    c = total / np.where(weight > 0, weight, 1.0)[:, None, None]
    n = np.asarray(normals, dtype=np.float64)
    along = c[..., 1] * n[:, 1:2] + c[..., 2] * n[:, 2:3] + c[..., 3] * n[:, 0:1]  # basis order y, z, x
    area = grid.cell_mm**2
    return np.maximum(2.0 / area * (RENDER_WEIGHTS[0] * c[..., 0] + RENDER_WEIGHTS[1] * along), 0.0)


def _flux(coefficients: np.ndarray) -> float:
    """Total flux √(4π) Σ c00 of a grid of coefficients."""
    return float(np.sqrt(4.0 * np.pi) * coefficients[..., 0].sum())


def _shifted(values: np.ndarray, direction: np.ndarray, periodic=(False, False, False)) -> np.ndarray:
    """`values` (nz, ny, nx, ...) moved one cell along `direction` (x, y, z): zeros shifted in, or
    wrapped around along the `periodic` axes."""
    out = values
    for axis, step, wrap in zip((2, 1, 0), direction, periodic):  # x is the last grid axis
        if step == 0:
            continue
        out = np.roll(out, step, axis=axis)
        if not wrap:
            edge = [slice(None)] * out.ndim
            edge[axis] = slice(0, step) if step > 0 else slice(step, None)
            out[tuple(edge)] = 0.0
    return out if out is not values else values.copy()
