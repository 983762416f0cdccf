"""toy: the bake, one albedo per mesh from its material."""

from __future__ import annotations

import numpy as np

from sssbake.pipeline.core.dipole import DipoleParams, total_diffuse_reflectance
from sssbake.pipeline.techniques.technique import BakeTarget, TechniqueBake
from toy_technique.options import ToyOptions


class ToyStage:
    def bake(self, target: BakeTarget, options: ToyOptions) -> TechniqueBake:
        params = DipoleParams.from_material(target.material)
        albedo = options.gain * np.asarray(total_diffuse_reflectance(params.alpha_prime, params.eta), dtype=np.float64)
        warnings = ("albedo over 1: the surface reflects more than it receives",) if albedo.max() > 1 else ()
        return TechniqueBake(None, {"albedo": albedo.tolist()}, {"albedo": albedo.tolist(), "bytes": {"perVertex": 0.0}},
                             warnings)

    def vertex_attributes(self, result: TechniqueBake, welded: np.ndarray) -> tuple:
        return ()
