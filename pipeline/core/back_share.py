"""Where the profile's gather over an object puts its light, in front of or behind each receiver,
and the two factors that make it let out what the object's random walk does
(`Material.escape_gain`, `Material.back_gain`).

A receiver o lit from a direction ω with n_o·ω < 0 sees only light that entered elsewhere and
crossed the medium: through a thin part that is transmission, and the half-space profile R(r),
evaluated at the chord across, carries far too little of it. On an infinite 2 mm slab of skin1
lit along its normal a walk lets through 1.48, 1.27, 0.80 × what it reflects (red, green, blue);
the gather 0.49, 0.20, 0.05 ×: skin1's blue crosses 2 mm in a few flights, which no diffusion
profile describes.

The object's walk (`mesh.escape_gain`) splits the light that enters under even, unoccluded light
into what leaves in front of the light it came from (g_F, over a plane's escape share) and behind
it (g_B). The gather splits the same light the same way: at a receiver o,

    G(o) = Σ_i W(o, i),  B(o) = Σ_i W(o, i) h(n_o·n_i),  h(μ) = ∫_{n_o·ω < 0} max(0, n_i·ω)/π dω

(W the gather's cell integrals, `near_field`; h the share of a cosine-weighted source's light that
arrives from behind a receiver whose normal makes cosine μ with the source's: 0 at μ = 1, 1 at
μ = -1; the walk's entry law, no Fresnel factor, so both sides count the same light). The bake
scales down a source that sends out more than R_tot in all (both faces of a thin slab together
receive ~1.4 R_tot from each source), by the symmetry of R(|x - y|) a factor min(1, R_tot/G) at
the source's own point; the area means of that limited gather's parts over R_tot are `front` and
`back`. So

    escape_gain = g_F / front,   back_gain = (g_B / back) / escape_gain

scale the profile, and on top of it what comes from behind. One number per channel and object: it
corrects the level of what crosses; the profile's spread sets where it lands.
"""

from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from sssbake.pipeline.core.near_field import NearField
from sssbake.pipeline.core.profile import Profile, profile_total, radius_for_energy
from sssbake.pipeline.core.scatter_kernels import gather_rows

#: Points the shares are averaged over at most (an area-weighted mean: ~1 % noise from sampling).
POINTS = 1024
#: Share of R_tot the gather may drop beyond its radius.
ENERGY_DROPPED = 1e-3
#: Photons the walk must have seen leave behind before its share is trusted (~5 % error).
MIN_BEHIND = 400
#: Nodes in μ of the table of h, and in cos θ of its integral.
_MU_NODES, _THETA_NODES = 401, 2048


def behind_share(mu: np.ndarray) -> np.ndarray:
    """h(μ): of a cosine-weighted light arriving at a source of normal n_i, the share whose
    direction ω lies behind a receiver's normal n_o (n_o·ω < 0), for n_o·n_i = μ.

    With θ the angle of ω to n_i, the azimuths behind n_o span 2 arccos(μ cos θ / (sin α sin θ))
    (cos α = μ), so h(μ) = ∫_0^1 2u · arccos(clip(μ u / (sqrt(1-μ²) sqrt(1-u²)))) / π du, u = cos θ.
    """
    mu = np.clip(np.asarray(mu, dtype=np.float64), -1.0, 1.0)
    u = (np.arange(_THETA_NODES) + 0.5) / _THETA_NODES
    sin_a = np.sqrt(1.0 - mu * mu)[..., None]
    # μ = ±1: every direction the source sees is in front of (μ = 1) or behind (μ = -1) the receiver
    c = np.where(sin_a > 0.0, mu[..., None] * u / np.maximum(sin_a * np.sqrt(1.0 - u * u), 1e-300),
                 np.where(mu[..., None] > 0.0, 1.0, -1.0))
    return (2.0 * u * np.arccos(np.clip(c, -1.0, 1.0)) / np.pi).mean(axis=-1)


def gathered(positions_mm: np.ndarray, faces: np.ndarray, normals: np.ndarray, profile: Profile,
             points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """G and B (module docstring) at the vertices `points`.

    Parameters
    ----------
    positions_mm : (n, 3) float64
    faces : (m, 3) int
    normals : (n, 3) float64
        Unit vertex normals.
    profile : Profile
    points : (k,) int64

    Returns
    -------
    total, behind : (k, 3) float64
    """
    x = np.ascontiguousarray(positions_mm, dtype=np.float64)
    normals = np.ascontiguousarray(normals, dtype=np.float64)
    points = np.ascontiguousarray(points, dtype=np.int64)
    field = NearField.build(x, faces, normals, profile)
    radius = radius_for_energy(ENERGY_DROPPED, profile)
    h_grid = behind_share(np.linspace(-1.0, 1.0, _MU_NODES))
    total, behind = np.zeros((len(points), 3)), np.zeros((len(points), 3))
    threads = len(os.sched_getaffinity(0))
    # blocks of receivers, several per thread: their costs differ with how much lies within the radius
    bounds = np.linspace(0, len(points), min(len(points), 8 * threads) + 1).astype(np.int64)
    args = field.kernel_args

    def gather(k: int) -> None:
        """Receivers bounds[k]..bounds[k + 1] - 1: their rows of `total` and `behind` alone, each
        row's pairs in source order whatever the threads (the sums are the same bits)."""
        gather_rows(bounds[k], bounds[k + 1], points, normals, radius, h_grid, *args, total, behind)

    with ThreadPoolExecutor(threads) as pool:  # the rows release the GIL
        list(pool.map(gather, range(len(bounds) - 1)))
    return total, behind


def gathered_shares(positions_mm: np.ndarray, faces: np.ndarray, normals: np.ndarray, areas_mm2: np.ndarray,
                    profile: Profile, seed: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """(3,) `front` and (3,) `back`: the area means over R_tot of the energy-limited gather's light
    in front of and behind its receivers under even light (module docstring), from up to `POINTS`
    vertices drawn at random."""
    n = len(positions_mm)
    points = np.arange(n) if n <= POINTS else np.sort(np.random.default_rng(seed).choice(n, POINTS, replace=False))
    total, behind = gathered(positions_mm, faces, normals, profile, points)
    r_tot = profile_total(profile)
    limit = np.minimum(1.0, r_tot / np.maximum(total, 1e-300))
    a = np.asarray(areas_mm2, dtype=np.float64)[points]
    mean = lambda v: (a @ v) / max(float(a.sum()), 1e-300) / r_tot  # noqa: E731
    return mean(limit * (total - behind)), mean(limit * behind)


def object_gains(walk_front: tuple, walk_back: tuple, walk_behind: tuple, front: np.ndarray,
                 back: np.ndarray) -> tuple[tuple[float, float, float], tuple[float, float, float]]:
    """`Material.escape_gain` g_F / front and `Material.back_gain` (g_B / back) / escape_gain per
    channel (module docstring). Where the walk saw fewer than `MIN_BEHIND` photons leave behind,
    or the gather brings nothing from behind, the light behind is not scaled on its own: one
    factor (g_F + g_B) / (front + back) for all of it."""
    gains, backs = [], []
    for g_f, g_b, count, f, b in zip(walk_front, walk_back, walk_behind, front, back):
        if count >= MIN_BEHIND and b > 1e-9 and f > 1e-9:
            gains.append(float(g_f / f))
            backs.append(float(g_b / b / gains[-1]))
        else:
            gains.append(float((g_f + g_b) / max(f + b, 1e-300)))
            backs.append(1.0)
    return tuple(gains), tuple(backs)
