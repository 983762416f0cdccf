"""toy: its registry object."""

from __future__ import annotations

from sssbake.pipeline.techniques.technique import MESH, Technique
from toy_technique.options import ToyOptions
from toy_technique.stage import ToyStage
from toy_technique.verify import ToyVerify


class Toy(ToyStage, ToyVerify, Technique):
    name = "toy"
    scope = MESH
    stage_version = 1
    needs_atlas = False
    options_type = ToyOptions
    draw_unit = "mesh"
