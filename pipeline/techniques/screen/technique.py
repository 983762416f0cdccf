"""The screen technique's registry object (`technique.Technique`), one mixin per concern."""

from __future__ import annotations

from sssbake.pipeline.techniques.screen.options import ScreenOptions
from sssbake.pipeline.techniques.screen.pilot import ScreenPilot
from sssbake.pipeline.techniques.screen.stage import ScreenStage
from sssbake.pipeline.techniques.screen.tradeoff import ScreenTradeoff
from sssbake.pipeline.techniques.screen.verify import ScreenVerify
from sssbake.pipeline.techniques.technique import MATERIAL, Technique


class Screen(ScreenStage, ScreenVerify, ScreenPilot, ScreenTradeoff, Technique):
    name = "screen"
    scope = MATERIAL
    stage_version = 1
    needs_atlas = False
    options_type = ScreenOptions
    draw_unit = "primitive"
