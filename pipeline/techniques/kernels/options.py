"""kernels: its bake options (`BakeOptions`' ``kernels_*`` fields, TOML keys and ``--kernels-*`` flags) and
the precompute's, with their choices: no numpy here, so that ``sssbake bake --help`` imports none."""

from __future__ import annotations

from dataclasses import dataclass

from sssbake.pipeline.core.ranges import Range
from sssbake.pipeline.techniques.option import option

BLENDS = ("optimised", "fixed", "none")
SEAMS = ("unfold", "none")
#: Bits per stored kernel weight that the layout offers (`layout.encode_kernels`).
KERNEL_BITS = (8, 16)
#: F's budget per vertex: the entries it allows are an integer count (1e308 made it inf, then NaN),
#: and a gigabyte a vertex already keeps every entry F has (one per pair of vertices at most).
F_BYTES = Range(0.0, 1e9, "F's entry count must stay an integer; a gigabyte a vertex keeps all of F",
                "bytes per vertex")
#: F's floor: its room in bytes (the floor × 2^20) sets an integer count of entries per source, and
#: 1e9 MiB (a petabyte) already holds every entry of any F a bake could store.
F_FLOOR_MB = Range(0.0, 1e9, "F's entry count must stay an integer; a petabyte holds all of any F a bake stores",
                   "MiB")


@dataclass(frozen=True)
class KernelsPrecomputeOptions:
    """Attributes
    ----------
    kernel_size : int
        k of the k × k local kernels (odd, 3..15); the atlas gutter should be >= (k + 1) / 2.
    threshold : float
        F entries whose largest channel is below it are dropped (Lensch et al.: 1e-5).
    blend : str
        ``"optimised"``, ``"fixed"`` or ``"none"`` (`precompute`'s module docstring).
    seams : str
        ``"unfold"`` (border texels across seams) or ``"none"`` (kernels stop at chart edges).
    ridge : float
        Weight of the pull towards w0 in the blending fit, per ring texel.
    global_vertices : int
        Surfaces with more vertices get their global response (F, the distribution and the
        blending) on a copy simplified to about this many vertices; 0: only when `f_bytes` asks.
    f_bytes : float
        Largest size of F (fIndptr, fIndices, fValues as stored) per welded surface vertex, in
        bytes (`global_budget`); 0: unbounded (F as thresholded, on at most `global_vertices`).
    f_floor_mb : float
        MiB F may always take whatever `f_bytes` gives (`precompute.f_room`); 0: no floor. Where F
        fits its room it is kept whole, as with `f_bytes` 0. The per-vertex bound is for large
        meshes, where F grows as n² (above 524,288 vertices 64 B a vertex passes 32 MiB); on smaller
        ones the entries it drops are the long-range ones that carry light through the object
        (marble at 1 mm a unit against the path-traced truth, block RMSE front / back-lit:
        samples/torus.ply, 1,408 vertices, 0.179 / 0.945 at 64 B a vertex, 0.044 / 0.437 whole, F
        14.8 MB; samples/blob.obj, 2,562 vertices, 0.118 / 0.658 at 64 B a vertex, 0.057 / 0.386 in
        32 MiB), in files whose other kernels tables already take tens of MB.
    """

    kernel_size: int = 7
    threshold: float = 1e-5
    blend: str = "optimised"
    seams: str = "unfold"
    ridge: float = 0.005
    global_vertices: int = 20_000
    f_bytes: float = 64.0
    f_floor_mb: float = 32.0

    def check(self) -> None:
        if not (isinstance(self.kernel_size, int) and 3 <= self.kernel_size <= 15 and self.kernel_size % 2):
            raise ValueError(f"kernels: kernel_size must be odd in 3..15, got {self.kernel_size!r}")
        if not (isinstance(self.threshold, (int, float)) and 0 < self.threshold < 1):
            raise ValueError(f"kernels: threshold must be in (0, 1), got {self.threshold!r}")
        if self.blend not in BLENDS or self.seams not in SEAMS:
            raise ValueError(f"kernels: blend must be one of {list(BLENDS)} and seams one of {list(SEAMS)}, "
                             f"got {self.blend!r}, {self.seams!r}")
        if not (isinstance(self.global_vertices, int) and (self.global_vertices == 0 or self.global_vertices >= 100)):
            raise ValueError(f"kernels: global_vertices must be 0 or at least 100, got {self.global_vertices!r}")
        if not (isinstance(self.f_bytes, (int, float)) and (self.f_bytes == 0 or self.f_bytes >= 16)):
            raise ValueError(f"kernels: f_bytes must be 0 (unbounded) or at least 16, got {self.f_bytes!r}")
        if not (isinstance(self.f_floor_mb, (int, float)) and 0 <= self.f_floor_mb <= F_FLOOR_MB.high):
            raise ValueError(f"kernels: f_floor_mb must be in [0, {F_FLOOR_MB.high:g}] MiB, got {self.f_floor_mb!r}")
        if not (0 < self.ridge < 1):
            raise ValueError(f"kernels: ridge must be in (0, 1), got {self.ridge!r}")


KERNELS_DEFAULTS = KernelsPrecomputeOptions()
_D = KERNELS_DEFAULTS

@dataclass(frozen=True)
class KernelsOptions:
    """Attributes
    ----------
    size, threshold, blend, seams, global_vertices, f_bytes, f_floor_mb
        The precompute (`KernelsPrecomputeOptions`; `size` is its ``kernel_size``).
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
    f_floor_mb: float = option(_D.f_floor_mb, "kernels: MiB the global response F may always take whatever "
                                              "--kernels-f-bytes gives (kept whole where it fits), so that meshes below "
                                              "~500k vertices keep the light through the object; 0 for no floor "
                                              "(default {default})", range=F_FLOOR_MB)
    # 8-bit codes: the hand's image RMSE is 0.0074747 against 0.0074749 with 16, in 27 % less file
    bits: int = option(8, "kernels: bits per stored kernel weight (default {default})", choices=KERNEL_BITS)

    def precompute(self) -> KernelsPrecomputeOptions:
        return KernelsPrecomputeOptions(self.size, self.threshold, self.blend, self.seams,
                                        global_vertices=self.global_vertices, f_bytes=self.f_bytes,
                                        f_floor_mb=self.f_floor_mb)

    def check(self) -> None:
        """Raise ValueError with a one-line reason for an impossible setting."""
        self.precompute().check()
        if self.bits not in KERNEL_BITS:
            raise ValueError(f"kernels_bits must be one of {list(KERNEL_BITS)}, got {self.bits!r}")
