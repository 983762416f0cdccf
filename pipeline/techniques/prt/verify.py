"""prt: verify and the runtime (`technique.Technique`'s verify hooks)."""

from __future__ import annotations

from sssbake.pipeline.techniques.prt.reader import read_prt_glb, read_prt_usd
from sssbake.pipeline.techniques.prt.runtime import PRT_DRAW
from sssbake.pipeline.techniques.technique import VerifyUnit


class PrtVerify:
    """A primitive's `PrtData`, drawn by ``prt.vert``; compared with the dipole."""

    draw = PRT_DRAW

    def read(self, path) -> dict:
        return read_prt_glb(path)

    def read_usd(self, path) -> dict:
        return read_prt_usd(path)

    def verify_items(self, unit: VerifyUnit, data: dict, runtime: dict) -> tuple[dict, dict]:
        item = {**unit.base, "prt": data[(unit.mesh, unit.primitives[0])]}
        return item, item
