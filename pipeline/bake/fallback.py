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
    - diffuse transmission (viewers that implement it): the slab's transmittance carried by the
      diffuse lobe, (1 - t) · factor · colour = T, the factor the largest channel's share (capped
      at 1) and the colour the rest. Such a viewer also lets the lit side reflect (1 - factor) of
      the lobe, darker than the slab by that share: glTF takes the light it transmits from the
      reflection, as this slab does.

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
    lobe = transmit / (1.0 - transmission) if transmission < 1.0 else np.zeros(3)
    dt_factor = float(np.clip(lobe.max(), 0.0, 1.0))
    dt_colour = np.clip(lobe / dt_factor, 0.0, 1.0) if dt_factor > 0 else np.ones(3)
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
    )
