"""The kernels technique's data for one mesh (Lensch et al. 2002): what the precompute makes, the
exporters lay out and the runtimes consume.

Three spaces: the mesh's welded surface vertices (``surface_vertex_count``; render vertices map to
them), the global response's vertices (n = ``vertex_count``: the surface's own, or those of a
simplified copy of it when the surface is dense; F lives there) and the texture atlas (``width`` ×
``height`` texels, glTF UV convention as in `atlas`; the local response lives there). At runtime,
for one light:

1. Illumination map E (H, W): per covered texel and per border texel,
   ``F_t(η, n·ω) max(0, n·ω) vis · irradiance / π`` at the texel's surface point (Schlick F_t
   on the GPU). Border texels (``border_texels``) are gutter texels that stand for the surface
   across a chart's seam (triangles unfolded over the seam into the chart's gutter), so a kernel
   near a seam reads the light that falls beyond it; their surface point is
   ``Σ_a border_barycentric[b, a] · vertex[border_vertices[b, a]]`` (position and normal, the
   normal renormalised). The GPU draws them as one-pixel points, so no two charts' borders
   fight over a texel. Texels neither covered nor border hold 0.
2. Local response per covered texel s, gather form: ``B_l[s, c] = Σ_o kernels[s, o, c] ·
   E[row_s + dy_o, col_s + dx_o]`` over the k × k offsets ``o = (dy + r) k + (dx + r)``,
   ``r = (k - 1) / 2``, dy along rows (v), dx along columns (u); offsets outside the image read 0.
3. Distribution to vertices: ``E_g[texel_vertices[s, a]] += texel_dual[s, a] · E[s]`` (the dual
   hat basis times the texel's area) and ``B_d[texel_vertices[s, a], c] += texel_direct[s, a, c]
   · E[s]`` (the blending weights of §5.4), over covered texels only.
4. Global response: ``B_g[j, c] = Σ_{p = f_indptr[j]}^{f_indptr[j+1]-1} f_values[p, c] ·
   E_g[f_indices[p]]`` (row j lists the sources of receiver j; F's diagonal is zero).
5. Each surface vertex v reads the global vertices' radiosity ``B_v[v] = Σ_k surface_weights[v, k]
   (B_g + B_d)[surface_global[v, k]]``; at a surface point x with atlas UV u in triangle (β):
   ``q(x) = B_l(u) + Σ_β bary_β(x) B_v[β]``, B_l read bilinearly over covered texels only; the eye
   sees ``F_t(η, ω_o) q(x)`` (the shared final pass).

q is radiance before the exit Fresnel, per unit irradiance scale of the light (as prt's q).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sssbake.pipeline.core.errors import SssbakeError


class KernelsDataError(SssbakeError, ValueError):
    """Arrays that do not form valid kernels data."""


@dataclass(frozen=True, eq=False)
class KernelsData:
    """Attributes
    ----------
    width, height : int
        Atlas size in texels.
    kernel_size : int
        k, odd, >= 3.
    vertex_count : int
        n, vertices of the global response.
    surface_vertex_count : int
        Welded surface vertices.
    texels : (S,) int64
        ``row · width + col`` of every covered texel, strictly increasing.
    kernels : (S, k², 3) float32
        Local gather weights per covered texel, offset and channel (may be negative: §5.4
        subtracts the interpolated global part).
    texel_vertices : (S, 3) int64
        Global vertices of the triangle under each covered texel's point.
    texel_dual : (S, 3) float32
        ``(3 / A_α)(4 β_α - 1) · A(texel)``: the texel's share of each corner's hat coefficient.
    texel_direct : (S, 3, 3) float32
        Blending weights w_α per corner and channel.
    f_indptr : (n + 1,) int64
    f_indices : (nnz,) int64
        Source vertex of each entry, sorted within a row.
    f_values : (nnz, 3) float32
        ``F_ij = (A_i / 3) Rd(|v_i - v_j|)`` per channel, diagonal dropped; under a byte bound
        each source's strongest entries beyond the kernels' window, scaled to send what all of its
        entries there sent
        (`throughput.strongest_per_source`).
    border_texels : (b,) int64
        ``row · width + col`` of every border texel, strictly increasing, none covered.
    border_vertices : (b, 3) int64
        Welded surface vertices of the triangle each border texel's surface point lies in.
    border_barycentric : (b, 3) float32
        That point's barycentric weights (non-negative, summing to 1).
    surface_global : (surface_vertex_count, 3) int64
        The global triangle each surface vertex lies on (itself three times when the global
        vertices are the surface's).
    surface_weights : (surface_vertex_count, 3) float32
        Its barycentric weights there.
    """

    width: int
    height: int
    kernel_size: int
    vertex_count: int
    texels: np.ndarray
    kernels: np.ndarray
    texel_vertices: np.ndarray
    texel_dual: np.ndarray
    texel_direct: np.ndarray
    f_indptr: np.ndarray
    f_indices: np.ndarray
    f_values: np.ndarray
    border_texels: np.ndarray
    border_vertices: np.ndarray
    border_barycentric: np.ndarray
    surface_vertex_count: int
    surface_global: np.ndarray
    surface_weights: np.ndarray

    @property
    def radius(self) -> int:
        return (self.kernel_size - 1) // 2

    @property
    def nnz(self) -> int:
        return int(len(self.f_indices))

    def offsets(self) -> tuple[np.ndarray, np.ndarray]:
        """(k²,) int64 row offsets dy and column offsets dx, in kernel order."""
        r = self.radius
        dy, dx = np.divmod(np.arange(self.kernel_size**2), self.kernel_size)
        return dy - r, dx - r

    def check(self) -> None:
        """Raise KernelsDataError naming the first array with a wrong shape, value or range."""
        k, n = self.kernel_size, self.vertex_count
        s = len(self.texels)
        if not (k >= 3 and k % 2 == 1):
            raise KernelsDataError(f"kernels: kernel_size must be odd and >= 3, got {k}")
        if self.width < 1 or self.height < 1 or n < 1:
            raise KernelsDataError(f"kernels: need a non-empty atlas and surface, got {self.width} x {self.height}, n={n}")
        shapes = {"kernels": (s, k * k, 3), "texel_vertices": (s, 3), "texel_dual": (s, 3),
                  "texel_direct": (s, 3, 3), "f_indptr": (n + 1,), "f_values": (self.nnz, 3),
                  "border_vertices": (len(self.border_texels), 3),
                  "border_barycentric": (len(self.border_texels), 3),
                  "surface_global": (self.surface_vertex_count, 3), "surface_weights": (self.surface_vertex_count, 3)}
        for name, shape in shapes.items():
            if getattr(self, name).shape != shape:
                raise KernelsDataError(f"kernels: {name} has shape {getattr(self, name).shape}, expected {shape}")
        for name in ("texels", "border_texels"):
            a = getattr(self, name)
            if a.size and (a.min() < 0 or a.max() >= self.width * self.height or np.any(np.diff(a) <= 0)):
                raise KernelsDataError(f"kernels: {name} must be strictly increasing pixel indices inside the atlas")
        if np.intersect1d(self.texels, self.border_texels).size:
            raise KernelsDataError("kernels: a border texel is also a covered texel")
        for name, count in (("texel_vertices", n), ("f_indices", n), ("surface_global", n),
                            ("border_vertices", self.surface_vertex_count)):
            a = getattr(self, name)
            if a.size and (a.min() < 0 or a.max() >= count):
                raise KernelsDataError(f"kernels: {name} must index 0..{count - 1}")
        if self.f_indptr[0] != 0 or self.f_indptr[-1] != self.nnz or np.any(np.diff(self.f_indptr) < 0):
            raise KernelsDataError("kernels: f_indptr must rise from 0 to the entry count")
        for name in ("kernels", "texel_dual", "texel_direct", "f_values", "border_barycentric", "surface_weights"):
            if not np.all(np.isfinite(getattr(self, name))):
                raise KernelsDataError(f"kernels: {name} holds NaN or Inf")
