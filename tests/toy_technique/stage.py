"""toy: the bake, one albedo per mesh from its material."""

from __future__ import annotations

import numpy as np

from sssbake.pipeline.core.profile import profile_for, profile_total
from sssbake.pipeline.techniques.technique import BakeTarget, TechniqueBake
from toy_technique.options import ToyOptions


class ToyStage:
    def bake(self, target: BakeTarget, options: ToyOptions) -> TechniqueBake:
        params = profile_for(target.material)
        albedo = options.gain * np.asarray(profile_total(params), dtype=np.float64)
        warnings = ("albedo over 1: the surface reflects more than it receives",) if albedo.max() > 1 else ()
        return TechniqueBake(None, {"albedo": albedo.tolist()}, {"albedo": albedo.tolist(), "bytes": {"perVertex": 0.0}},
                             warnings)

    def vertex_attributes(self, result: TechniqueBake, welded: np.ndarray) -> tuple:
        return ()
