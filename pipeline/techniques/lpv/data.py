"""The lpv technique's material grid (Børlum et al. 2011, SSLPV): one object's voxelised medium, as
the pipeline makes it (`lpv_grid.voxelise`), the exporters write it and the propagation reads it.

Arrays are indexed (z, y, x): x varies fastest in memory, as a GL 3-D texture's texels, so
``array.tobytes()`` is the texture's data. Cell (i, j, k) (x, y, z indices) spans
``origin + cell * [i, i + 1] x [j, j + 1] x [k, k + 1]`` in the object's frame.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True, eq=False)
class LpvGrid:
    """Attributes
    ----------
    origin : (3,) float64
        Object-space corner of cell (0, 0, 0), file units.
    cell : float
        Cell side, file units (cells are cubes).
    mm_per_unit : float
        Millimetres per file unit.
    occupancy : (nz, ny, nx) float32
        Share of each cell inside the object, in [0, 1]; 0: no medium (light there has left).
    sigma_t : (nz, ny, nx, 3) float32
        Reduced extinction σ'_t = σ'_s + σ_a per colour channel, 1/mm (0 where there is no medium).
    albedo : (nz, ny, nx, 3) float32
        Reduced scattering albedo α' = σ'_s / σ'_t, in [0, 1].
    g : (nz, ny, nx, 3) float32
        Henyey-Greenstein asymmetry of the phase function, in (-1, 1) (0 with reduced
        coefficients, which fold the anisotropy into σ'_s).
    eta : float
        Relative index of refraction at the surface.
    """

    origin: np.ndarray
    cell: float
    mm_per_unit: float
    occupancy: np.ndarray
    sigma_t: np.ndarray
    albedo: np.ndarray
    g: np.ndarray
    eta: float

    @property
    def shape(self) -> tuple[int, int, int]:
        """(nx, ny, nz), cells along x, y, z."""
        nz, ny, nx = self.occupancy.shape
        return nx, ny, nz

    @property
    def cell_mm(self) -> float:
        """Cell side in mm."""
        return float(self.cell * self.mm_per_unit)

    def check(self) -> None:
        """Raise ValueError unless the arrays have matching shapes and valid, finite values."""
        if self.occupancy.ndim != 3 or min(self.occupancy.shape) < 1:
            raise ValueError(f"lpv grid: occupancy must be (nz, ny, nx), got shape {self.occupancy.shape}")
        per_channel = (*self.occupancy.shape, 3)
        for name in ("sigma_t", "albedo", "g"):
            if getattr(self, name).shape != per_channel:
                raise ValueError(f"lpv grid: {name} must have shape {per_channel}, got {getattr(self, name).shape}")
        for name in ("occupancy", "sigma_t", "albedo", "g"):
            if not np.all(np.isfinite(getattr(self, name))):
                raise ValueError(f"lpv grid: {name} has non-finite values")
        if np.any(self.occupancy < 0) or np.any(self.occupancy > 1):
            raise ValueError("lpv grid: occupancy must be in [0, 1]")
        if np.any(self.sigma_t < 0) or np.any(self.albedo < 0) or np.any(self.albedo > 1):
            raise ValueError("lpv grid: need sigma_t >= 0 and albedo in [0, 1]")
        if np.any(np.abs(self.g) >= 1):
            raise ValueError("lpv grid: g must be in (-1, 1)")
        origin = np.asarray(self.origin, dtype=np.float64)
        if origin.shape != (3,) or not np.all(np.isfinite(origin)):
            raise ValueError(f"lpv grid: origin must be three finite numbers, got {self.origin}")
        for name in ("cell", "mm_per_unit", "eta"):
            value = getattr(self, name)
            if not (np.isfinite(value) and value > 0):
                raise ValueError(f"lpv grid: {name} must be positive, got {value}")
