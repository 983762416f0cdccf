"""The published profiles issue 31 chose among, for `bench_profile.py` to measure against Monte
Carlo: the better dipole (d'Eon 2012), photon beam diffusion (Habel, Christensen, Jarosz 2013, as
pbrt-v3 evaluates it, with the boundary's Fresnel moments integrated exactly instead of its
polynomial fits) and the Christensen-Burley 2015 fit. (The classical dipole is the product's
``--profile dipole``; the Monte Carlo table is its default.)

All lengths are in units of 1/σ'_t (σ'_t = 1): a material with σ'_t in 1/mm scales r by σ'_t and
R by σ'_t². The reduced coefficients go in with an isotropic phase function, as in Jensen's and
d'Eon's dipoles.

Multiple scattering: the beam's real sources lie at depths z_r drawn from e^(-z_r) (midpoint
strata of its inverse CDF); each is the better dipole of d'Eon 2012 — Grosjean's diffusion
coefficient D = (2σ_a + σ'_s) / (3σ'_t²), σ_tr = sqrt(σ_a / D), an extrapolated boundary at
z_e = -2D (1 + 3C2) / (1 - 2C1), the virtual source at z_v = -z_r + 2 z_e, and the exitance
C_φ φ + C_E E with C_φ = (1 - 2C1)/4, C_E = (1 - 3C2)/2 — weighted by α'² and by
κ = 1 - e^(-2 (d_r + z_r)), which removes the sources a beam puts too close to the exit point.

Single scattering: the beam scatters once at depth t and leaves at r, refracted out through the
boundary (none from depths above t_crit = r sqrt(η² - 1), where the exit would be beyond the
critical angle): R_ss(r) = ∫ α' e^(-t) p e^(-d) T(cos θ) cos θ / d² dt with d² = r² + t²,
cos θ = t / d, p = 1/4π.

C1 and C2 are the first two angular moments of the Fresnel reflectance from inside,
C_i = ∫_0^1 F_r(μ) μ^i dμ (2 C1 is the internal diffuse reflectance F_dr).
"""

from __future__ import annotations

from functools import cache

import numpy as np

from sssbake.pipeline.core.fresnel import fresnel_transmittance

#: Depth strata of the beam (multiple scattering) and of the single-scattering integral.
BEAM_SAMPLES = 256


@cache
def fresnel_moments(eta: float) -> tuple[float, float]:
    """(C1, C2): ∫_0^1 F_r(μ) μ dμ and ∫_0^1 F_r(μ) μ² dμ for light inside a medium of index η
    meeting the boundary to index 1 (Gauss-Legendre on μ split at the critical cosine)."""
    eta = float(eta)
    if eta == 1.0:
        return 0.0, 0.0
    mu_c = np.sqrt(1.0 - 1.0 / (eta * eta))  # below it: total internal reflection, F_r = 1
    nodes, weights = np.polynomial.legendre.leggauss(200)
    mu = mu_c + (1.0 - mu_c) * 0.5 * (nodes + 1.0)
    w = 0.5 * (1.0 - mu_c) * weights
    # reflectance from inside at cosine μ equals that from outside at the refracted cosine
    cos_out = np.sqrt(1.0 - eta * eta * (1.0 - mu * mu))
    fr = 1.0 - fresnel_transmittance(eta, cos_out)
    return (0.5 * mu_c**2 + float(np.sum(w * fr * mu)),
            mu_c**3 / 3.0 + float(np.sum(w * fr * mu * mu)))


def _strata(samples: int) -> np.ndarray:
    """Depths with density e^(-z), at the midpoints of `samples` equal-probability strata."""
    return -np.log1p(-(np.arange(samples) + 0.5) / samples)


def multiple_scattering(r, albedo, eta: float, samples: int = BEAM_SAMPLES) -> np.ndarray:
    """R_ms(r) for reduced albedo `albedo` (σ'_t = 1).

    Parameters
    ----------
    r : (n,) float64, >= 0
    albedo : float in [0, 1]

    Returns
    -------
    (n,) float64, per unit area
    """
    r = np.asarray(r, dtype=np.float64)[:, None]
    a = float(albedo)
    sigma_a = 1.0 - a
    diffusion = (2.0 * sigma_a + a) / 3.0
    sigma_tr = np.sqrt(sigma_a / diffusion)
    c1, c2 = fresnel_moments(eta)
    z_e = -2.0 * diffusion * (1.0 + 3.0 * c2) / (1.0 - 2.0 * c1)
    c_phi, c_e = 0.25 * (1.0 - 2.0 * c1), 0.5 * (1.0 - 3.0 * c2)
    z_r = _strata(samples)[None, :]
    z_v = -z_r + 2.0 * z_e
    d_r = np.sqrt(r * r + z_r * z_r)
    d_v = np.sqrt(r * r + z_v * z_v)
    e_r, e_v = np.exp(-sigma_tr * d_r), np.exp(-sigma_tr * d_v)
    phi = (e_r / d_r - e_v / d_v) / (4.0 * np.pi * diffusion)
    flux = (z_r * (1.0 + sigma_tr * d_r) * e_r / d_r**3 - z_v * (1.0 + sigma_tr * d_v) * e_v / d_v**3) / (4.0 * np.pi)
    kappa = -np.expm1(-2.0 * (d_r + z_r))
    return a * a * np.mean(kappa * (c_phi * phi + c_e * flux), axis=1)


def single_scattering(r, albedo, eta: float, samples: int = BEAM_SAMPLES) -> np.ndarray:
    """R_ss(r) for reduced albedo `albedo` (σ'_t = 1), (n,) float64 per unit area."""
    r = np.asarray(r, dtype=np.float64)[:, None]
    t_crit = r * np.sqrt(max(eta * eta - 1.0, 0.0))
    t = t_crit + _strata(samples)[None, :]
    d = np.sqrt(r * r + t * t)
    cos = t / np.maximum(d, 1e-300)
    # transmittance out at internal cosine `cos` equals that in at the refracted (outside) cosine
    cos_out = np.sqrt(np.clip(1.0 - eta * eta * (1.0 - cos * cos), 0.0, 1.0))
    out = np.exp(-(d + t_crit)) / np.maximum(d * d, 1e-300) * fresnel_transmittance(eta, cos_out) * cos
    return float(albedo) / (4.0 * np.pi) * np.mean(out, axis=1)


def beam_diffusion(r, albedo, eta: float) -> np.ndarray:
    """R(r) = R_ms + R_ss, (n,) float64 per unit area (σ'_t = 1)."""
    return multiple_scattering(r, albedo, eta) + single_scattering(r, albedo, eta)


def better_dipole(r, albedo, eta: float) -> np.ndarray:
    """d'Eon 2012's better dipole: one real source at z_r = 1/σ'_t, R = α' (C_φ φ + C_E E), (n,)."""
    r = np.asarray(r, dtype=np.float64)
    a = float(albedo)
    diffusion = (2.0 * (1.0 - a) + a) / 3.0
    sigma_tr = np.sqrt((1.0 - a) / diffusion)
    c1, c2 = fresnel_moments(eta)
    z_e = -2.0 * diffusion * (1.0 + 3.0 * c2) / (1.0 - 2.0 * c1)
    z_r, z_v = 1.0, -1.0 + 2.0 * z_e
    d_r, d_v = np.sqrt(r * r + z_r * z_r), np.sqrt(r * r + z_v * z_v)
    e_r, e_v = np.exp(-sigma_tr * d_r), np.exp(-sigma_tr * d_v)
    phi = (e_r / d_r - e_v / d_v) / (4.0 * np.pi * diffusion)
    flux = (z_r * (1.0 + sigma_tr * d_r) * e_r / d_r**3 - z_v * (1.0 + sigma_tr * d_v) * e_v / d_v**3) / (4.0 * np.pi)
    return a * (0.25 * (1.0 - 2.0 * c1) * phi + 0.5 * (1.0 - 3.0 * c2) * flux)


def burley(r, total: float) -> np.ndarray:
    """Christensen & Burley 2015: R(r) = A s (e^(-s r) + e^(-s r/3)) / (8π r), with the total A given
    (here the walk's) and s from their searchlight fit for the mean free path, s = 1.85 - A +
    7 |A - 0.8|³ (σ'_t = 1), (n,)."""
    r = np.maximum(np.asarray(r, dtype=np.float64), 1e-300)
    s = 1.85 - total + 7.0 * abs(total - 0.8) ** 3
    return total * s * (np.exp(-s * r) + np.exp(-s * r / 3.0)) / (8.0 * np.pi * r)
