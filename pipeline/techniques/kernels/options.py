"""kernels: its bake options (`BakeOptions`' ``kernels_*`` fields, TOML keys and ``--kernels-*`` flags)."""

from __future__ import annotations

from dataclasses import dataclass

from sssbake.pipeline.core.ranges import Range
from sssbake.pipeline.techniques.kernels.layout import KERNEL_BITS
from sssbake.pipeline.techniques.kernels.precompute import BLENDS, KERNELS_DEFAULTS, SEAMS, KernelsPrecomputeOptions
from sssbake.pipeline.techniques.option import option

_D = KERNELS_DEFAULTS
#: F's budget per vertex: the entries it allows are an integer count (1e308 made it inf, then NaN),
#: and a gigabyte a vertex already keeps every entry F has (one per pair of vertices at most).
F_BYTES = Range(0.0, 1e9, "F's entry count must stay an integer; a gigabyte a vertex keeps all of F",
                "bytes per vertex")


@dataclass(frozen=True)
class KernelsOptions:
    """Attributes
    ----------
    size, threshold, blend, seams, global_vertices, f_bytes
        The precompute (`precompute.KernelsPrecomputeOptions`; `size` is its ``kernel_size``).
    bits : int
        Bits per stored kernel weight (8 or 16).
    """

    size: int = option(_D.kernel_size, "kernels: k of the k x k local kernels (odd; default {default})")
    threshold: float = option(_D.threshold, "kernels: drop throughput entries below this (default {default})")
    blend: str = option(_D.blend, "kernels: how local and global responses are blended (default {default})",
                        choices=BLENDS)
    seams: str = option(_D.seams, "kernels: unfold the surface across chart seams into the gutter, or not "
                                  "(default {default})", choices=SEAMS)
    global_vertices: int = option(_D.global_vertices, "kernels: surfaces with more vertices get their global response "
                                                      "on a copy simplified to about this many, 0 for no cap "
                                                      "(default {default})")
    f_bytes: float = option(_D.f_bytes, "kernels: largest size of the global response F per vertex in bytes: a "
                                        "coarser global mesh and each source's strongest entries, 0 for unbounded "
                                        "(default {default})", range=F_BYTES)
    # 8-bit codes: the hand's image RMSE is 0.0074747 against 0.0074749 with 16, in 27 % less file
    bits: int = option(8, "kernels: bits per stored kernel weight (default {default})", choices=KERNEL_BITS)

    def precompute(self) -> KernelsPrecomputeOptions:
        return KernelsPrecomputeOptions(self.size, self.threshold, self.blend, self.seams,
                                        global_vertices=self.global_vertices, f_bytes=self.f_bytes)

    def check(self) -> None:
        """Raise ValueError with a one-line reason for an impossible setting."""
        self.precompute().check()
        if self.bits not in KERNEL_BITS:
            raise ValueError(f"kernels_bits must be one of {list(KERNEL_BITS)}, got {self.bits!r}")
