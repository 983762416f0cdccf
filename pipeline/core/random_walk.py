"""Monte Carlo ground truth for a semi-infinite medium: photons walked from a normally incident
pencil beam to where they leave through a smooth dielectric boundary.

Lengths are in units of 1/σ'_s (σ'_s = 1) and the phase function is isotropic (the similarity
relation that the reduced coefficients assume). A walk runs at a reference absorption a₀ = σ_a/σ'_s:
free paths are drawn with σ_t = 1 + a₀ and a photon survives each scattering with probability
1/(1 + a₀) (analog absorption); each photon that leaves records its exit radius and its total path
length L. By the microscopic Beer-Lambert law the same exits describe any absorption a >= a₀ with
the weight e^(-(a - a₀) L) (`exit_weights`): one walk serves a decade of albedos, and a₀ = 0 (the
"white" walk) all of them in principle, though at high absorption only its rare short paths
would count.

At the boundary a photon is reflected back in with the exact unpolarised Fresnel reflectance from
inside (total internal reflection beyond the critical angle), otherwise it leaves. It enters already
refracted (normal incidence stays normal), so the profile is per unit power *entering* the medium,
the quantity R(r) of the diffusion literature. Photons still inside after `max_length` are dropped:
they would carry e^(-σ_a max_length / σ'_s) or less.

This is the independent reference the diffusion profile (`profile.py`) is fitted and tested
against; it shares no equation with it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np

_GOLDEN = np.uint64(0x9E3779B97F4A7C15)
_MIX1 = np.uint64(0xBF58476D1CE4E5B9)
_MIX2 = np.uint64(0x94D049BB133111EB)
_UNIT = 1.0 / 9007199254740992.0  # 2^-53
#: Photons walked at once: bounds the per-photon arrays (24 bytes each) whatever the walk's size.
CHUNK = 4_000_000


@numba.njit(inline="always")
def _scramble(z):
    """splitmix64's output function: a bijection of 64-bit words that decorrelates nearby inputs."""
    z = (z ^ (z >> np.uint64(30))) * _MIX1
    z = (z ^ (z >> np.uint64(27))) * _MIX2
    return z ^ (z >> np.uint64(31))


@numba.njit(inline="always")
def _uniform(state):
    """splitmix64: the next state and a uniform in [0, 1) from its top 53 bits."""
    state = state + _GOLDEN
    return state, float(_scramble(state) >> np.uint64(11)) * _UNIT


@numba.njit(inline="always")
def _reflectance_inside(cos_i, eta):
    """Unpolarised Fresnel reflectance for light inside (index η) meeting the boundary to index 1."""
    sin_t2 = eta * eta * (1.0 - cos_i * cos_i)
    if sin_t2 >= 1.0:
        return 1.0
    cos_t = np.sqrt(1.0 - sin_t2)
    rs = (eta * cos_i - cos_t) / (eta * cos_i + cos_t)
    rp = (cos_i - eta * cos_t) / (cos_i + eta * cos_t)
    return 0.5 * (rs * rs + rp * rp)


@numba.njit(parallel=True, cache=True)
def _walk(first, photons, eta, absorption, max_length, seed):
    radius = np.full(photons, np.nan)
    length = np.full(photons, np.nan)
    cos_out = np.full(photons, np.nan)
    for k in numba.prange(photons):
        # each photon's stream starts at a hashed point of splitmix64's one 2^64 cycle: neighbours'
        # streams must not be shifted copies of each other (a walk draws at most ~3e6 numbers)
        state = _scramble((np.uint64(seed) << np.uint64(32)) + np.uint64(first + k))
        x = 0.0
        y = 0.0
        z = 0.0
        dx = 0.0
        dy = 0.0
        dz = -1.0
        travelled = 0.0
        while travelled < max_length:
            state, u = _uniform(state)
            step = -np.log(1.0 - u) / (1.0 + absorption)
            if z + step * dz >= 0.0:  # meets the boundary first (dz > 0)
                t = -z / dz
                x += t * dx
                y += t * dy
                z = 0.0
                travelled += t
                state, u = _uniform(state)
                if u >= _reflectance_inside(dz, eta):
                    radius[k] = np.sqrt(x * x + y * y)
                    length[k] = travelled
                    sin_o2 = eta * eta * (1.0 - dz * dz)
                    cos_out[k] = np.sqrt(max(0.0, 1.0 - sin_o2))
                    break
                dz = -dz  # memoryless: the next free path starts afresh at the boundary
                continue
            x += step * dx
            y += step * dy
            z += step * dz
            travelled += step
            if absorption > 0.0:  # (no draw without absorption: the white walk's stream stays as it was)
                state, u = _uniform(state)
                if u * (1.0 + absorption) >= 1.0:  # absorbed
                    break
            state, u = _uniform(state)
            dz = 2.0 * u - 1.0
            state, u = _uniform(state)
            phi = 2.0 * np.pi * u
            s = np.sqrt(max(0.0, 1.0 - dz * dz))
            dx = s * np.cos(phi)
            dy = s * np.sin(phi)
    return radius, length, cos_out


@dataclass(frozen=True, eq=False)
class Exits:
    """The photons of one white walk that left the medium.

    Attributes
    ----------
    eta : float
    absorption : float
        The walk's reference absorption a₀ = σ_a / σ'_s.
    photons : int
        Photons launched (the normalisation: every weight is per launched photon).
    radius : (m,) float64
        Exit distance from the entry point, in units of 1/σ'_s.
    length : (m,) float64
        Path length inside, in units of 1/σ'_s.
    cos_out : (m,) float64
        Cosine of the refracted exit direction with the normal (outside).
    max_length : float
        Photons still inside after this length were dropped.
    """

    eta: float
    absorption: float
    photons: int
    radius: np.ndarray
    length: np.ndarray
    cos_out: np.ndarray
    max_length: float


def random_walk(eta: float, photons: int, absorption: float = 0.0, max_length: float = 1e6, seed: int = 1) -> Exits:
    """Walk `photons` photons into a semi-infinite medium of index `eta` and absorption ratio
    `absorption` = σ_a / σ'_s.

    Cost: without absorption a walk's length has a ~L^(-1/2) tail, so a photon costs ~sqrt(max_length)
    steps (~80 µs of a core at max_length = 1e6); with absorption a₀ it ends after ~1/a₀ steps.
    """
    if not (np.isfinite(eta) and eta >= 1.0) or photons < 1 or not max_length > 0 or not absorption >= 0:
        raise ValueError(f"random walk: need eta >= 1, photons >= 1, absorption >= 0, max_length > 0 "
                         f"(got {eta}, {photons}, {absorption}, {max_length})")
    parts = []
    for first in range(0, int(photons), CHUNK):  # photon k's stream depends on k alone, not on the chunking
        radius, length, cos_out = _walk(first, min(CHUNK, int(photons) - first), float(eta), float(absorption),
                                        float(max_length), int(seed))
        left = np.isfinite(radius)
        parts.append((radius[left], length[left], cos_out[left]))
    radius, length, cos_out = (np.concatenate(x) for x in zip(*parts))
    return Exits(float(eta), float(absorption), int(photons), radius, length, cos_out, float(max_length))


def exit_weights(exits: Exits, absorption: float) -> np.ndarray:
    """(m,) weight of each exit for σ_a / σ'_s = `absorption` (>= the walk's own), per launched photon."""
    if absorption < exits.absorption:
        raise ValueError(f"random walk: a walk at absorption {exits.absorption} cannot describe less ({absorption})")
    return np.exp(-(float(absorption) - exits.absorption) * exits.length) / exits.photons


def walk_total(exits: Exits, absorption: float) -> tuple[float, float]:
    """The total reflectance (share of the entered power that leaves) and its standard error."""
    w = exit_weights(exits, absorption)
    total = float(w.sum())
    second = float(np.square(w).sum()) * exits.photons
    return total, float(np.sqrt(max(second - total * total, 0.0) / exits.photons))
