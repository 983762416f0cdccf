"""The diffusion profile R(r) that every technique, the fallback and the offline reference
evaluate: a positive mixture of point-source poles,

    Rd(r) = Σ_k w_k/(4π) · z_k (1 + σ_k d_k) e^(-σ_k d_k) / d_k³,   d_k = sqrt(r² + z_k²),

per colour channel. Each pole is a normalised radial density times e^(-σ_k z_k): its disc integral
2π ∫_0^a is (w_k/2) [e^(-σ_k z_k) - z_k e^(-σ_k D_k)/D_k], D_k = sqrt(a² + z_k²), its derivatives and
its inverse CDF are closed forms, so sums, self terms, derivatives and importance sampling stay
exact whatever the model.

Two models (`materials.PROFILE_MODELS`), chosen per material (`Material.profile`):

- ``"montecarlo"`` (the default): R(r) of a semi-infinite medium behind a smooth dielectric
  boundary as measured by a random walk (`random_walk.py`), tabulated over albedo and η and fitted
  with poles (`montecarlo_profile.py`). It reproduces the walk's total reflectance within 2 % and
  the energy of every annulus holding 5 % of it within 5 % (docs/profile.md). Its values are
  radiance-normalised: a runtime multiplies them by F_t(η, ω_o)/π, whose integral over the
  hemisphere is c(η) = `exit_normalisation(η)`, not 1, so the poles carry 1/c(η) (d'Eon 2012's
  remedy) and the light that leaves a flat medium is R(r) itself.
- ``"dipole"``: the classical dipole of Jensen et al. 2001 (DESIGN.md §3), two poles at z_r and z_v
  with w = α' and σ = σ_tr, without that normalisation, as the papers use it.

All functions are vectorised and float64, lengths in mm, coefficients in 1/mm. Per-channel
parameters broadcast against the leading shape of `r`: pass ``r[..., None]`` with (3,) channel
arrays to get (..., 3) results.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from functools import cache

import numpy as np

from sssbake.pipeline.core.fresnel import fresnel_transmittance
from sssbake.pipeline.core.materials import DEFAULT_PROFILE, PROFILE_MODELS, Material, MaterialError


def fresnel_diffuse_reflectance(eta) -> np.ndarray:
    """Internal diffuse Fresnel reflectance F_dr(η), the rational fit used by Jensen et al. 2001."""
    eta = np.asarray(eta, dtype=np.float64)
    return -1.440 / eta**2 + 0.710 / eta + 0.668 + 0.0636 * eta


def boundary_a(eta) -> np.ndarray:
    """The classical dipole's boundary mismatch term A = (1 + F_dr) / (1 - F_dr)."""
    fdr = fresnel_diffuse_reflectance(eta)
    return (1.0 + fdr) / (1.0 - fdr)


@cache
def exit_normalisation(eta: float) -> float:
    """c(η) = ∫ F_t(η, ω) cos θ dω / π over the outer hemisphere: the share of an isotropic
    internal radiance's exitance that F_t(η, ω_o)/π lets out (1 at η = 1, ~0.91 at η = 1.5)."""
    nodes, weights = np.polynomial.legendre.leggauss(256)
    mu = 0.5 * (nodes + 1.0)
    return float(np.sum(weights * fresnel_transmittance(float(eta), mu) * mu))  # 2 ∫_0^1 F_t μ dμ


@dataclass(frozen=True, eq=False)
class Profile:
    """A material's profile as a mixture of P poles per channel.

    Attributes
    ----------
    weight, depth, sigma : (P, 3) float64
        w_k >= 0, z_k > 0 (mm), σ_k >= 0 (1/mm) of each pole and channel (unused poles weigh 0).
    eta : float
    model : str
        One of `materials.PROFILE_MODELS`.
    alpha_prime, sigma_tr : (3,) float64
        The material's reduced albedo and diffusion decay sqrt(3 σ_a σ'_t) (1/mm): scales for the
        heuristics that size a neighbourhood, not part of the profile's values.
    exit_scale : float
        1/c(η) folded into the weights (montecarlo), or 1 (dipole).
    """

    weight: np.ndarray
    depth: np.ndarray
    sigma: np.ndarray
    eta: float
    model: str
    alpha_prime: np.ndarray
    sigma_tr: np.ndarray
    exit_scale: float

    @property
    def z_min(self) -> np.ndarray:
        """(3,) the shallowest pole depth that carries weight, per channel (mm; any pole's where
        none does): the profile's near-field scale."""
        used = self.weight > 0
        return np.where(used.any(axis=0), np.where(used, self.depth, np.inf).min(axis=0), self.depth.min(axis=0))

    @property
    def z_max(self) -> np.ndarray:
        """(3,) the deepest weighted pole depth per channel (mm; any pole's where none carries weight)."""
        used = self.weight > 0
        return np.where(used.any(axis=0), np.where(used, self.depth, 0.0).max(axis=0), self.depth.max(axis=0))

    def channel(self, c: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(w, z, σ) of channel c's weighted poles, each (P_c,)."""
        keep = self.weight[:, c] > 0
        return self.weight[keep, c], self.depth[keep, c], self.sigma[keep, c]


def classical_dipole(sigma_s_prime, sigma_a, eta: float) -> Profile:
    """Jensen et al. 2001's dipole: poles at z_r = 1/σ'_t and z_v = z_r (1 + 4A/3), w = α', σ = σ_tr."""
    s = np.asarray(sigma_s_prime, dtype=np.float64) * np.ones(3)
    a = np.asarray(sigma_a, dtype=np.float64) * np.ones(3)
    st = s + a
    z_r = 1.0 / st
    z_v = z_r * (1.0 + 4.0 * boundary_a(eta) / 3.0)
    alpha, sigma_tr = s / st, np.sqrt(3.0 * a * st)
    return Profile(np.stack([alpha, alpha]), np.stack([z_r, z_v]), np.stack([sigma_tr, sigma_tr]),
                   float(eta), "dipole", alpha, sigma_tr, 1.0)


def profile_for(material: Material) -> Profile:
    """The profile of `material` under its model (`Material.profile`), scaled by its escape gain."""
    return profile_of(material.sigma_s_prime, material.sigma_a, material.eta, material.profile, material.escape_gain)


@cache
def profile_of(sigma_s_prime: tuple, sigma_a: tuple, eta: float, model: str,
               escape_gain: tuple = (1.0, 1.0, 1.0)) -> Profile:
    """The profile of σ'_s, σ_a ((3,) tuples, 1/mm), η under `model`, its values times `escape_gain`
    ((3,): `Material.escape_gain`) (cached)."""
    p = _half_space_profile(sigma_s_prime, sigma_a, eta, model)
    return p if escape_gain == (1.0, 1.0, 1.0) else replace(p, weight=p.weight * np.asarray(escape_gain))


def _half_space_profile(sigma_s_prime: tuple, sigma_a: tuple, eta: float, model: str) -> Profile:
    if model == "dipole":
        return classical_dipole(sigma_s_prime, sigma_a, eta)
    if model != "montecarlo":
        raise MaterialError(f"unknown profile model {model!r}; choose one of {', '.join(PROFILE_MODELS)}")
    from sssbake.pipeline.core.montecarlo_profile import fitted_poles

    s, a = np.asarray(sigma_s_prime), np.asarray(sigma_a)
    st = s + a
    scale = 1.0 / exit_normalisation(eta)
    poles = [fitted_poles(float(si / ti), eta) for si, ti in zip(s, st)]  # σ'_t = 1 units
    count = max(1, max(len(w) for w, _, _ in poles))
    # unused slots: no weight, at a mean free path (a channel where nothing leaves has only those)
    weight, depth, sigma = np.zeros((count, 3)), np.tile(1.0 / st, (count, 1)), np.zeros((count, 3))
    for c, (w, z, sg) in enumerate(poles):
        # σ'_t = 1 → mm: depths shrink by σ'_t, decays grow by it; a per-area density gains σ'_t²,
        # which z/d³ carries by itself, so the weights stay.
        weight[: len(w), c], depth[: len(w), c], sigma[: len(w), c] = w * scale, z / st[c], sg * st[c]
    return Profile(weight, depth, sigma, float(eta), "montecarlo", s / st, np.sqrt(3.0 * a * st), scale)


def diffuse_reflectance_profile(r, p: Profile) -> np.ndarray:
    """Rd(r): diffuse reflectance per unit area at distance r (1/mm²).

    Parameters
    ----------
    r : (...,) float64, mm, >= 0

    Returns
    -------
    (..., 3) float64
    """
    r2 = np.square(np.asarray(r, dtype=np.float64))[..., None]
    out = np.zeros(r2.shape[:-1] + (3,))
    for w, z, s in zip(p.weight, p.depth, p.sigma):
        d = np.sqrt(r2 + z * z)
        sd = s * d
        out += w * z * (1.0 + sd) * np.exp(-sd) / (d * d * d)
    return out / (4.0 * np.pi)


def profile_derivatives(r, p: Profile, c: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rd, dRd/dr and d²Rd/dr² of channel c at r (mm), (...,) float64 each.

    With g(D) = (1 + σD) e^(-σD) / D³ and D² = r² + z²: g' = -e (σ²D² + 3σD + 3) / D⁴,
    g'' = e (σ³D³ + 5σ²D² + 12σD + 12) / D⁵, and dD/dr = r/D, d²D/dr² = z²/D³.
    """
    r = np.asarray(r, dtype=np.float64)
    out = [np.zeros_like(r) for _ in range(3)]
    for w, z, s in zip(*p.channel(c)):
        d2 = r * r + z * z
        d = np.sqrt(d2)
        e = np.exp(-s * d)
        g1 = -e * (s * s * d2 + 3.0 * s * d + 3.0) / (d2 * d2)
        g2 = e * (s**3 * d2 * d + 5.0 * s * s * d2 + 12.0 * s * d + 12.0) / (d2 * d2 * d)
        k = w / (4.0 * np.pi)
        out[0] += k * z * (1.0 + s * d) * e / (d2 * d)
        out[1] += k * z * g1 * r / d
        out[2] += k * z * (g2 * r * r / d2 + g1 * z * z / (d2 * d))
    return out[0], out[1], out[2]


def pole_disc_term(a2, z, sigma):
    """e^(-σ z) - (z/d) e^(-σ d) with d = sqrt(a² + z²), free of cancellation for small a."""
    d = np.sqrt(a2 + z * z)
    excess = a2 / (d + z)  # d - z, computed stably
    return np.exp(-sigma * z) * -np.expm1(-np.log1p(excess / z) - sigma * excess)


def disc_integral(a, p: Profile) -> np.ndarray:
    """Exact 2π ∫_0^a Rd(r) r dr: the reflectance gathered from a disc of radius a around the point.

    Used for a vertex's own area (the self term), which a point sample would get badly wrong.

    Parameters
    ----------
    a : (...,) float64, mm, >= 0

    Returns
    -------
    (..., 3) float64, in [0, `profile_total`]
    """
    a2 = np.square(np.asarray(a, dtype=np.float64))[..., None]
    total = np.zeros(a2.shape[:-1] + (3,))
    for w, z, s in zip(p.weight, p.depth, p.sigma):
        total += w * pole_disc_term(a2, z, s)
    return 0.5 * total


def profile_total(p: Profile) -> np.ndarray:
    """(3,) 2π ∫_0^∞ Rd(r) r dr of the profile's values (radiance-normalised: see `Profile`)."""
    return 0.5 * np.sum(p.weight * np.exp(-p.sigma * p.depth), axis=0)


def total_reflectance(p: Profile) -> np.ndarray:
    """(3,) the share of the light entering a flat semi-infinite medium that leaves it again."""
    return profile_total(p) / p.exit_scale


def total_for_albedo(alpha_prime, eta: float, model: str = DEFAULT_PROFILE) -> np.ndarray:
    """`total_reflectance` of a material with reduced albedo `alpha_prime` ((k,) float64) under
    `model` (it depends on α' and η alone)."""
    alpha = np.atleast_1d(np.asarray(alpha_prime, dtype=np.float64))
    if model == "dipole":
        k = np.sqrt(3.0 * np.clip(1.0 - alpha, 0.0, None))
        return 0.5 * alpha * (1.0 + np.exp(-(4.0 / 3.0) * boundary_a(eta) * k)) * np.exp(-k)
    if model != "montecarlo":
        raise MaterialError(f"unknown profile model {model!r}; choose one of {', '.join(PROFILE_MODELS)}")
    from sssbake.pipeline.core.montecarlo_profile import table_point

    # the table's T, which each fit reproduces exactly: no fit needed where only the total is asked
    return np.array([table_point(float(x), float(eta))[0] for x in alpha])


def radius_for_energy(fraction_dropped: float, p: Profile, r_max: float = 1e12) -> np.ndarray:
    """Smallest radius a (mm, per channel) with 2π∫_a^∞ Rd r dr <= fraction_dropped · total.

    The neighbourhood radius of a gather comes from this energy bound rather than from
    e^(-σ_tr r): without absorption the profile falls off only as 1/r³.
    """
    target = (1.0 - fraction_dropped) * profile_total(p)
    lo = np.zeros(3)
    hi = np.full(3, float(r_max))
    for _ in range(200):  # bisection on a monotone function; 200 halvings reach float64 resolution
        mid = 0.5 * (lo + hi)
        # lo and hi next to each other in every channel: no halving can move them (~90 steps, not
        # 200); lo is never enough and hi always, so stopping changes nothing
        if np.all((mid == lo) | (mid == hi)):
            break
        # each channel at its own radius, all poles at once: disc_integral's (3, 3) of every radius
        # in every channel, pole by pole, cost 0.04 s a call, and a bake's pilot calls ~15 times
        terms = pole_disc_term(np.square(mid), p.depth, p.sigma) * p.weight  # (P, 3)
        enough = 0.5 * terms.sum(axis=0) >= target
        hi = np.where(enough, mid, hi)
        lo = np.where(enough, lo, mid)
    return hi


def radius_holding(p: Profile, energy: float) -> np.ndarray:
    """(3,) radius (mm) within which the disc integral reaches `energy` (in (0, 1)) of the total,
    per channel (`radius_for_energy` with 1 - `energy` dropped)."""
    return radius_for_energy(1.0 - energy, p)
