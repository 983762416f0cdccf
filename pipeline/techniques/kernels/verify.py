"""kernels: verify and the runtime (`technique.Technique`'s verify hooks)."""

from __future__ import annotations

import numpy as np

from sssbake.pipeline.techniques.kernels.reader import read_kernels_glb, read_kernels_usd
from sssbake.pipeline.techniques.kernels.runtime import KERNELS_DRAW
from sssbake.pipeline.techniques.technique import VerifyUnit


class KernelsVerify:
    """A mesh's `KernelsData` (its primitives share its atlas and throughput matrix), drawn after
    the kernels passes; compared with the dipole."""

    draw = KERNELS_DRAW

    def read(self, path) -> dict:
        return read_kernels_glb(path)

    def read_usd(self, path) -> dict:
        return read_kernels_usd(path)

    def verify_items(self, unit: VerifyUnit, data: dict, runtime: dict) -> tuple[dict, dict]:
        item = {**unit.base, "kernels": data[(unit.mesh, unit.primitives[0])][0], "uvs": unit.primitive.uvs[-1],
                "vertex_ids": np.concatenate([data[(unit.mesh, p)][1] for p in unit.primitives])}
        return item, item
