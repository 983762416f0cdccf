"""The diffusion profile averaged over a source's area: what a vertex of area ΔA at distance d
really sends to a receiver, instead of the point sample Rd(d).

A point sum Σ_i Rd(|x_i - x_o|) ΔA_i under-resolves Rd wherever the vertex spacing is not small
against z_r = 1/σ'_t: on a flat plane tessellated at 2 z_r it loses ~11 % of R_d (measured; tests
keep it), and meshes of one surface at different resolutions disagree. Treating each source as a
disc D of area ΔA (radius a = sqrt(ΔA/π)) in the receiver's tangent plane, its exact mean

    ḡ(d, a) = 1/(πa²) ∫_D Rd(|p - x_o|) dp

follows from the closed-form disc integral G(r) = 2π ∫_0^r Rd(s) s ds in polar coordinates about
the receiver: a receiver inside the disc (d < a) sees the boundary at ρ(φ) = d cos φ + sqrt(a² -
d² sin² φ) and ∫_D = (1/π) ∫_0^π G(ρ) dφ; one outside sees the disc within the half-angle
asin(a/d), between ρ± = d cos φ ± sqrt(a² - d² sin² φ), and ∫_D = (1/π) ∫_0^β (H(ρ-) - H(ρ+)) dφ,
with H = G(∞) - G the closed-form tail (no cancellation far away). Both are smooth after the
substitution sin φ = (a/d) sin ψ and take Gauss-Legendre quadrature.

Sums over many pairs read a table of ln ḡ over (ln a, d/a) for d <= `TABLE_REACH`·a, bilinear:
~2e-4 relative typically, 3e-3 at worst where the disc's edge passes the receiver (d ≈ a, a few
z_r wide; tests measure it). Beyond it the second-order expansion ḡ = Rd + (a²/8)(Rd'' + Rd'/d)
has a relative error ~(σ_tr a)⁴/200 + 3e-4: small wherever a source's light still matters.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from sssbake.pipeline.core.profile import Profile

#: Table range in d/a; beyond it the expansion's fourth-order error is below ~3e-4.
TABLE_REACH = 8.0
#: Table steps in d/a and in ln a.
T_STEP = 1.0 / 16.0
LOG_A_STEP = 0.02
#: Below this fraction of the shallowest pole depth the expansion holds to ~1e-4: no table needed.
SMALL_DISC = 0.1
#: Gauss-Legendre nodes of the exact mean.
NODES = 64
#: Receivers off the source's plane by more than this fraction of their distance see it tilted.
OFF_PLANE = 0.3
#: A tilted disc of radius below this fraction of sqrt(d² + z²), z the shallowest pole, takes the expansion (~0.5 %).
SMALL_TILTED = 0.25
#: Beyond this many radii, for discs with σ_tr a below `POINT_SIGMA`, Rd(d) itself: the spread
#: term is ~(a²/8)(9/d² + σ_tr²) of it, below 4e-3.
POINT_REACH = 30.0
POINT_SIGMA = 0.15
#: Receivers at least this many radii above a tilted disc take the polar rule.
POLAR_HEIGHT = 0.5
#: Where a disc's edge passes within this many radii of the receiver, and the disc is wider than
#: `EDGE_SHARP` of the profile's shallowest poles, the exact mean: there ḡ steps within a width of
#: that pole's depth (the Monte Carlo profile's near-singular peak, ~1/1000 of a mean free path),
#: inside a table step or four, where bilinear interpolation erred by 6 % (0.8 % from 10 depths).
EDGE_BAND = 0.25
EDGE_SHARP = 0.25 / T_STEP


@dataclass(frozen=True, eq=False)
class DiscMean:
    """ḡ(d, a) for many pairs: a table of ln ḡ over (ln a, d/a) for the discs of one surface.

    Build with `DiscMean.build`; the compiled `scatter_kernels` read it for many pairs (which pairs
    take the table, the exact mean, a polar rule, the expansion or the point value:
    tests/disc_reference.py's `disc_mean`, the same in numpy). They fill it as they read it
    (`scatter_kernels.table_cell`): a cell is the exact mean at its node, computed the first time
    a pair reads it, so a gather pays for the cells its pairs read and no more: the escape gain's
    gather over 1024 receivers of the 50k dragon reads 46 % of its table (2.0-2.2 CPU-s in full),
    the pilot's reference on its 4k subsample 61 %.

    Attributes
    ----------
    params : Profile
    log_a0 : float
        ln of the smallest tabulated radius (mm).
    a : (A,) float64
        The tabulated radii, exp(log_a0 + i·LOG_A_STEP), mm.
    t : (T,) float64
        The tabulated d/a, j·T_STEP.
    table : (3, A, T) float64
        ln ḡ per channel at (a[i], t[j]); NaN where no reader has needed it yet. Shared by every
        build of the same profile and grid (`_log_table`): only the kernels write it, each cell
        once with its own value.
    """

    params: Profile
    log_a0: float
    a: np.ndarray
    t: np.ndarray
    table: np.ndarray

    @property
    def log_table(self) -> np.ndarray:
        """(3, A, T) float64: ln ḡ per channel at ln a = log_a0 + i·LOG_A_STEP, d/a = j·T_STEP,
        every cell filled (read-only view), for readers of the whole table."""
        from sssbake.pipeline.core.scatter_kernels import disc_mean_rows  # it imports this module's constants

        p = self.params
        disc_mean_rows(self.a, self.t, p.weight, p.depth, p.sigma, *np.polynomial.legendre.leggauss(NODES),
                       self.table, 0, len(self.a))
        view = self.table.view()
        view.flags.writeable = False
        return view

    @staticmethod
    def build(params: Profile, radii_mm: np.ndarray) -> "DiscMean":
        """Tabulate for source radii in the range of `radii_mm` (any shape, mm; zeros ignored): the
        grid, its cells left for the kernels to fill as they read them."""
        radii = np.asarray(radii_mm, dtype=np.float64)
        floor = SMALL_DISC * float(params.z_min.min())
        big = radii[radii >= floor]
        lo = float(np.log(big.min())) if len(big) else float(np.log(floor))
        hi = float(np.log(big.max())) if len(big) else lo
        count_a = int(np.ceil((hi - lo) / LOG_A_STEP)) + 2
        count_t = int(round(TABLE_REACH / T_STEP)) + 1
        poles = (np.ascontiguousarray(v, dtype=np.float64).tobytes() for v in (params.weight, params.depth, params.sigma))
        a = np.exp(lo + LOG_A_STEP * np.arange(count_a))
        t = T_STEP * np.arange(count_t)
        return DiscMean(params, lo, a, t, _log_table(*poles, lo, count_a, count_t))


@lru_cache(maxsize=8)
def _log_table(weight: bytes, depth: bytes, sigma: bytes, lo: float, count_a: int, count_t: int) -> np.ndarray:
    """`DiscMean.table` for a profile's poles (as bytes) on the grid from ln a = `lo`, unfilled (NaN).

    Kept: one bake reads the same table for the same surface and profile several times (the
    pilot's reference and prt's pilot item), and each reader fills what the others left."""
    return np.full((3, count_a, count_t), np.nan)


def _polar_rule(rings: int, angles: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Nodes (ρ/a, cos φ) and weights of a mean over the unit disc: Gauss-Legendre in ρ² (equal
    area), the midpoint rule in φ over [0, π] (the integrand is even in φ)."""
    x, w = np.polynomial.legendre.leggauss(rings)
    rho = np.sqrt(0.5 * (x + 1.0))
    phi = (np.arange(angles) + 0.5) * np.pi / angles
    return np.repeat(rho, angles), np.tile(np.cos(phi), rings), np.repeat(0.5 * w, angles) / angles


_POLAR_RULE = _polar_rule(4, 8)
