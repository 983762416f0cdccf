"""The disc mean of `sssbake.pipeline.core.disc_average` in numpy, term by term: the readable
definition that the compiled loops (`sssbake.pipeline.core.scatter_kernels`) follow and are tested
against, itself tested against closed forms (tests/core/test_disc_average.py)."""

from __future__ import annotations

import numpy as np

from sssbake.pipeline.core import disc_average as D
from sssbake.pipeline.core.disc_average import DiscMean
from sssbake.pipeline.core.profile import Profile, diffuse_reflectance_profile


def disc_mean_exact(d: np.ndarray, a: np.ndarray, p: Profile, height: np.ndarray | float = 0.0) -> np.ndarray:
    """Exact mean of Rd over a disc of radius a, the receiver `height` above the disc's plane
    and `d` from the disc's centre along that plane.

    Parameters
    ----------
    d, a : (...,) float64, mm, d >= 0, a > 0 (broadcast together)
    p : Profile
    height : (...,) float64, mm, >= 0
        Above the plane, Rd(sqrt(s² + h²)) is each pole with its depth z in the distance
        replaced by sqrt(z² + h²) (the numerator keeps z), so the closed forms still hold.

    Returns
    -------
    (..., 3) float64, 1/mm²
    """
    d, a, h = np.broadcast_arrays(*(np.asarray(v, dtype=np.float64) for v in (d, a, height)))
    x, w = np.polynomial.legendre.leggauss(D.NODES)
    t = (d / a)[..., None]
    out = np.empty(d.shape + (3,))
    inside = t[..., 0] < 1.0
    if np.any(inside):
        # φ ∈ [0, π] at nodes; ∫_D = (1/π) ∫ G(ρ(φ)) dφ with G = H(0) - H(ρ).
        phi = 0.5 * np.pi * (x + 1.0)
        ti, ai, hi = t[inside], a[inside][:, None], h[inside][:, None]
        rho = ai * (ti * np.cos(phi) + np.sqrt(np.clip(1.0 - (ti * np.sin(phi)) ** 2, 0.0, None)))
        g = _cumulative(rho, hi, p)  # (m, D.NODES, 3)
        out[inside] = 0.5 * np.einsum("k,mkc->mc", w, g) / (np.pi * ai**2)
    if np.any(~inside):
        # ψ ∈ [0, π/2]; sin φ = sin ψ / t, dφ = cos ψ / (t cos φ) dψ; ρ± = a (t cos φ ± cos ψ).
        psi = 0.25 * np.pi * (x + 1.0)
        to, ao, ho = t[~inside], a[~inside][:, None], h[~inside][:, None]
        cos_phi = np.sqrt(np.clip(1.0 - (np.sin(psi) / to) ** 2, 0.0, None))
        near, far = ao * (to * cos_phi - np.cos(psi)), ao * (to * cos_phi + np.cos(psi))
        jac = np.cos(psi) / np.maximum(to * cos_phi, 1e-300)
        band = _tail(near, ho, p) - _tail(far, ho, p)  # (m, D.NODES, 3)
        out[~inside] = (0.25 * np.pi) * np.einsum("k,mk,mkc->mc", w, jac, band) / (np.pi * np.pi * ao**2)
    return out


def _cumulative(r: np.ndarray, h: np.ndarray, p: Profile) -> np.ndarray:
    """G(r) = 2π ∫_0^r Rd(sqrt(s² + h²)) s ds = H(0) - H(r), free of cancellation for small r, (..., 3)."""
    r2 = np.square(r)[..., None]
    h2 = np.square(h)[..., None]
    total = np.zeros(np.broadcast_shapes(r2.shape, h2.shape)[:-1] + (3,))
    for w, z, s in zip(p.weight, p.depth, p.sigma):
        lifted = np.sqrt(h2 + z * z)
        excess = r2 / (np.sqrt(r2 + lifted * lifted) + lifted)  # D - z̃, computed stably
        total += w * z * np.exp(-s * lifted) / lifted * -np.expm1(-np.log1p(excess / lifted) - s * excess)
    return 0.5 * total


def _tail(r: np.ndarray, h: np.ndarray, p: Profile) -> np.ndarray:
    """H(r) = 2π ∫_r^∞ Rd(sqrt(s² + h²)) s ds in closed form, (..., 3)."""
    r2 = np.square(r)[..., None]
    h2 = np.square(h)[..., None]
    total = np.zeros(np.broadcast_shapes(r2.shape, h2.shape)[:-1] + (3,))
    for w, z, s in zip(p.weight, p.depth, p.sigma):
        dist = np.sqrt(r2 + h2 + z * z)
        total += w * z * np.exp(-s * dist) / dist
    return 0.5 * total


def is_point(table: DiscMean, d: np.ndarray, a: np.ndarray) -> np.ndarray:
    """(m,) bool: pairs far enough from a small enough disc that ḡ is Rd(d) itself."""
    return (d > D.POINT_REACH * a) & (a * float(table.params.sigma_tr.max()) < D.POINT_SIGMA)


def disc_mean(means: DiscMean, d: np.ndarray, a: np.ndarray, height: np.ndarray) -> np.ndarray:
    """ḡ for pairs at distance d from sources of radius a, the receiver `height` off the
    source's tangent plane (|offset · n_i|); mm, (m,) each -> (m, 3). a = 0 gives Rd(d).

    Receivers nearly in the source's plane (height <= `D.OFF_PLANE`·d: neighbours on a smooth
    surface) read the planar table at the distance d; those well off it (across a thin part
    or a fold, where the planar disc would wrongly cover the receiver) take the exact mean
    over the tilted disc; pairs beyond the table take the expansion for a tilted disc."""
    d = np.asarray(d, dtype=np.float64)
    a = np.asarray(a, dtype=np.float64)
    h = np.minimum(np.asarray(height, dtype=np.float64), d)
    out = np.empty((len(d), 3))
    t = d / np.maximum(a, 1e-300)
    u = (np.log(np.maximum(a, 1e-300)) - means.log_a0) / D.LOG_A_STEP
    close = (t <= D.TABLE_REACH) & (u >= 0.0)  # above the range cannot happen: built from these radii
    tabled = close & (h <= D.OFF_PLANE * d)
    edge = tabled & (np.abs(t - 1.0) < D.EDGE_BAND) & (a > D.EDGE_SHARP * float(means.params.z_min.min()))
    tabled &= ~edge
    # Off the plane, a disc small against the kernel's scale there takes the expansion too.
    tilted = close & ~tabled & (a > D.SMALL_TILTED * np.sqrt(d * d + means.params.z_min.min() ** 2))
    close = tabled | tilted | edge
    if np.any(edge):
        out[edge] = disc_mean_exact(d[edge], a[edge], means.params)
    if np.any(tabled):
        ui = np.clip(u[tabled], 0.0, means.log_table.shape[1] - 1.000001)
        ti = np.clip(t[tabled] / D.T_STEP, 0.0, means.log_table.shape[2] - 1.000001)
        i, j = ui.astype(np.int64), ti.astype(np.int64)
        fu, ft = ui - i, ti - j
        for c, table in enumerate(means.log_table):
            v = ((1 - fu) * ((1 - ft) * table[i, j] + ft * table[i, j + 1])
                 + fu * ((1 - ft) * table[i + 1, j] + ft * table[i + 1, j + 1]))
            out[tabled, c] = np.exp(v)
    if np.any(tilted):
        # Half a radius or more above the disc, no node comes close to the receiver and a
        # 32-node polar rule holds (~1e-4); nearer the plane, the exact mean.
        high = np.flatnonzero(tilted)
        low = high[h[high] < D.POLAR_HEIGHT * a[high]]
        high = high[h[high] >= D.POLAR_HEIGHT * a[high]]
        for pick, exact in ((low, True), (high, False)):
            if len(pick) == 0:
                continue
            along = np.sqrt(np.maximum(d[pick] ** 2 - h[pick] ** 2, 0.0))
            if exact:
                out[pick] = disc_mean_exact(along, a[pick], means.params, h[pick])
            else:
                rho, cos_phi, weight = D._POLAR_RULE
                ap = a[pick, None]
                r2 = h[pick, None] ** 2 + along[:, None] ** 2 + (ap * rho) ** 2 - 2.0 * along[:, None] * ap * rho * cos_phi
                out[pick] = np.einsum("k,mkc->mc", weight, diffuse_reflectance_profile(np.sqrt(r2), means.params))
    # Far from a small disc the spread term is below ~1e-3 of Rd: the point value, for all
    # three channels at once (most pairs of the offline reference are of this kind).
    point = ~close & is_point(means, d, a)
    if np.any(point):
        out[point] = diffuse_reflectance_profile(d[point], means.params)
    rest = ~close & ~point
    if np.any(rest):
        out[rest] = disc_expansion(d[rest], a[rest], h[rest], means.params)
    return out


def disc_expansion(r: np.ndarray, a: np.ndarray, h: np.ndarray, p: Profile) -> np.ndarray:
    """Rd(r) + ½ tr(H Σ) for discs of radius a (covariance (a²/4)(I - n nᵀ)) seen from `h` off
    their plane, clipped at 0; (m,) each -> (m, 3).

    With c = û·n = h/r, ½ tr(H Σ) = (a²/8) (Rd'' (1 - c²) + Rd'/r (1 + c²)). Per
    pole (D² = r² + z², P = σ D) every piece is e^(-P)/D³ times a polynomial in P
    (`profile.profile_derivatives`), so the sum is

        z e^(-P)/D³ [1 + P + (a²/8D²) ((1 - c²)(Q₃ r²/D² - Q₂ z²/D²) - (1 + c²) Q₂)]

    with Q₂ = P² + 3P + 3, Q₃ = P³ + 5P² + 12P + 12: half the passes of evaluating Rd, Rd'
    and Rd'' apart, and finite at r = 0 (duplicate vertices), where Rd'/r is Rd''.
    """
    r2 = r * r
    c2 = np.divide(h * h, r2, out=np.zeros(len(r)), where=r > 0)
    spread = 0.125 * a * a
    out = np.empty((len(r), 3))
    for c in range(3):
        total = np.zeros(len(r))
        for w, z, s in zip(*p.channel(c)):
            d2 = r2 + z * z
            d = np.sqrt(d2)
            big_p = s * d
            q2 = big_p * (big_p + 3.0) + 3.0
            q3 = big_p * (big_p * (big_p + 5.0) + 12.0) + 12.0
            bracket = ((1.0 - c2) * (q3 * r2 - q2 * (z * z)) / d2 - (1.0 + c2) * q2) * (spread / d2) + (1.0 + big_p)
            total += w * z * np.exp(-big_p) / (d2 * d) * bracket
        out[:, c] = np.maximum(total / (4.0 * np.pi), 0.0)
    return out
