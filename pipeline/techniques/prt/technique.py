"""The prt technique's registry object (`technique.Technique`), one mixin per concern
and its entry (``entry.py``: its name, options and tradeoff flags)."""

from __future__ import annotations

from sssbake.pipeline.techniques.prt.entry import PrtEntry
from sssbake.pipeline.techniques.prt.pilot import PrtPilot
from sssbake.pipeline.techniques.prt.stage import PrtStage
from sssbake.pipeline.techniques.prt.tradeoff import PrtTradeoff
from sssbake.pipeline.techniques.prt.verify import PrtVerify
from sssbake.pipeline.techniques.technique import MESH, Technique


class Prt(PrtStage, PrtVerify, PrtPilot, PrtTradeoff, PrtEntry, Technique):
    scope = MESH
    stage_version = 4  # 4: float32 VEC3 attributes (its tables name no _SSS_PRT_W)
    needs_atlas = False
    draw_unit = "primitive"
    vertex_keys = ("sss:prt:",)  # _SSS_PRT_REF, _SSS_PRT_DQ<i> (layout.REF_KEY, DQ_KEY)
