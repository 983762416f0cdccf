"""Rd(d) tabulated on a uniform grid of d² for the tens of millions of pairs the kernels technique
evaluates (its local kernels and its throughput matrix), where the closed form's six exponentials
and square roots per pair dominate the bake.

Linear interpolation in d² is accurate far from the source; near d = 0 its error grows as the grid
step² / z_r⁴, so below the distance where the error measured at the grid's midpoints exceeds
`TOLERANCE` the closed form is evaluated instead.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sssbake.pipeline.core.profile import Profile, diffuse_reflectance_profile

#: Largest relative error of the interpolated values (at the midpoints of the grid, where linear
#: interpolation errs most).
TOLERANCE = 1e-5
NODES = 1 << 18


@dataclass(frozen=True, eq=False)
class ProfileTable:
    """Attributes
    ----------
    params : Profile
    step : float
        Grid step in d², mm².
    values : (3, nodes) float64
        Rd at d² = i · step per channel.
    slopes : (3, nodes) float64
        ``values[:, i + 1] - values[:, i]`` (0 at the last node).
    exact_below : float
        d² (mm²) below which the closed form is used.
    """

    params: Profile
    step: float
    values: np.ndarray
    slopes: np.ndarray
    exact_below: float

    @staticmethod
    def build(params: Profile, max_mm: float, nodes: int = NODES) -> "ProfileTable":
        """A table up to `max_mm` (farther pairs fall back to the closed form)."""
        top = max(float(max_mm), 1e-9) ** 2
        step = top / (nodes - 1)
        grid = np.arange(nodes) * step
        values = diffuse_reflectance_profile(np.sqrt(grid), params)
        mid = diffuse_reflectance_profile(np.sqrt(grid[:-1] + 0.5 * step), params)
        error = np.abs(0.5 * (values[:-1] + values[1:]) - mid) / np.maximum(mid, 1e-300)
        bad = np.flatnonzero(error.max(axis=1) > TOLERANCE)
        exact_below = float(grid[bad[-1] + 1]) if len(bad) else 0.0
        values = np.ascontiguousarray(values.T)
        return ProfileTable(params, step, values, np.diff(values, axis=1, append=values[:, -1:]), exact_below)

    def __call__(self, d2: np.ndarray) -> np.ndarray:
        """Rd at squared distances `d2` (m,) mm² -> (m, 3) 1/mm²."""
        d2 = np.asarray(d2, dtype=np.float64)
        nodes = self.values.shape[1]
        at = d2 * (1.0 / self.step)
        index = np.minimum(at.astype(np.int64), nodes - 1)
        frac = at - index
        out = np.empty((len(d2), 3))
        for c in range(3):  # one gather per channel from a contiguous row: far faster than a (m, 3) gather
            out[:, c] = self.values[c].take(index) + frac * self.slopes[c].take(index)
        rest = np.flatnonzero((d2 < self.exact_below) | (at > nodes - 1))
        if len(rest):
            out[rest] = diffuse_reflectance_profile(np.sqrt(d2[rest]), self.params)
        return out
