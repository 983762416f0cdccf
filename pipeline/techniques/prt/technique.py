"""The prt technique's registry object (`technique.Technique`), one mixin per concern."""

from __future__ import annotations

from sssbake.pipeline.techniques.prt.options import PrtOptions
from sssbake.pipeline.techniques.prt.pilot import PrtPilot
from sssbake.pipeline.techniques.prt.stage import PrtStage
from sssbake.pipeline.techniques.prt.tradeoff import PrtTradeoff
from sssbake.pipeline.techniques.prt.verify import PrtVerify
from sssbake.pipeline.techniques.technique import MESH, Technique


class Prt(PrtStage, PrtVerify, PrtPilot, PrtTradeoff, Technique):
    name = "prt"
    scope = MESH
    stage_version = 4  # 4: float32 VEC3 attributes (its tables name no _SSS_PRT_W)
    needs_atlas = False
    options_type = PrtOptions
    draw_unit = "primitive"
