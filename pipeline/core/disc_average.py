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

import numpy as np

from sssbake.pipeline.core.profile import Profile, diffuse_reflectance_profile

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
    x, w = np.polynomial.legendre.leggauss(NODES)
    t = (d / a)[..., None]
    out = np.empty(d.shape + (3,))
    inside = t[..., 0] < 1.0
    if np.any(inside):
        # φ ∈ [0, π] at nodes; ∫_D = (1/π) ∫ G(ρ(φ)) dφ with G = H(0) - H(ρ).
        phi = 0.5 * np.pi * (x + 1.0)
        ti, ai, hi = t[inside], a[inside][:, None], h[inside][:, None]
        rho = ai * (ti * np.cos(phi) + np.sqrt(np.clip(1.0 - (ti * np.sin(phi)) ** 2, 0.0, None)))
        g = _cumulative(rho, hi, p)  # (m, NODES, 3)
        out[inside] = 0.5 * np.einsum("k,mkc->mc", w, g) / (np.pi * ai**2)
    if np.any(~inside):
        # ψ ∈ [0, π/2]; sin φ = sin ψ / t, dφ = cos ψ / (t cos φ) dψ; ρ± = a (t cos φ ± cos ψ).
        psi = 0.25 * np.pi * (x + 1.0)
        to, ao, ho = t[~inside], a[~inside][:, None], h[~inside][:, None]
        cos_phi = np.sqrt(np.clip(1.0 - (np.sin(psi) / to) ** 2, 0.0, None))
        near, far = ao * (to * cos_phi - np.cos(psi)), ao * (to * cos_phi + np.cos(psi))
        jac = np.cos(psi) / np.maximum(to * cos_phi, 1e-300)
        band = _tail(near, ho, p) - _tail(far, ho, p)  # (m, NODES, 3)
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


@dataclass(frozen=True, eq=False)
class DiscMean:
    """ḡ(d, a) for many pairs: a table of ln ḡ over (ln a, d/a) for the discs of one surface.

    Build with `DiscMean.build`; call with distances and source radii.

    Attributes
    ----------
    params : Profile
    log_a0 : float
        ln of the smallest tabulated radius (mm).
    log_table : (3, A, T) float64
        ln ḡ per channel at ln a = log_a0 + i·LOG_A_STEP, d/a = j·T_STEP.
    """

    params: Profile
    log_a0: float
    log_table: np.ndarray

    @staticmethod
    def build(params: Profile, radii_mm: np.ndarray) -> "DiscMean":
        """Tabulate for source radii in the range of `radii_mm` (any shape, mm; zeros ignored)."""
        radii = np.asarray(radii_mm, dtype=np.float64)
        floor = SMALL_DISC * float(params.z_min.min())
        big = radii[radii >= floor]
        lo = float(np.log(big.min())) if len(big) else float(np.log(floor))
        hi = float(np.log(big.max())) if len(big) else lo
        count_a = int(np.ceil((hi - lo) / LOG_A_STEP)) + 2
        count_t = int(round(TABLE_REACH / T_STEP)) + 1
        a = np.exp(lo + LOG_A_STEP * np.arange(count_a))
        t = T_STEP * np.arange(count_t)
        mean = disc_mean_exact((a[:, None] * t[None, :]).ravel(), np.repeat(a, count_t), params)
        log_table = np.log(np.maximum(mean, 1e-300)).reshape(count_a, count_t, 3).transpose(2, 0, 1).copy()
        return DiscMean(params, lo, log_table)

    def is_point(self, d: np.ndarray, a: np.ndarray) -> np.ndarray:
        """(m,) bool: pairs far enough from a small enough disc that ḡ is Rd(d) itself."""
        return (d > POINT_REACH * a) & (a * float(self.params.sigma_tr.max()) < POINT_SIGMA)

    def __call__(self, d: np.ndarray, a: np.ndarray, height: np.ndarray) -> np.ndarray:
        """ḡ for pairs at distance d from sources of radius a, the receiver `height` off the
        source's tangent plane (|offset · n_i|); mm, (m,) each -> (m, 3). a = 0 gives Rd(d).

        Receivers nearly in the source's plane (height <= `OFF_PLANE`·d: neighbours on a smooth
        surface) read the planar table at the distance d; those well off it (across a thin part
        or a fold, where the planar disc would wrongly cover the receiver) take the exact mean
        over the tilted disc; pairs beyond the table take the expansion for a tilted disc."""
        d = np.asarray(d, dtype=np.float64)
        a = np.asarray(a, dtype=np.float64)
        h = np.minimum(np.asarray(height, dtype=np.float64), d)
        out = np.empty((len(d), 3))
        t = d / np.maximum(a, 1e-300)
        u = (np.log(np.maximum(a, 1e-300)) - self.log_a0) / LOG_A_STEP
        close = (t <= TABLE_REACH) & (u >= 0.0)  # above the range cannot happen: built from these radii
        tabled = close & (h <= OFF_PLANE * d)
        edge = tabled & (np.abs(t - 1.0) < EDGE_BAND) & (a > EDGE_SHARP * float(self.params.z_min.min()))
        tabled &= ~edge
        # Off the plane, a disc small against the kernel's scale there takes the expansion too.
        tilted = close & ~tabled & (a > SMALL_TILTED * np.sqrt(d * d + self.params.z_min.min() ** 2))
        close = tabled | tilted | edge
        if np.any(edge):
            out[edge] = disc_mean_exact(d[edge], a[edge], self.params)
        if np.any(tabled):
            ui = np.clip(u[tabled], 0.0, self.log_table.shape[1] - 1.000001)
            ti = np.clip(t[tabled] / T_STEP, 0.0, self.log_table.shape[2] - 1.000001)
            i, j = ui.astype(np.int64), ti.astype(np.int64)
            fu, ft = ui - i, ti - j
            for c, table in enumerate(self.log_table):
                v = ((1 - fu) * ((1 - ft) * table[i, j] + ft * table[i, j + 1])
                     + fu * ((1 - ft) * table[i + 1, j] + ft * table[i + 1, j + 1]))
                out[tabled, c] = np.exp(v)
        if np.any(tilted):
            # Half a radius or more above the disc, no node comes close to the receiver and a
            # 32-node polar rule holds (~1e-4); nearer the plane, the exact mean.
            high = np.flatnonzero(tilted)
            low = high[h[high] < POLAR_HEIGHT * a[high]]
            high = high[h[high] >= POLAR_HEIGHT * a[high]]
            for pick, exact in ((low, True), (high, False)):
                if len(pick) == 0:
                    continue
                along = np.sqrt(np.maximum(d[pick] ** 2 - h[pick] ** 2, 0.0))
                if exact:
                    out[pick] = disc_mean_exact(along, a[pick], self.params, h[pick])
                else:
                    rho, cos_phi, weight = _POLAR_RULE
                    ap = a[pick, None]
                    r2 = h[pick, None] ** 2 + along[:, None] ** 2 + (ap * rho) ** 2 - 2.0 * along[:, None] * ap * rho * cos_phi
                    out[pick] = np.einsum("k,mkc->mc", weight, diffuse_reflectance_profile(np.sqrt(r2), self.params))
        # Far from a small disc the spread term is below ~1e-3 of Rd: the point value, for all
        # three channels at once (most pairs of the offline reference are of this kind).
        point = ~close & self.is_point(d, a)
        if np.any(point):
            out[point] = diffuse_reflectance_profile(d[point], self.params)
        rest = ~close & ~point
        if np.any(rest):
            out[rest] = _disc_expansion(d[rest], a[rest], h[rest], self.params)
        return out


def _disc_expansion(r: np.ndarray, a: np.ndarray, h: np.ndarray, p: Profile) -> np.ndarray:
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


def _polar_rule(rings: int, angles: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Nodes (ρ/a, cos φ) and weights of a mean over the unit disc: Gauss-Legendre in ρ² (equal
    area), the midpoint rule in φ over [0, π] (the integrand is even in φ)."""
    x, w = np.polynomial.legendre.leggauss(rings)
    rho = np.sqrt(0.5 * (x + 1.0))
    phi = (np.arange(angles) + 0.5) * np.pi / angles
    return np.repeat(rho, angles), np.tile(np.cos(phi), rings), np.repeat(0.5 * w, angles) / angles


_POLAR_RULE = _polar_rule(4, 8)
