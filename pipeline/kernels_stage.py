"""The kernels stage of a bake: precompute for one mesh's surface and atlas, with its report."""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass, field

from .atlas import Atlas
from .clean import Surface
from .kernels_data import KernelsData
from .kernels_layout import kernels_bytes
from .kernels_precompute import KernelsOptions, precompute_kernels
from .materials import Material


@dataclass(frozen=True, eq=False)
class KernelsBake:
    """The data of one mesh and what it cost.

    Attributes
    ----------
    kernels : KernelsData
    report : dict
        Options, seconds per step, texel and border counts, F's non-zeros, radius and carried
        energy, the blending fit's ring misfit, and bytes per block as stored.
    """

    kernels: KernelsData
    report: dict = field(default_factory=dict)


def bake_kernels(surface: Surface, atlas: Atlas, primitives: list, mm_per_unit: float, material: Material,
                 options: KernelsOptions, kernel_bits: int) -> KernelsBake:
    """Run the kernels precompute on one welded surface (`kernels_precompute.precompute_kernels`)."""
    t = time.perf_counter()
    pre = precompute_kernels(surface, atlas, primitives, mm_per_unit, material, options)
    seconds = {k: round(v, 4) for k, v in pre.seconds.items()} | {"total": round(time.perf_counter() - t, 4)}
    report = {**asdict(options), "kernelBits": kernel_bits, **pre.stats, "seconds": seconds,
              "bytes": kernels_bytes(pre.data, kernel_bits)}
    return KernelsBake(pre.data, report)
