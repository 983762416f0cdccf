"""The radiance a glTF viewer draws of sssbake's standard fallback material under verify's lobe,
per vertex, for `verify --reference volpath`.

The fallback (`bake.fallback.make_fallback`) is base colour R_tot, ``KHR_materials_transmission``
t, ``KHR_materials_diffuse_transmission`` factor f and colour c. The glTF BSDF a viewer that
implements both evaluates is

    f_s = (1 - t) [(1 - f) base / π  on the lit side  +  f c / π  on the far side] + t · specular transmission,

so its diffuse radiance under the lobe is

    L = (1 - t) [(1 - f) base E+ + f c E-] / π,

E+ the irradiance on the vertex's own hemisphere, with the geometry's shadows (as verify's Lambert
has them), and E- the irradiance on the opposite hemisphere, unshadowed: a viewer lights the
diffuse transmission lobe through the object without a shadow test (a shadow map would hide it
behind the object itself). The specular transmission (t) shows what lies behind the object
through a rough refraction, a surface term like the mirror reflection the truth leaves out; it is
not drawn (t is 0 for objects thick for their diffusion length).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class FallbackLook:
    """The glTF fallback's factors (see the module docstring).

    Attributes
    ----------
    base_color, diffuse_transmission_color : (3,) float
    transmission, diffuse_transmission : float
    """

    base_color: tuple[float, float, float]
    transmission: float
    diffuse_transmission: float
    diffuse_transmission_color: tuple[float, float, float]

    @classmethod
    def of(cls, material) -> FallbackLook | None:
        """A pygltflib ``Material``'s fallback factors; None when its base colour is a texture
        (the look is then per texel, not a factor)."""
        pbr = material.pbrMetallicRoughness
        if pbr is not None and pbr.baseColorTexture is not None:
            return None
        ext = material.extensions or {}
        base = (pbr.baseColorFactor if pbr is not None and pbr.baseColorFactor else [1.0, 1.0, 1.0, 1.0])[:3]
        diffuse = ext.get("KHR_materials_diffuse_transmission", {})
        return cls(tuple(float(x) for x in base),
                   float(ext.get("KHR_materials_transmission", {}).get("transmissionFactor", 0.0)),
                   float(diffuse.get("diffuseTransmissionFactor", 0.0)),
                   tuple(float(x) for x in diffuse.get("diffuseTransmissionColorFactor", [1.0, 1.0, 1.0])))

    def radiance(self, normals: np.ndarray, towards: np.ndarray, weights: np.ndarray, visible: np.ndarray
                 ) -> np.ndarray:
        """(n, 3) L at vertices of unit `normals` (n, 3) under directional lights from unit
        `towards` (K, 3) of irradiances `weights` (K,), `visible` (n, K) bool where the geometry
        does not shadow the lit side."""
        cosine = normals @ np.asarray(towards).T
        lit = (np.clip(cosine, 0.0, None) * visible) @ weights
        through = np.clip(-cosine, 0.0, None) @ weights
        keep = 1.0 - self.transmission
        reflect = keep * (1.0 - self.diffuse_transmission) * np.asarray(self.base_color)
        transmit = keep * self.diffuse_transmission * np.asarray(self.diffuse_transmission_color)
        return (lit[:, None] * reflect + through[:, None] * transmit) / np.pi
