"""The prt technique's compressed data (Hao & Varshney 2004): what the bake writes and the runtime reads.

One `PrtData` per scattering mesh, over the mesh's welded surface vertices (``Surface``); the
exporters map per-vertex arrays to render vertices through ``Surface.weld``.

Decoding (numpy in `prt_decode`, GLSL in ``runtime_shaders/prt_decode.glsl``), per colour channel c
and light direction ω (unit, object space, pointing from the surface towards the light)::

    q_c(ω) = Σ_k w_k · T_c[r_k](ω)  +  Σ_i dq_c,i · y_i(ω)

- ``r_0, r_1, r_2 = ref_triangles[vertex_triangle]`` are the vertex's reference points and
  ``w_0 = weight_scale · weight_codes[:, 0] / M``, ``w_1`` likewise, ``w_2 = 1 - w_0 - w_1``, with
  ``M = 2^(weight_bits - 1) - 1`` (127 or 32767).
- ``T_c[r](ω)`` interpolates the reference point's table over the direction set: the hull
  triangle (a, b, c) of ``directions`` that contains ω — found from ``direction_lookup`` at ω's
  octahedral texel, then up to ``directions.WALK_STEPS`` steps to ``direction_neighbours`` across
  the edge with the most negative barycentric — barycentrics ``β ∝ direction_inverse[t] @ ω``
  (clamped at 0, normalised to sum 1). RGB tables (``ref_codes.shape[2] == 3``):
  ``T = Σ β_a · lut[c, ref_codes[r, a, c]]``; one shared table per reference point
  (``ref_codes.shape[2] == 1``): ``T = ref_scale[r, c] · Σ β_a · lut[c, ref_codes[r, a, 0]]``.
- ``y_i`` is the real spherical harmonic basis (Sloan 2002 normalisation, index i = l² + l + m,
  l < sh_order) and ``dq_c,i = dq_scale[c, i] · dq_codes[:, c, i] / 127``.

A mesh without reference points (SH only) has ``ref_codes.shape[0] == 0`` and zero weights; the
uncompressed baseline makes every vertex its own reference point with weights (1, 0, 0).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

# Octahedral map used by `direction_lookup` (and mirrored in GLSL):
#   p = ω.xy / (|ω.x| + |ω.y| + |ω.z|);  if ω.z < 0: p = (1 - |p.yx|) · sign(p.xy)  (sign(0) = +1)
#   texel = clamp(floor((p · 0.5 + 0.5) · L), 0, L - 1); lookup[v, u] (see `directions.octahedral_texel`)


@dataclass(frozen=True, eq=False)
class PrtData:
    """Compressed precomputed scattering integrals of one mesh.

    Attributes
    ----------
    directions : (K, 3) float32
        Unit light directions the integrals were computed for.
    direction_triangles : (T, 3) int32
        Convex hull of ``directions``, counter-clockwise seen from outside.
    direction_inverse : (T, 3, 3) float32
        Per hull triangle, the inverse of the matrix whose columns are its three directions.
    direction_lookup : (L, L) int32
        Hull triangle containing the direction at each texel centre of the octahedral map above.
    direction_neighbours : (T, 3) int32
        Hull triangle across the edge opposite each corner.
    lut : (3, 256) float32
        Reconstruction levels per colour channel: radiance per unit irradiance (1/sr) for RGB
        tables, the unitless shape for shared tables (one code, a level per channel).
    ref_vertices : (R,) int64
        Surface vertex of each reference point.
    ref_codes : (R, K, C_t) uint8
        Lloyd codes of each reference point's table per direction: q per colour channel (C_t = 3),
        or one shape shared by the channels (C_t = 1).
    ref_scale : (R, 3) float32
        With shared tables, each reference point's RGB colour multiplying its shape (1/sr);
        (0, 3) with RGB tables.
    ref_triangles : (F, 3) int32
        Triangles over reference points (indices into ``ref_vertices``).
    vertex_triangle : (n,) int32
        Per surface vertex, its triangle in ``ref_triangles`` (0 when R == 0).
    weight_codes : (n, 2) int16
        Per surface vertex, w_0 and w_1 as signed codes, |code| <= M (see above).
    weight_scale : float
        Range of the weights: 1 for barycentric weights, larger for least-squares weights.
    weight_bits : int
        8 or 16: the codes' range (M = 127 or 32767). The exporters store both as float32 with
        the vertex's triangle (`prt_layout`).
    dq_codes : (n, 3, C) int8
        Per surface vertex and channel, SH coefficients of Δq as signed normalised bytes; C = sh_order².
    dq_scale : (3, C) float32
        Per channel and coefficient, the value of code 127.
    sh_order : int
        n of the paper (0: no Δq).
    eta : float
        Relative index of refraction, for F_t(η, ω_o) at runtime.
    detail_order : int
        SH order of the reference points' detail term (shared tables only; 0: none).
    detail_codes : (R, D) int8
        Per reference point, the SH coefficients of its detail shape as signed codes; D = detail_order².
    detail_colour : (R, 3) int8
        Per reference point, the RGB weights of its detail shape times 127.
    detail_scale : (D,) float32
        Per coefficient, the value of code 127.
    """

    directions: np.ndarray
    direction_triangles: np.ndarray
    direction_inverse: np.ndarray
    direction_lookup: np.ndarray
    direction_neighbours: np.ndarray
    lut: np.ndarray
    ref_vertices: np.ndarray
    ref_codes: np.ndarray
    ref_scale: np.ndarray
    ref_triangles: np.ndarray
    vertex_triangle: np.ndarray
    weight_codes: np.ndarray
    weight_scale: float
    weight_bits: int
    dq_codes: np.ndarray
    dq_scale: np.ndarray
    sh_order: int
    eta: float
    detail_order: int = 0
    detail_codes: np.ndarray = field(default_factory=lambda: np.zeros((0, 0), dtype=np.int8))
    detail_colour: np.ndarray = field(default_factory=lambda: np.zeros((0, 3), dtype=np.int8))
    detail_scale: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.float32))

    @property
    def vertex_count(self) -> int:
        return len(self.vertex_triangle)

    def check(self) -> None:
        """Raise ValueError naming the first array with a wrong shape, a value that is not finite or
        an index out of range."""
        k, t, n, r = len(self.directions), len(self.direction_triangles), self.vertex_count, len(self.ref_vertices)
        lookup, f = len(self.direction_lookup), len(self.ref_triangles)
        channels = self.ref_codes.shape[2] if self.ref_codes.ndim == 3 else -1
        c, d = self.sh_order * self.sh_order, self.detail_order * self.detail_order
        detail_rows = r if self.detail_order else 0
        if channels not in (1, 3) or self.weight_bits not in (8, 16) or self.sh_order < 0 or self.detail_order < 0:
            raise ValueError(f"prt: need 1 or 3 table channels and 8 or 16 weight bits, got {channels} and "
                             f"{self.weight_bits}")
        shapes = {"directions": (k, 3), "direction_triangles": (t, 3), "direction_inverse": (t, 3, 3),
                  "direction_lookup": (lookup, lookup), "direction_neighbours": (t, 3), "lut": (3, 256),
                  "ref_vertices": (r,), "ref_codes": (r, k, channels), "ref_scale": (r if channels == 1 else 0, 3),
                  "ref_triangles": (f, 3), "vertex_triangle": (n,), "weight_codes": (n, 2), "dq_codes": (n, 3, c),
                  "dq_scale": (3, c), "detail_codes": (detail_rows, d), "detail_colour": (detail_rows, 3),
                  "detail_scale": (d,)}
        for name, shape in shapes.items():
            if getattr(self, name).shape != shape:
                raise ValueError(f"prt: {name} has shape {getattr(self, name).shape}, expected {shape}")
        # vertex_triangle is 0 for every vertex of a mesh without reference points
        for name, bound in (("direction_triangles", k), ("direction_lookup", t), ("direction_neighbours", t),
                            ("ref_vertices", n), ("ref_triangles", r), ("vertex_triangle", max(f, 1))):
            a = getattr(self, name)
            if a.size and (a.min() < 0 or a.max() >= bound):
                raise ValueError(f"prt: {name} must index 0..{bound - 1}")
        if np.abs(self.weight_codes.astype(np.int64)).max(initial=0) > 2 ** (self.weight_bits - 1) - 1:
            raise ValueError(f"prt: weight codes beyond the {self.weight_bits}-bit range")
        for name in ("directions", "direction_inverse", "lut", "ref_scale", "dq_scale", "detail_scale"):
            if not np.all(np.isfinite(getattr(self, name))):
                raise ValueError(f"prt: {name} holds NaN or Inf")
        if not (np.isfinite(self.weight_scale) and np.isfinite(self.eta)):
            raise ValueError("prt: weight_scale and eta must be finite")
