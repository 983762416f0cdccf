"""prt: what `registry` lists before importing the technique (`entry.TechniqueEntry`): its name,
options and ``sssbake tradeoff`` flags."""

from __future__ import annotations

import argparse

from sssbake.pipeline.techniques.entry import TechniqueEntry
from sssbake.pipeline.techniques.prt.options import PrtOptions


class PrtEntry(TechniqueEntry):
    name = "prt"
    options_type = PrtOptions
    implementation = "sssbake.pipeline.techniques.prt.technique:Prt"

    def add_tradeoff_arguments(self, parser: argparse.ArgumentParser) -> None:
        parser.add_argument("--k", type=int, default=PrtOptions().directions,
                            help="prt: directions for the compression sweeps")
