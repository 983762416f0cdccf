"""The lpv technique's registry object (`technique.Technique`), one mixin per concern."""

from __future__ import annotations

from sssbake.pipeline.techniques.lpv.options import LpvOptions
from sssbake.pipeline.techniques.lpv.pilot import LpvPilot
from sssbake.pipeline.techniques.lpv.stage import LpvStage
from sssbake.pipeline.techniques.lpv.tradeoff import LpvTradeoff
from sssbake.pipeline.techniques.lpv.verify import LpvVerify
from sssbake.pipeline.techniques.technique import MESH, Technique


class Lpv(LpvStage, LpvVerify, LpvPilot, LpvTradeoff, Technique):
    name = "lpv"
    scope = MESH
    stage_version = 2
    needs_atlas = False
    options_type = LpvOptions
    draw_unit = "mesh"
