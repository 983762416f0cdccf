"""lpv: what `registry` lists before importing the technique (`entry.TechniqueEntry`): its name,
options and ``sssbake tradeoff`` flags, with the sweeps' defaults."""

from __future__ import annotations

import argparse

from sssbake.pipeline.techniques.entry import TechniqueEntry, add_sweep_argument
from sssbake.pipeline.techniques.lpv.options import FIELDS, LpvOptions

RESOLUTIONS = (16, 32, 64)
STEPS = (8, 16, 32)


class LpvEntry(TechniqueEntry):
    name = "lpv"
    options_type = LpvOptions
    implementation = "sssbake.pipeline.techniques.lpv.technique:Lpv"

    def add_tradeoff_arguments(self, parser: argparse.ArgumentParser) -> None:
        add_sweep_argument(parser, "--lpv-resolutions", int, RESOLUTIONS, "lpv: grid resolutions swept")
        add_sweep_argument(parser, "--lpv-steps", int, STEPS, "lpv: propagation steps swept")
        parser.add_argument("--lpv-field", choices=FIELDS, default="homogeneous",
                            help="lpv: the medium; marble veins are compared with the finest configuration")
