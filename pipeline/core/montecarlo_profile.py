"""The Monte Carlo diffusion profile: R(r) of a semi-infinite medium measured by random walks
(`random_walk.py`), tabulated over η and absorption, and fitted per material with poles so that
every closed form of `profile.py` holds.

The table (`data/montecarlo_profile.npz`, written by `build_table`) holds, for each η node and
each absorption ratio a = σ_a / σ'_s node, the total reflectance T and the radii (in units of
1/σ'_t) within which the fractions `FRACTIONS` of T leave: a quantile function, which interpolates
smoothly across nodes where densities would not. Each node reads the walk at the largest
reference absorption a₀ <= a (`REFERENCES`), reweighted by e^(-(a - a₀) L): the white walk
(a₀ = 0) alone would leave the strongly absorbing nodes to its rare short paths. Without
absorption every photon comes back (a 1-D random walk in depth is recurrent): T = 1, and the
photons the white walk dropped after `MAX_LENGTH` count as leaving beyond every tabulated radius.

A material's channel (α' = 1/(1 + a), η) reads ln T and its quantile radii by linear interpolation in
η and in sqrt(a) (near a = 0, 1 - T grows as sqrt(a)), and fits non-negative pole weights (NNLS) to
the energy of every band between consecutive quantile radii, each band weighted by its own energy
so that relative errors count alike, plus T itself. Beyond the last a node (α' < 1/101) the
shape is the last node's, single scattering's, and T scales with α'.
"""

from __future__ import annotations

from functools import cache
from importlib import resources
from typing import TYPE_CHECKING

import numpy as np
from scipy.optimize import brentq, nnls

if TYPE_CHECKING:  # the walks (numba) run when the table is built, never when a bake reads it
    from sssbake.pipeline.core.random_walk import Exits

#: Energy fractions whose radii the table holds (the last band, beyond 99 %, is left to the fit).
FRACTIONS = np.concatenate([[0.001, 0.0025, 0.005, 0.01, 0.02, 0.03, 0.04], np.arange(0.05, 0.951, 0.025),
                            [0.96, 0.97, 0.98, 0.99]])
#: The fit's first band ends at this fraction (the finer ones are the near-singular peak).
FIT_FROM = 0.01
#: η nodes of the table.
ETAS = (1.0, 1.1, 1.2, 1.3, 1.4, 1.5, 1.6, 1.8, 2.0)
#: Walk length (units of 1/σ'_s) after which a photon is dropped: ~0.2 % of the white walk's photons
#: (measured); they would carry e^(-a · MAX_LENGTH), under e^(-30) from the first absorbing node.
MAX_LENGTH = 1e6
#: Absorption-ratio nodes a = σ_a / σ'_s: 0, then from 30 / MAX_LENGTH to 100 (α' = 1/101).
ABSORPTIONS = np.concatenate([[0.0], np.geomspace(30.0 / MAX_LENGTH, 1e2, 50)])
#: The walks' reference absorptions a₀, one walk each per η node, and each walk's photons as a
#: multiple of the white walk's: absorbing walks are short, and few of their photons come back
#: (~0.7 % at a₀ = 10), so they take many more to hold the same noise.
REFERENCES = (0.0, 0.01, 0.1, 1.0, 10.0, 40.0)
PHOTON_FACTORS = (1, 1, 4, 16, 256, 256)
#: Pole depths (units of 1/σ'_t) and decays besides κ (units of σ'_t) the fit chooses from: κ for
#: the far field, faster ones for light scattered a few times, whose path in and out decays up to
#: e^(-(η + sqrt(η² - 1)) r) (single scattering beyond the critical angle).
#: Down to 1/1000 of a mean free path: at low albedo the first 5 % of the light leaves within
#: ~0.01 of one (single scattering near the entry point).
DEPTHS = np.geomspace(1e-3, 1e3, 49)
DECAYS = (1.0, 1.5, 2.0, 3.0, 4.0)
TABLE = "data/montecarlo_profile.npz"


def band_energies(radius: np.ndarray, weight: np.ndarray, fractions: np.ndarray) -> tuple[float, np.ndarray]:
    """The total of `weight` and the radii within which `fractions` of it lie (weighted quantiles).

    Parameters
    ----------
    radius, weight : (m,) float64
    fractions : (q,) float64 in (0, 1)

    Returns
    -------
    total : float
    radii : (q,) float64
    """
    order = np.argsort(radius)
    cumulative = np.cumsum(weight[order])
    total = float(cumulative[-1]) if len(cumulative) else 0.0
    if total <= 0.0:
        return 0.0, np.full(len(fractions), np.nan)
    return total, np.interp(fractions * total, cumulative, radius[order])


def tabulate(walks: list["Exits"]) -> tuple[np.ndarray, np.ndarray]:
    """One η's row of the table from its walks, one per `REFERENCES` entry (in that order).

    Returns
    -------
    total : (a,) float64
    log_radius : (a, q) float64, ln of the radii in units of 1/σ'_t
    """
    from sssbake.pipeline.core.random_walk import exit_weights

    total = np.zeros(len(ABSORPTIONS))
    log_radius = np.zeros((len(ABSORPTIONS), len(FRACTIONS)))
    for j, a in enumerate(ABSORPTIONS):
        walk = walks[int(np.searchsorted(REFERENCES, a, side="right")) - 1]
        weight = exit_weights(walk, a)
        if a == 0.0:  # every photon returns: the dropped ones beyond every tabulated radius
            radius = np.append(walk.radius, np.inf)
            weight = np.append(weight, 1.0 - weight.sum())
        else:
            radius = walk.radius
        total[j], radii = band_energies(radius * (1.0 + a), weight, FRACTIONS)  # → units of 1/σ'_t
        log_radius[j] = np.log(radii)
    return total, log_radius


def build_table(photons: int, seed: int = 1, walk=None) -> dict:
    """Walk `photons` photons per η node and reference absorption and tabulate T and the quantile
    radii (minutes per η node on two cores; `walk`, `random_walk.random_walk`'s signature, lets a
    caller cache the walks)."""
    if walk is None:
        from sssbake.pipeline.core.random_walk import random_walk as walk
    rows = [tabulate([walk(eta, photons * f, a0, MAX_LENGTH, seed + 1000 * k)
                      for k, (a0, f) in enumerate(zip(REFERENCES, PHOTON_FACTORS))]) for eta in ETAS]
    return {"eta": np.array(ETAS), "absorption": ABSORPTIONS, "fractions": FRACTIONS,
            "total": np.array([r[0] for r in rows]), "log_radius": np.array([r[1] for r in rows]),
            "references": np.array(REFERENCES), "photons": np.array(photons), "seed": np.array(seed)}


@cache
def _table() -> dict:
    with resources.files("sssbake.pipeline.core").joinpath(TABLE).open("rb") as f, np.load(f) as data:
        return {k: data[k] for k in data.files}


def table_point(alpha_prime: float, eta: float) -> tuple[float, np.ndarray, np.ndarray]:
    """T, the fractions and their radii (units of 1/σ'_t) for reduced albedo α' and index η.

    Returns
    -------
    total : float
    fractions, radii : (q,) float64
    """
    t = _table()
    etas = t["eta"]
    if not etas[0] <= eta <= etas[-1]:
        raise ValueError(f"eta {eta} is outside the Monte Carlo table ({etas[0]:g}-{etas[-1]:g})")
    a_nodes = t["absorption"]
    a = (1.0 - alpha_prime) / alpha_prime if alpha_prime > 0 else np.inf
    shrink = 1.0
    if a > a_nodes[-1]:  # single scattering's shape; T in proportion to α'
        shrink = alpha_prime * (1.0 + a_nodes[-1])
        a = a_nodes[-1]
    s_nodes, s = np.sqrt(a_nodes), np.sqrt(a)
    j = int(np.clip(np.searchsorted(s_nodes, s) - 1, 0, len(s_nodes) - 2))
    fa = (s - s_nodes[j]) / (s_nodes[j + 1] - s_nodes[j])
    i = int(np.clip(np.searchsorted(etas, eta) - 1, 0, len(etas) - 2))
    fe = (eta - etas[i]) / (etas[i + 1] - etas[i])

    def at(field: np.ndarray) -> np.ndarray:
        rows = (1.0 - fa) * field[i : i + 2, j] + fa * field[i : i + 2, j + 1]
        return (1.0 - fe) * rows[0] + fe * rows[1]

    # ln T: linear in sqrt(a) near a = 0 and in ln a far out, where T itself (~1/a) would bow 2 %
    return float(np.exp(at(np.log(t["total"])))) * shrink, t["fractions"], np.exp(at(t["log_radius"]))


def decay_rate(alpha: float) -> float:
    """κ (units of σ_t) of the transport equation's slowest mode for single-scattering albedo
    α with isotropic scattering: α artanh(κ)/κ = 1, the far-field decay e^(-κ r)."""
    if alpha >= 1.0:
        return 0.0
    if alpha <= 0.0:
        return 1.0
    f = lambda k: alpha * np.arctanh(k) / k - 1.0  # noqa: E731  (negative at 0+, +inf at 1)
    lo, hi = 1e-15, 1.0 - 1e-16
    if f(lo) >= 0.0:
        return lo
    if f(hi) <= 0.0:  # α below ~0.05: κ is 1 to double precision
        return 1.0
    return brentq(f, lo, hi, xtol=1e-300)


def pole_cdf(radius: np.ndarray, depth: np.ndarray, sigma: np.ndarray) -> np.ndarray:
    """(r, k) energy within each radius of unit-weight poles: ½ [e^(-σz) - z e^(-σD)/D]."""
    from sssbake.pipeline.core.profile import pole_disc_term

    return 0.5 * pole_disc_term(np.square(radius)[:, None], depth[None, :], sigma[None, :])


@cache
def fitted_poles(alpha_prime: float, eta: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Pole weights, depths and decays (units of 1/σ'_t) whose mixture reproduces the table's
    profile for α' and η; empty arrays where nothing leaves (α' = 0)."""
    total, fractions, radii = table_point(alpha_prime, eta)
    fitted = fractions >= FIT_FROM
    fractions, radii = fractions[fitted], radii[fitted]
    if total <= 0.0:
        return np.zeros(0), np.zeros(0), np.zeros(0)
    kappa = decay_rate(alpha_prime)
    depth = np.tile(DEPTHS, 1 + len(DECAYS))
    sigma = np.repeat([kappa, *DECAYS], len(DEPTHS))
    full = 0.5 * np.exp(-sigma * depth)
    usable = full > 1e-9  # a pole that deep and fast leaves nothing: its column would be all zeros
    depth, sigma, full = depth[usable], sigma[usable], full[usable]
    inside = pole_cdf(radii, depth, sigma)
    # bands: [0, r_0], [r_0, r_1], ..., [r_last, ∞) and, last, the total
    columns = np.vstack([inside[:1], np.diff(inside, axis=0), full - inside[-1:], full[None, :]])
    target = total * np.concatenate([fractions[:1], np.diff(fractions), [1.0 - fractions[-1]], [1.0]])
    scale = 1.0 / target
    scale[-1] *= 10.0  # the total counts ten times a band
    system = columns * scale[:, None]
    norm = np.linalg.norm(system, axis=0)  # unit columns: NNLS stays well conditioned
    weight, _ = nnls(system / norm, target * scale, maxiter=50 * len(depth))
    weight /= norm
    keep = weight > 0
    weight, depth, sigma = weight[keep], depth[keep], sigma[keep]
    return weight * (total / float(weight @ full[keep])), depth, sigma  # T exactly
