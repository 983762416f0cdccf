"""The kernels stage of a bake: precompute for one mesh's surface and atlas, with its report."""

from __future__ import annotations

import time
from dataclasses import asdict, replace

import numpy as np

from sssbake.pipeline.core.materials import Material
from sssbake.pipeline.core.surface import Surface
from sssbake.pipeline.mesh.atlas import Atlas
from sssbake.pipeline.mesh.baked import VertexAttribute
from sssbake.pipeline.techniques.kernels.data import KernelsData
from sssbake.pipeline.techniques.kernels.layout import kernels_bytes, kernels_tables, kernels_vertex_attributes
from sssbake.pipeline.techniques.kernels.options import KernelsOptions
from sssbake.pipeline.techniques.kernels.precompute import KernelsPrecomputeOptions, precompute_kernels
from sssbake.pipeline.techniques.technique import BakeTarget, TechniqueBake, same_tables


def bake_kernels(surface: Surface, atlas: Atlas, primitives: list, mm_per_unit: float, material: Material,
                 options: KernelsPrecomputeOptions, kernel_bits: int) -> TechniqueBake:
    """Run the kernels precompute on one welded surface (`precompute.precompute_kernels`).

    Returns
    -------
    TechniqueBake
        ``data``: the `KernelsData`; ``tables``: `kernels_tables` at `kernel_bits`; ``report``:
        options, seconds per step, texel and border counts, F's non-zeros, radius and carried
        energy, the blending fit's ring misfit, and bytes per block as stored.
    """
    t = time.perf_counter()
    pre = precompute_kernels(surface, atlas, primitives, mm_per_unit, material, options)
    seconds = {k: round(v, 4) for k, v in pre.seconds.items()} | {"total": round(time.perf_counter() - t, 4)}
    report = {**asdict(options), "kernelBits": kernel_bits, **pre.stats, "seconds": seconds,
              "bytes": kernels_bytes(pre.data, kernel_bits)}
    return TechniqueBake(pre.data, kernels_tables(pre.data, kernel_bits), report)


class KernelsStage:
    """kernels' bake hooks (`technique.Technique`)."""

    def bake(self, target: BakeTarget, options: KernelsOptions) -> TechniqueBake:
        baked = bake_kernels(target.surface, target.atlas, list(target.primitives), target.mm_per_unit,
                             target.material, options.precompute(), options.bits)
        reach = (options.size + 1) // 2
        if target.atlas_padding >= reach:
            return baked
        return replace(baked, warnings=(
            f"atlas_padding {target.atlas_padding} is below the {reach} texels a {options.size}-texel kernel "
            "reaches; kernels near chart edges see less of their neighbourhood",))

    def vertex_attributes(self, result: TechniqueBake, welded: np.ndarray) -> tuple[VertexAttribute, ...]:
        return kernels_vertex_attributes(result.data, welded)

    def check_bake(self, result: TechniqueBake, target: BakeTarget, options: KernelsOptions) -> None:
        if not isinstance(result.data, KernelsData):
            raise ValueError(f"kernels: data is a {type(result.data).__name__}, not KernelsData")
        if result.data.surface_vertex_count != len(target.surface.positions) or (
                (result.data.width, result.data.height) != (target.atlas.width, target.atlas.height)):
            raise ValueError("kernels: data over another surface or atlas than the mesh's")
        if not same_tables(result.tables, kernels_tables(result.data, options.bits)):
            raise ValueError("kernels: tables are not those of its data")
