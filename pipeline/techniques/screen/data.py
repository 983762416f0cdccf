"""The screen technique's per-material sample tables (Mertens et al. 2003), as the pipeline makes
them (`screen_samples`), the exporters write them and the runtime reads them."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sssbake.pipeline.core.ranges import LENGTH_MAX_MM


@dataclass(frozen=True, eq=False)
class ScreenSamples:
    """Attributes
    ----------
    offsets : (N + U, 2) float64
        Tangent-plane offsets, mm: the importance samples of red, green, blue, then the uniform ones.
    weights : (N + U,) float64
        w_i, mm².
    driver : int
        The channel that spreads furthest (it sets the uniform disc).
    uniform_radius_mm : float
    table : (3, T) float64
        Rd (1/mm²) per channel at r = table_reach_mm · (i / (T - 1))².
    table_reach_mm : float
    table_error : float
        The table's largest relative interpolation error, measured.
    """

    offsets: np.ndarray
    weights: np.ndarray
    driver: int
    uniform_radius_mm: float
    table: np.ndarray
    table_reach_mm: float
    table_error: float

    def check(self) -> None:
        """Raise ValueError unless the tables are finite, of matching shapes and usable."""
        k, t = len(self.offsets), self.table.shape[-1]
        if self.offsets.shape != (k, 2) or k < 1 or self.weights.shape != (k,):
            raise ValueError(f"screen: need (K, 2) offsets and (K,) weights, K >= 1, got {self.offsets.shape} "
                             f"and {self.weights.shape}")
        if self.table.shape != (3, t) or t < 2:
            raise ValueError(f"screen: the Rd table must be (3, T), T >= 2, got {self.table.shape}")
        for name in ("offsets", "weights", "table"):
            if not np.all(np.isfinite(getattr(self, name))):
                raise ValueError(f"screen: {name} are not all finite")
        if np.any(self.weights < 0) or np.any(self.table < 0):
            raise ValueError("screen: weights and the Rd table must be non-negative")
        if not (np.isfinite(self.table_reach_mm) and self.table_reach_mm > 0 and self.driver in (0, 1, 2)):
            raise ValueError(f"screen: need a positive table reach and a driver channel 0..2, got "
                             f"{self.table_reach_mm} and {self.driver}")
        # up to the profile's own reach: `table_integral` squares the reach (1e300 overflowed), the render
        # scales its disc by the radius (-1 drew NaN)
        if not (self.table_reach_mm <= LENGTH_MAX_MM and 0 < self.uniform_radius_mm <= LENGTH_MAX_MM):
            raise ValueError(f"screen: the table reach and the uniform radius must be in (0, {LENGTH_MAX_MM:g}] mm, "
                             f"got {self.table_reach_mm} and {self.uniform_radius_mm}")


def table_total(samples: ScreenSamples) -> np.ndarray:
    """(3,) float64 R_d per channel from the Rd table (`table_integral`)."""
    return table_integral(samples.table, samples.table_reach_mm)


def table_integral(table: np.ndarray, reach: float) -> np.ndarray:
    """(3,) 2π ∫ Rd(r) r dr of a (3, T) Rd table on r = reach t², t in [0, 1] (dr = 2 reach t dt),
    trapezoidal in t, where the table is linear."""
    t = np.linspace(0.0, 1.0, table.shape[1])
    return 2.0 * np.pi * np.trapezoid(table * (reach * t * t) * (2.0 * reach * t), t, axis=1)
