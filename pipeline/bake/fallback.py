"""Standard glTF fallback parameters (KHR_materials_volume, KHR_materials_diffuse_transmission)
derived from a scattering material, so viewers without sssbake's shaders look plausible.
"""

from __future__ import annotations

import numpy as np

from sssbake.pipeline.core.dipole import DipoleParams, total_diffuse_reflectance
from sssbake.pipeline.core.materials import Material
from sssbake.pipeline.mesh.baked import Fallback
from sssbake.pipeline.mesh.scene import TextureRef


def make_fallback(
    material: Material,
    mm_per_unit: float,
    thickness_mm: np.ndarray,
    thickness_texture: TextureRef | None,
    thickness_max_units: float,
) -> Fallback:
    """Fallback parameters for `material` on a mesh whose file unit is `mm_per_unit` mm.

    - base colour: the closed-form total diffuse reflectance R_d per channel (what a thick slab of
      the material reflects under uniform light);
    - volume attenuation: Beer's law with the diffusion extinction σ_tr (diffuse light inside the
      medium decays as e^(-σ_tr x)); the distance is 1/max σ_tr so the colour stays in [1/e, 1];
    - diffuse transmission: the share that crosses the object's median thickness,
      mean over channels of e^(-σ_tr t), tinted by R_d.

    Parameters
    ----------
    thickness_mm : (n,) float64
        Baked per-vertex thickness in mm (empty when none was baked).
    thickness_max_units : float
        Largest thickness in file units (the texture's normalisation).
    """
    p = DipoleParams.from_material(material)
    rd = np.clip(total_diffuse_reflectance(p.alpha_prime, p.eta), 0.0, 1.0)
    sigma_units = p.sigma_tr * mm_per_unit  # 1/file-unit
    if sigma_units.max() > 0:
        distance = float(1.0 / sigma_units.max())
        colour = np.exp(-sigma_units * distance)
    else:  # no absorption: nothing attenuates; a huge distance keeps the spec's 'no attenuation'
        distance, colour = float(np.finfo(np.float32).max), np.ones(3)
    t_med = float(np.median(thickness_mm)) if len(thickness_mm) else 0.0
    transmission = float(np.clip(np.mean(np.exp(-p.sigma_tr * t_med)), 0.0, 1.0))
    return Fallback(
        base_color=tuple(float(x) for x in rd),
        thickness_texture=thickness_texture,
        thickness_factor=float(thickness_max_units),
        attenuation_color=tuple(float(x) for x in colour),
        attenuation_distance=distance,
        diffuse_transmission_factor=transmission,
        diffuse_transmission_color=tuple(float(x) for x in rd),
        ior=material.eta,
    )
