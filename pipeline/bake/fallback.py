"""Standard glTF fallback parameters (KHR_materials_transmission, KHR_materials_volume,
KHR_materials_diffuse_transmission) derived from a scattering material, so viewers without
sssbake's shaders show a translucent object: not black, not opaque.

The object is treated as a slab of its median thickness d. The multipole model (Donner & Jensen
2005: the dipole mirrored in both extrapolated boundaries of the slab) gives, per channel, the
slab's total diffuse reflectance R(d) and transmittance T(d) (`slab_totals`). A semi-infinite
medium reflects R_d = R(∞) and transmits nothing; a slab thin for its diffusion length reflects
less, R(d) < R_d, because light that a thicker medium would have scattered back leaves through the
far side instead.

three.js 0.187 (GLTFLoader → MeshPhysicalMaterial), the common web runtime, implements transmission,
volume and ior but not diffuse transmission, and mixes its diffuse lobe with the refracted view of
the scene behind: ``(1 - transmission) · base · Lambert + transmission · base · Beer(x) · behind``.
So the fallback keeps base colour R_d and takes the light the slab transmits out of the reflection
with ``transmission``; the refracted part then shows what lies behind the object, attenuated with
the diffusion extinction over the local thickness x (the thickness texture). Base colour and
attenuation stay what `planning.assign.material_from_khr_volume` inverts, so a re-baked sssbake
output maps back to its coefficients.

Viewers that implement diffuse transmission (Babylon.js, Blender, the Khronos sample viewer) take
its lobe out of the lit side's reflection as well: they reflect (1 - factor) of what three.js
reflects with the same file, whatever the base colour, so no factor is right for both. The factor
is the compromise `diffuse_transmission_share` states; the slab transmittance itself is written
whole into sssbake's own extension (``slabTransmittance``) for sssbake's runtime.
"""

from __future__ import annotations

import numpy as np

from sssbake.pipeline.core.profile import classical_dipole, profile_for, profile_total, total_reflectance
from sssbake.pipeline.core.materials import Material
from sssbake.pipeline.mesh.baked import Fallback
from sssbake.pipeline.mesh.scene import TextureRef


def _image_sum(c: np.ndarray, period: np.ndarray, sigma: np.ndarray) -> np.ndarray:
    """S(c) = Σ_{i ∈ ℤ} sign(c + i·L) e^(-σ |c + i·L|) for |c| < L = `period`, in closed form.

    The i = 0 term is sign(c) e^(-σ|c|); the terms i >= 1 are positive and i <= -1 negative, two
    geometric series whose sum is -2 sinh(σc) / (e^(σL) - 1), evaluated as
    -sign(c) e^(σ(|c| - L)) (1 - e^(-2σ|c|)) / (1 - e^(-σL)): no exponent is positive, and it tends
    to -2c/L as σ → 0, so the form stays finite without absorption (where a truncated sum would
    not converge).
    """
    a, sl = np.abs(c), sigma * period
    safe = np.where(sl > 0, sl, 1.0)
    geometric = np.exp(sigma * (a - period)) * -np.expm1(-2.0 * sigma * a) / -np.expm1(-safe)
    tail = -np.sign(c) * np.where(sl > 0, geometric, 2.0 * a / period)
    return np.sign(c) * np.exp(-sigma * a) + tail


def slab_totals(material: Material, thickness_mm: float) -> tuple[np.ndarray, np.ndarray]:
    """Total diffuse reflectance and transmittance of a slab, multipole model, per channel.

    The multipole geometry is the classical dipole's; the reflectance is scaled so that a thick
    slab reflects what the material's profile model does (`profile.total_reflectance`: the Monte
    Carlo total for the default model, R_d itself for the dipole).

    Light first scatters at depth z_s = min(z_r, d/2) (z_r = 1/σ'_t; the source cannot lie beyond
    a thin slab). Real sources sit at z_s + i·L, virtual ones at -z_s - 2 z_b + i·L (i ∈ ℤ), with
    L = 2(d + 2 z_b), z_b = 2A/(3 σ'_t) the extrapolation distance (z_s = z_r: Jensen's dipole,
    z_v = z_r + 2 z_b) and A the boundary term. A source at signed depth z adds
    2π ∫ z (1 + σ_tr D) e^(-σ_tr D) / D³ r dr = 2π sign(z) e^(-σ_tr |z|) (D² = r² + z²) to the
    flux through the plane; with S the closed-form image sum (`_image_sum`), the diffusion part is

        R_s = α'/2 [S(z_s) - S(-z_s - 2 z_b)],   T_s = α'/2 [S(d - z_s) - S(d + z_s + 2 z_b)].

    Only the share w = 1 - e^(-d σ'_t) scatters at all; the rest crosses unscattered:
    R = w R_s, T = (1 - w) + w T_s. For d → ∞ R is the profile's total reflectance and T is 0; for
    d → 0, R = 0 and T = 1; without absorption R + T = 1. T falls with d; where d < 2 z_r the
    shallower source lets R exceed R_d slightly (by under 0.01 in the 12 measured presets).

    Parameters
    ----------
    material : Material
    thickness_mm : float
        Slab thickness d, mm, >= 0.

    Returns
    -------
    reflectance, transmittance : (3,) float64 each, in [0, 1]
    """
    d = float(thickness_mm)
    p = classical_dipole(material.sigma_s_prime, material.sigma_a, material.eta)
    (z_r, z_v), sigma_tr = p.depth, p.sigma_tr
    z_b = 0.5 * (z_v - z_r)
    z_s = np.minimum(z_r, 0.5 * d)
    period = 2.0 * (d + 2.0 * z_b)
    half = 0.5 * p.alpha_prime
    scattered = -np.expm1(-d / z_r)
    r = half * (_image_sum(z_s, period, sigma_tr) - _image_sum(-z_s - 2.0 * z_b, period, sigma_tr))
    t = half * (_image_sum(d - z_s, period, sigma_tr) - _image_sum(d + z_s + 2.0 * z_b, period, sigma_tr))
    thick = profile_total(p)
    r = r * np.divide(total_reflectance(profile_for(material)), thick, out=np.ones(3), where=thick > 0)
    r, t = scattered * r, (1.0 - scattered) + scattered * t
    t = np.clip(t, 0.0, 1.0)
    return np.clip(r, 0.0, 1.0 - t), t  # a model brighter than the dipole must not create light


def diffuse_transmission_share(transmit: np.ndarray, keep: float) -> tuple[float, np.ndarray]:
    """KHR_materials_diffuse_transmission's factor f and colour c for a slab transmitting `transmit`
    under a diffuse lobe of weight `keep` = 1 - transmission.

    A viewer implementing the extension reflects (1 - f) of the lit-side light three.js reflects
    (whose (1 - t) R_d is the slab's reflectance) and transmits keep · f · c_c; with c_c ≤ 1 the
    nearest it comes to T_c is min(T_c, keep · f), so c_c = min(1, T_c / (keep f)). f trades the
    lit side's loss against the far side's shortfall; it minimises their squared errors in stops,

        J(f) = 3 ln²(1 - f) + Σ_{c: T_c > 0} ln²(min(1, keep f / T_c)),

    one term per channel and side, the two sides weighted alike (a convex object under one light,
    seen from directions uniform on the sphere, shows as much lit as unlit area on average).
    Relative errors, because a side shown half as bright looks as wrong on a dark material as on a
    light one. Each term is convex on (0, 1) (ln²(af) has second derivative 2(1 - ln af)/f² > 0
    while af ≤ 1), so J' increases from -∞ to +∞ and its root is found by bisection. T = (0.53,
    0.30, 0.10) (2 mm of skin1, keep 0.77) gives f = 0.36: the lit side 0.64× three.js', red's
    far side 0.52× the slab's; carrying all of T would need f = 0.69 and leave the lit side 0.31×.

    Returns
    -------
    factor : float in [0, 1)
        0 when nothing is transmitted or nothing is kept.
    colour : (3,) float64 in [0, 1]
    """
    transmit = np.asarray(transmit, dtype=np.float64)
    if keep <= 0.0 or not np.any(transmit > 0):
        return 0.0, np.ones(3)
    lit = transmit > 0

    def slope(f: float) -> float:
        short = lit & (keep * f < transmit)
        return (-6.0 * np.log1p(-f) / (1.0 - f)
                + float(np.sum(2.0 * np.log(keep * f / transmit[short]))) / f)

    lo, hi = 0.0, 1.0
    for _ in range(64):  # halves [0, 1] below float64's spacing near the root
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if slope(mid) < 0 else (lo, mid)
    factor = 0.5 * (lo + hi)
    return factor, np.clip(transmit / (keep * factor), 0.0, 1.0)


def make_fallback(
    material: Material,
    mm_per_unit: float,
    thickness_mm: np.ndarray,
    thickness_texture: TextureRef | None,
    thickness_max_units: float,
) -> Fallback:
    """Fallback parameters for `material` on a mesh whose file unit is `mm_per_unit` mm.

    With R_d the total diffuse reflectance and R, T the reflectance and transmittance of a slab of
    the median thickness (`slab_totals`):

    - base colour: R_d per channel (what a thick piece reflects; viewers that ignore every
      extension, pyrender and most game engines' defaults, show this);
    - transmission: the scalar t minimising Σ_c ((1 - t) R_d,c - R_c)², t = 1 - ΣR_d R / ΣR_d²,
      in [0, 1], so three.js's diffuse lobe (1 - t) · R_d reflects what the slab reflects; 0 for
      an object thick for its diffusion length, which stays as opaque as it is;
    - volume attenuation: Beer's law with the diffusion extinction σ_tr (diffuse light inside the
      medium decays as e^(-σ_tr x)), in file units: distance 1/max σ_tr so the colour stays in
      [1/e, 1]; thickness: the baked thickness texture times its largest value, file units;
    - diffuse transmission (viewers that implement it): factor and colour from
      `diffuse_transmission_share`, which balances the lit side such a viewer darkens by
      (1 - factor) against the share of T the lobe carries;
    - slab transmittance: T itself, for sssbake's runtime (which darkens no lit side).

    Parameters
    ----------
    thickness_mm : (n,) float64
        Baked per-vertex thickness in mm (empty when none was baked: then a semi-infinite medium,
        t = 0, nothing transmitted).
    thickness_max_units : float
        Largest thickness in file units (the texture's normalisation).
    """
    p = profile_for(material)
    rd = np.clip(total_reflectance(p), 0.0, 1.0)
    sigma_units = p.sigma_tr * mm_per_unit  # 1/file-unit
    if sigma_units.max() > 0:
        distance = float(1.0 / sigma_units.max())
        colour = np.exp(-sigma_units * distance)
    else:  # no absorption: nothing attenuates; a huge distance keeps the spec's 'no attenuation'
        distance, colour = float(np.finfo(np.float32).max), np.ones(3)
    if len(thickness_mm):
        reflect, transmit = slab_totals(material, float(np.median(thickness_mm)))
    else:
        reflect, transmit = rd, np.zeros(3)
    norm = float(rd @ rd)
    transmission = float(np.clip(1.0 - (rd @ reflect) / norm, 0.0, 1.0)) if norm > 0 else 0.0
    dt_factor, dt_colour = diffuse_transmission_share(transmit, 1.0 - transmission)
    return Fallback(
        base_color=tuple(float(x) for x in rd),
        thickness_texture=thickness_texture,
        thickness_factor=float(thickness_max_units),
        attenuation_color=tuple(float(x) for x in colour),
        attenuation_distance=distance,
        diffuse_transmission_factor=dt_factor,
        diffuse_transmission_color=tuple(float(x) for x in dt_colour),
        ior=material.eta,
        transmission_factor=transmission,
        slab_transmittance=tuple(float(x) for x in transmit),
    )
