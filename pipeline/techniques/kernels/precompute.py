"""The kernels technique's precompute (Lensch et al. 2002, §5): per-texel local kernels in the
atlas, the vertex-to-vertex throughput matrix F, the dual-hat distribution weights and the
blending of §5.4.

Discretisation (float64 throughout, lengths in mm):

- Texels: one sample per covered texel (`texels.rasterize_atlas`), area A(t) = the surface it
  stands for; border texels (`kernels_border`) stand for the surface across chart seams.
- True local response of source texel t at receiver r: ``T(r, t) = A(t) Rd(|x_r - x_t|)``; a
  texel's response to itself is the exact disc integral over its area (`dipole.disc_integral`).
- Distribution: ``texel_dual = (3 / A_α)(4 β_α - 1) A(t)``, A_α the area of α's triangles, each
  triangle's sums made exact (`_dual_weights`). Where a vertex's triangles hold too few texels
  for the dual basis to reproduce a constant (sub-texel triangles), its weights become β_α A(t)
  normalised over its texels (`DUAL_TOLERANCE`).
- Global response of a unit irradiance at real texel s, at a surface point y in triangle (β):
  ``g(y, s) = Σ_β ψ_β(y) [Σ_α dual_α(s) F'_αβ + [β ∈ s's corners] w_β(s)]`` with F' = F without
  its diagonal and w the blending weights.
- Global mesh: F, the distribution and the blending live on the surface's vertices, or on a
  simplified copy when the surface has more than ``global_vertices`` or more than F's byte budget
  allows (texel points located on it, `surface_locate`; each surface vertex then blends three of its
  vertices).
- F's bytes: ``f_bytes`` per surface vertex but at least ``f_floor_mb`` MiB (`f_room`). F is whole
  where that holds it (small meshes, as with ``f_bytes`` 0); else the global mesh (`global_budget`)
  gets at most as many vertices as leave `ROW_ENTRIES` entries each, and each source keeps its strongest entries
  beyond the kernels' window within the budget, renormalised to send what its entries beyond the
  window sent (`throughput.strongest_per_source`); the blending below fits the kernels to that F.
- Blending (``blend="optimised"``, `_blend`): w(s) per channel by least squares so that g matches T
  on the ring of texels at chessboard distance r + 1 around s (the boundary of the (k + 2)² kernel,
  where the k² kernel no longer reaches), ridge-regularised towards w0 = dual(s) F_αα (the dropped
  diagonal) for weights the ring barely constrains, and constrained so that g sends beyond the
  window what T sends there (exact energy; without it the hats carry a texel's light too far and
  the hand came out 14 % too bright). Then each kernel entry becomes
  ``T(r, t) - g(r, t)``: inside the window the sum is the true response, outside it is g, and the
  two meet at the ring. A border texel's g is that of the covered texel at the same surface point,
  scaled by the ratio of their areas.
- ``blend="fixed"``: w = w0 and the same kernel correction (the blending without the
  optimisation); ``blend="none"``: kernels T, F with its diagonal, no direct term (local and
  global simply added, which §5.4 says roughly doubles the light near where it enters).
"""

from __future__ import annotations

import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree

from sssbake.pipeline.core.profile import Profile, disc_integral, profile_for
from sssbake.pipeline.core.integer_keys import argsort_keys, unique_keys
from sssbake.pipeline.core.materials import Material
from sssbake.pipeline.core.profile_table import ProfileTable
from sssbake.pipeline.core.surface import Surface, area_weighted_normals, triangle_areas, vertex_areas
from sssbake.pipeline.mesh.atlas import Atlas
from sssbake.pipeline.mesh.atlas_surface import atlas_surface
from sssbake.pipeline.mesh.simplify import simplify
from sssbake.pipeline.mesh.surface_locate import locate_on_mesh
from sssbake.pipeline.mesh.texels import rasterize_atlas
from sssbake.pipeline.techniques.kernels.border import border_texels
from sssbake.pipeline.techniques.kernels.compiled import (grouped_products, local_transport, mix_global, near_table,
                                                            shared_hats)
from sssbake.pipeline.techniques.kernels.data import KernelsData
from sssbake.pipeline.techniques.kernels.options import KERNELS_DEFAULTS, KernelsPrecomputeOptions
from sssbake.pipeline.techniques.kernels.throughput import Throughput, throughput_matrix

#: A vertex whose dual weights sum further than this from 1 gets normalised barycentric weights.
DUAL_TOLERANCE = 0.2
#: The energy constraint of the blending fit applies where the corners' hats put at least this
#: share of their mass beyond the window.
CONSTRAIN = 0.05
#: ... and where meeting it moves the weights by at most about this many times w0.
STEER_LIMIT = 1.0
#: Entries per global vertex the byte budget aims for when it chooses the global mesh. Narrow rows
#: on the surface's own vertices beat a coarse mesh with wide ones: the blending corrects F only
#: within the kernel's window, and hats wider than it smear the light (hand, skin1, 64 B per
#: vertex, q at the texels against unbounded F: 4 entries on all 7,993 vertices 0.079 uniform /
#: 0.110 directional, 16 on 2,245 vertices 0.175 / 0.190, 31 on 1,133 vertices 0.28 / 0.30;
#: benchmarks/README.md#kernels-f-bounded).
ROW_ENTRIES = 4
#: Fewest vertices a budget makes the global mesh (a coarser one no longer follows the shape).
MIN_GLOBAL = 100
#: Bytes of one stored F entry: three float32 values and a uint16 or uint32 source index, and of
#: one row's fIndptr.
F_VALUE_BYTES, F_ROW_BYTES = 12, 4
#: GL_MAX_TEXTURE_SIZE the runtimes may count on (desktop GPUs and WebGL 2 on them): every table
#: is wrapped into textures no wider or taller (`runtime.wrap_width`).
GL_TEXTURE_LIMIT = 16384
#: Texels per chunk of the fit and kernel passes (bounds the pair arrays to ~100 MB).
CHUNK = 4096
THREADS = 2


def f_entry_bytes(vertex_count: int) -> int:
    """Bytes of one stored F entry over `vertex_count` global vertices (uint16 indices below 65536)."""
    return F_VALUE_BYTES + (2 if vertex_count < 65536 else 4)


def f_room(surface_vertices: int, options: KernelsPrecomputeOptions) -> float:
    """Bytes F may take on a surface of `surface_vertices` welded vertices: ``f_bytes`` per vertex,
    never less than ``f_floor_mb`` MiB; 0: unbounded. The per-vertex bound is for large meshes,
    where F grows as n²; on smaller ones the entries it drops are the long-range ones that carry
    light through the object (see `KernelsPrecomputeOptions.f_floor_mb`)."""
    if not options.f_bytes:
        return 0.0
    return max(options.f_bytes * surface_vertices, options.f_floor_mb * 2**20)


def global_budget(surface_vertices: int, options: KernelsPrecomputeOptions) -> int:
    """Vertices of the global mesh for a surface of `surface_vertices` welded vertices: the surface's
    own count, capped by ``global_vertices`` and, with a byte budget (`f_room`), by what leaves
    `ROW_ENTRIES` entries per global vertex (never below `MIN_GLOBAL`, nor above the surface's)."""
    n = surface_vertices
    if options.global_vertices:
        n = min(n, options.global_vertices)
    room = f_room(surface_vertices, options)
    if room:
        n = min(n, max(MIN_GLOBAL, int(room / (ROW_ENTRIES * f_entry_bytes(n) + F_ROW_BYTES))))
    return min(n, surface_vertices)


def f_entries(surface_vertices: int, global_vertices: int, options: KernelsPrecomputeOptions) -> int:
    """Entries F's room (`f_room`) holds over `global_vertices`, its fIndptr rows taken out; 0: unbounded."""
    room = f_room(surface_vertices, options)
    if not room:
        return 0
    return max(0, int((room - F_ROW_BYTES * (global_vertices + 1)) // f_entry_bytes(global_vertices)))


def entries_per_source(surface_vertices: int, global_vertices: int, options: KernelsPrecomputeOptions) -> int:
    """Entries each source of F keeps so that F fits its room (`f_room`); 0: unbounded.

    Raises
    ------
    ValueError
        The room does not hold one entry per global vertex (naming the two knobs).
    """
    if not f_room(surface_vertices, options):
        return 0
    keep = f_entries(surface_vertices, global_vertices, options) // global_vertices
    if keep < 1:
        raise ValueError(f"kernels: F's budget of {options.f_bytes:g} B per vertex (at least {options.f_floor_mb:g} MiB) "
                         f"holds no entry for {global_vertices} global vertices over {surface_vertices}; raise "
                         "--kernels-f-bytes or --kernels-f-floor-mb")
    return keep


@dataclass(frozen=True, eq=False)
class KernelsPrecompute:
    """The data and what the CPU needs to evaluate it at the texels.

    Attributes
    ----------
    data : KernelsData
    barycentric : (S, 3) float64
        Each covered texel's weights on ``data.texel_vertices`` (its point on the global mesh).
    positions, normals : (S, 3) float64
        Covered texels' surface points (mesh units) and unit normals.
    areas : (S,) float64
        The surface each covered texel stands for (its triangle's area over the triangle's texel
        count), mesh units².
    border_positions, border_normals : (B, 3) float64
        The same for the border texels.
    stats : dict
    seconds : dict
    """

    data: KernelsData
    barycentric: np.ndarray
    positions: np.ndarray
    normals: np.ndarray
    areas: np.ndarray
    border_positions: np.ndarray
    border_normals: np.ndarray
    stats: dict = field(default_factory=dict)
    seconds: dict = field(default_factory=dict)


def precompute_kernels(surface: Surface, atlas: Atlas, primitives: list[tuple[np.ndarray, np.ndarray]],
                       mm_per_unit: float, material: Material,
                       options: KernelsPrecomputeOptions = KERNELS_DEFAULTS) -> KernelsPrecompute:
    """Parameters
    ----------
    surface : Surface
        The mesh's welded surface.
    atlas : Atlas
        Its atlas, one part per primitive.
    primitives : list of (positions (n_p, 3), normals (n_p, 3))
        The primitives' render vertices, in the order of ``atlas.parts``.
    mm_per_unit : float
    material : Material
    options : KernelsPrecomputeOptions
    """
    options.check()
    seconds = {}
    t = time.perf_counter()
    params = profile_for(material)
    width, height = atlas.width, atlas.height
    k, r = options.kernel_size, (options.kernel_size - 1) // 2
    parts = [(part.uvs, part.faces, pos[part.vmapping], nrm[part.vmapping]) for part, (pos, nrm) in zip(atlas.parts, primitives)]
    texels = rasterize_atlas(parts, width, height)
    if not len(texels.rows):
        raise ValueError(f"kernels: the {width} x {height} atlas covers no texel centre; raise atlas_resolution")
    # said before the expensive steps: a runtime could not hold the kernel weights in one texture
    if len(texels.rows) * k * k > GL_TEXTURE_LIMIT**2:
        raise ValueError(f"kernels: {len(texels.rows)} covered texels x {k * k} kernel weights pass the "
                         f"{GL_TEXTURE_LIMIT} x {GL_TEXTURE_LIMIT} texels a GPU table holds; lower --atlas-resolution "
                         f"(now {max(width, height)}) or --kernels-size (now {k})")
    layout = atlas_surface(atlas, surface)
    real_face = layout.part_face_offset[texels.part] + texels.face
    pixels = texels.rows * width + texels.cols
    chart = layout.face_chart[real_face]
    border = border_texels(layout, surface, pixels, chart, r + 1 if options.seams == "unfold" else 0)
    seconds["texels"] = time.perf_counter() - t

    t = time.perf_counter()
    mm2 = mm_per_unit * mm_per_unit
    s_count = len(pixels)
    faces = np.r_[real_face, border.faces]
    bary = np.r_[texels.barycentric, border.barycentric]
    border_positions = np.einsum("bk,bkd->bd", border.barycentric, surface.positions[surface.faces[border.faces]])
    border_normals = np.einsum("bk,bkd->bd", border.barycentric, surface.normals[surface.faces[border.faces]])
    border_normals /= np.maximum(np.linalg.norm(border_normals, axis=1, keepdims=True), 1e-300)
    x = np.r_[texels.positions, border_positions] * mm_per_unit
    # A covered texel stands for its triangle's area shared among the triangle's texels, so that
    # the texels of a triangle hold exactly its area (the UV-area share misses it by ±10 % on a
    # triangle of ~15 texels, and the kernels and the distribution must agree on it).
    face_area = triangle_areas(surface.positions, surface.faces) * mm2
    per_face = np.bincount(real_face, minlength=len(face_area))
    area = np.r_[face_area[real_face] / per_face[real_face], border.areas * mm2]
    label = np.r_[chart, border.chart]
    index_image = np.full(width * height, -1, dtype=np.int64)
    index_image[np.r_[pixels, border.pixels]] = np.arange(len(faces))
    # Each border texel's light also reaches the vertices through the covered texel at its point.
    real_of = np.arange(len(faces))
    if len(border.pixels):
        real_of[s_count:] = cKDTree(x[:s_count]).query(x[s_count:])[1]

    # The global response's mesh: the surface itself, or a simplified copy when it is denser than
    # `global_vertices` or F's byte budget allows (Lensch et al. ran on meshes under 20,000
    # triangles; F grows as n^4/3).
    n_s = len(surface.positions)
    wanted = global_budget(n_s, options)
    if wanted < n_s:
        simple = simplify(surface.positions, surface.faces, target_count=2 * wanted)
        g_pos, g_faces = simple.positions, simple.faces
        g_normals = area_weighted_normals(g_pos, g_faces)
        faces, bary = locate_on_mesh(np.r_[texels.positions, border_positions], g_pos, g_faces)
        on_face, surface_weights = locate_on_mesh(surface.positions, g_pos, g_faces)
        surface_global = g_faces[on_face]
    else:
        g_pos, g_faces, g_normals = surface.positions, surface.faces, surface.normals
        surface_global = np.repeat(np.arange(n_s)[:, None], 3, axis=1)
        surface_weights = np.tile([1.0, 0.0, 0.0], (n_s, 1))
    corners = g_faces[faces]
    cell = vertex_areas(g_pos, g_faces) * mm2
    dual, resampled, lost = _dual_weights(corners[:s_count], faces[:s_count], bary[:s_count], area[:s_count], cell,
                                          np.bincount(faces[:s_count], weights=area[:s_count], minlength=len(g_faces)))
    seconds["distribution"] = time.perf_counter() - t

    t = time.perf_counter()
    # Under a byte bound F keeps only entries beyond the kernels' window (r texels): inside it the
    # blended kernels give the true response whatever F holds, and light F put there would be lost.
    correct_kernels = options.blend != "none"
    throughput = throughput_matrix(g_pos * mm_per_unit, g_faces, g_normals, params, options.threshold,
                                   diagonal=options.blend == "none",
                                   per_source=entries_per_source(n_s, len(g_pos), options),
                                   whole_entries=f_entries(n_s, len(g_pos), options),
                                   beyond_mm=r * float(np.sqrt(np.median(area[:s_count]))) if correct_kernels else 0.0)
    seconds["throughput"] = time.perf_counter() - t

    t = time.perf_counter()
    rows, cols = np.divmod(np.r_[pixels, border.pixels], width)
    grid = _Grid(index_image, rows, cols, label, width, height)
    local = ProfileTable.build(params, (k + 2) * float(np.sqrt(area.max())) * 2.0)
    n = len(g_pos)
    # int32 when n² fits (the default global mesh): half the memory and the bytes each search reads
    key_type = np.int32 if n * n < 2**31 else np.int64
    f_keys = np.repeat(np.arange(n, dtype=key_type), np.diff(throughput.indptr)) * key_type(n)
    f_keys += throughput.indices.astype(key_type)
    ctx = _Context(x, faces, g_faces, area, corners, bary, real_of, dual, throughput, f_keys, n, local,
                   near_table(local), params)
    # the dropped diagonal F_αα, handed out through the direct term instead
    w0 = dual[:, :, None] * throughput.field.own[corners[:s_count]]
    kernels, direct, misfit = _blend(ctx, grid, s_count, r, w0, options.blend, options.ridge)
    seconds["kernels"] = time.perf_counter() - t

    data = KernelsData(
        width=width, height=height, kernel_size=k, vertex_count=n, texels=pixels,
        kernels=kernels, texel_vertices=corners[:s_count], texel_dual=dual.astype(np.float32),
        texel_direct=direct.astype(np.float32), f_indptr=throughput.indptr, f_indices=throughput.indices,
        f_values=throughput.values, border_texels=border.pixels, border_vertices=surface.faces[border.faces],
        border_barycentric=border.barycentric.astype(np.float32), surface_vertex_count=n_s,
        surface_global=surface_global, surface_weights=surface_weights.astype(np.float32),
    )
    data.check()
    stats = {
        "texels": int(s_count), "borderTexels": int(len(border.pixels)), "borderTriangles": int(border.triangles),
        "charts": int(layout.face_chart.max() + 1), "atlasCoverage": s_count / float(width * height),
        "verticesResampled": int(resampled), "verticesWithoutTexels": int(lost),
        "globalVertices": int(n), "nnz": throughput.nnz, "nnzPerVertex": throughput.nnz / max(n, 1),
        "fMoved": throughput.moved,
        "throughputRadiusMm": throughput.radius_mm, "throughputSent": throughput.sent.tolist(), **misfit,
    }
    return KernelsPrecompute(data, bary[:s_count], texels.positions, texels.normals, area[:s_count] / mm2,
                             border_positions,
                             border_normals, stats, seconds)


def _dual_weights(corners: np.ndarray, faces: np.ndarray, beta: np.ndarray, area: np.ndarray, cell: np.ndarray,
                  face_area: np.ndarray) -> tuple[np.ndarray, int, int]:
    """(S, 3) distribution weights, the count of vertices given normalised barycentric weights,
    and the count of vertices no texel reaches.

    The texels of a triangle sample ∫_T (4β_α - 1) dA = A_T / 3 with an error (a triangle of ~15
    texels: ±10 % per vertex); each (triangle, corner) sum is shifted to the exact value, spread over
    its texels by area, so a vertex whose triangles all hold texels reproduces a constant exactly.
    """
    n = len(cell)
    raw = (4.0 * beta - 1.0) * area[:, None]
    _, slot, count = np.unique(faces, return_inverse=True, return_counts=True)
    slot = slot.reshape(-1)
    face_of_slot = np.zeros(len(count), dtype=np.int64)
    face_of_slot[slot] = faces
    texel_area = np.bincount(slot, weights=area, minlength=len(count))
    sampled = np.stack([np.bincount(slot, weights=raw[:, a], minlength=len(count)) for a in range(3)], axis=1)
    shift = (face_area[face_of_slot, None] / 3.0 - sampled) / np.maximum(texel_area, 1e-300)[:, None]
    dual = (raw + shift[slot] * area[:, None]) / np.maximum(cell[corners], 1e-300)
    flat = corners.reshape(-1)
    coverage = np.bincount(flat, weights=dual.reshape(-1), minlength=n)
    reached = np.bincount(flat, minlength=n) > 0
    bad = reached & (np.abs(coverage - 1.0) > DUAL_TOLERANCE)
    dual /= np.where(bad | ~reached, 1.0, coverage)[corners]  # a few triangles without texels: rescale
    if bad.any():  # many: positive weights normalised instead
        plain = beta * area[:, None]
        total = np.bincount(flat, weights=plain.reshape(-1), minlength=n)
        swap = bad[corners]
        dual[swap] = (plain / np.maximum(total[corners], 1e-300))[swap]
    return dual, int(bad.sum()), int((~reached & (cell > 0)).sum())


@dataclass(frozen=True, eq=False)
class _Grid:
    """Texel neighbourhoods in the atlas: which texel (covered or border) of the same chart sits at
    an offset from another."""

    index_image: np.ndarray
    rows: np.ndarray
    cols: np.ndarray
    label: np.ndarray
    width: int
    height: int

    def pairs(self, centres: np.ndarray, dy: np.ndarray, dx: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(centre, offset number, neighbour) for every offset of every centre that lands on a
        texel of the centre's chart."""
        rr = self.rows[centres][:, None] + dy[None, :]
        cc = self.cols[centres][:, None] + dx[None, :]
        inside = (rr >= 0) & (rr < self.height) & (cc >= 0) & (cc < self.width)
        nb = np.where(inside, self.index_image[np.clip(rr, 0, self.height - 1) * self.width
                                               + np.clip(cc, 0, self.width - 1)], -1)
        ok = (nb >= 0) & (self.label[np.maximum(nb, 0)] == self.label[centres][:, None])
        c, o = np.nonzero(ok)
        return centres[c], o, nb[c, o]


@dataclass(frozen=True, eq=False)
class _Context:
    x: np.ndarray           # (T, 3) texel points, mm
    face: np.ndarray        # (T,) surface face
    face_corners: np.ndarray  # (f, 3) surface.faces
    area: np.ndarray        # (T,) mm²
    corners: np.ndarray     # (T, 3) welded vertices
    bary: np.ndarray        # (T, 3)
    real_of: np.ndarray     # (T,) covered texel at the same surface point
    dual: np.ndarray        # (S, 3)
    throughput: Throughput  # F as stored
    f_keys: np.ndarray      # (nnz,) row · n + column, increasing (int32 when n² fits)
    vertex_count: int
    local: ProfileTable     # finer table for texel pairs
    near: tuple             # its closed form's stand-in (`compiled.near_table`)
    params: Profile

    def transport(self, receiver: np.ndarray, source: np.ndarray) -> np.ndarray:
        """(m, 3) T(receiver, source) between texels."""
        out = local_transport(self.local, self.near, self.x, self.area, receiver, source)
        same = receiver == source
        if same.any():
            out[same] = disc_integral(np.sqrt(self.area[source[same]] / np.pi), self.params)
        return out

    def global_part(self, receiver: np.ndarray, source: np.ndarray) -> np.ndarray:
        """(m, 3) Σ_β ψ_β(receiver) Σ_α dual_α(source) F'_αβ for texel receivers and covered
        texel sources: F' once per distinct (source face, receiver face), mixed with the dual
        weights once per distinct (source, receiver face)."""
        faces = len(self.face_corners)
        if not len(source):
            return np.zeros((0, 3))
        # a chunk's sources are a narrow range: keys from its lowest keep the radix sort short
        lo = int(source.min())
        first, per_pair = unique_keys((source - lo) * faces + self.face[receiver], (int(source.max()) - lo + 1) * faces)
        src, rface = source[first], self.face[receiver[first]]
        first_block, per_source = unique_keys(self.face[src] * faces + rface, faces * faces)
        a, b = np.divmod(np.arange(9), 3)
        cs = self.face_corners[self.face[src[first_block]]]
        cr = self.face_corners[rface[first_block]]
        block = self.entries(cs[:, a].reshape(-1), cr[:, b].reshape(-1)).reshape(len(first_block), 3, 3, 3)
        return mix_global(self.dual, src, block, per_source, self.bary, receiver, per_pair)

    def entries(self, sources: np.ndarray, receivers: np.ndarray) -> np.ndarray:
        """(m, 3) the stored F entries (0 where F has none), found in its sorted (row, column) keys."""
        out = np.zeros((len(sources), 3))
        if not len(self.f_keys) or not len(sources):
            return out
        key = receivers * self.vertex_count + sources
        # Neighbouring face pairs share vertex pairs: each distinct key is searched once, and
        # sorted needles walk F's keys in order (far fewer cache misses).
        order = argsort_keys(key, self.vertex_count**2)
        ordered = key[order]
        new = np.r_[True, ordered[1:] != ordered[:-1]]
        distinct = ordered[new]
        # needles of F's key type: a wider type would have numpy cast all of F's keys per call
        at = np.minimum(np.searchsorted(self.f_keys, distinct.astype(self.f_keys.dtype)), len(self.f_keys) - 1)
        value = np.where((self.f_keys[at] == distinct)[:, None], self.throughput.values[at], 0.0)
        out[order] = value[np.cumsum(new) - 1]
        return out

    def shared(self, receiver: np.ndarray, source: np.ndarray) -> np.ndarray:
        """(m, 3 α) Σ_β ψ_β(receiver) [β = α-th corner of source]: how the direct weights of the
        source's corners reach the receiver."""
        return shared_hats(self.corners, self.bary, receiver, source)


def _blend(ctx: _Context, grid: _Grid, s_count: int, r: int, w0: np.ndarray, blend: str,
           ridge: float) -> tuple[np.ndarray, np.ndarray, dict]:
    """The gather kernels (S, k², 3) and the direct weights (S, 3 corners, 3 channels).

    Per chunk of covered sources, in one pass over each source's window: the true response T and
    the global part there, the blending fit (``optimised``: least squares on the ring at r + 1,
    ridge-pulled towards w0, subject to the energy the smooth part sends beyond the window being
    what T sends there, so kernels plus smooth part carry exactly the energy of the unblended
    global response), then the kernel entries ``T - g`` of the covered receivers, which see the
    source at the mirrored offset. Border texels as sources come last, once every weight is known.
    """
    ring_dy, ring_dx = _ring(r + 1)
    dy, dx = _window(r)
    mirror = len(dy) - 1 - np.arange(len(dy))  # offset o from s to t is offset mirror[o] from t to s
    cell = ctx.throughput.field.area
    correct = blend != "none"

    def chunk(start: int):
        stop = min(s_count, start + CHUNK)
        centres = np.arange(start, stop)
        m = stop - start
        sources, offset, receivers = grid.pairs(centres, dy, dx)
        local = sources - start
        truth = ctx.transport(receivers, sources)
        stats = np.zeros((4, 3))
        if blend == "optimised":
            # the ring's global part with the window's: the pairs share most (source, face) blocks
            ring_sources, _, ring = grid.pairs(centres, ring_dy, ring_dx)
            both = ctx.global_part(np.r_[receivers, ring], np.r_[sources, ring_sources])
            smooth, ring_smooth = both[:len(receivers)], both[len(receivers):]
        elif correct:
            smooth = ctx.global_part(receivers, sources)
        if correct:
            hats = ctx.shared(receivers, sources)
        if blend == "optimised":
            weights, stats = _fit_chunk(ctx, centres, w0[centres], ridge, truth - smooth, hats, local, receivers, cell,
                                        ring_sources, ring, ring_smooth)
        else:
            weights = w0[centres] if blend == "fixed" else np.zeros((m, 3, 3))
        value = truth
        if correct:
            value = truth - smooth - np.einsum("pa,pac->pc", hats, weights[local])
        real = receivers < s_count
        # each (receiver, offset) has one source, so chunks write disjoint entries
        flat[receivers[real] * len(dy) + mirror[offset[real]]] = value[real]
        direct[start:stop] = weights
        return stats

    out = np.zeros((s_count, len(dy), 3), dtype=np.float32)  # as stored
    flat = out.reshape(-1, 3)
    direct = np.zeros((s_count, 3, 3))
    with ThreadPoolExecutor(THREADS) as pool:
        totals = sum(pool.map(chunk, range(0, s_count, CHUNK)), np.zeros((4, 3)))

    def border_chunk(start: int):
        receivers, offset, texel = grid.pairs(np.arange(start, min(s_count, start + CHUNK)), dy, dx)
        keep = texel >= s_count
        receivers, offset, texel = receivers[keep], offset[keep], texel[keep]
        value = ctx.transport(receivers, texel)
        if correct:
            source = ctx.real_of[texel]
            ratio = (ctx.area[texel] / ctx.area[source])[:, None]
            smooth = ctx.global_part(receivers, source)
            smooth += np.einsum("pa,pac->pc", ctx.shared(receivers, source), direct[source])
            value -= ratio * smooth
        flat[receivers * len(dy) + offset] = value  # the chunk's own receivers

    if len(ctx.x) > s_count:
        with ThreadPoolExecutor(THREADS) as pool:
            list(pool.map(border_chunk, range(0, s_count, CHUNK)))
    misfit = {}
    if blend == "optimised":
        denom = np.sqrt(np.maximum(totals[2], 1e-300))
        misfit = {"energyConstrained": float(totals[0, 0] / max(s_count, 1)),
                  "ringMisfitGlobal": (np.sqrt(totals[1]) / denom).tolist(),
                  "ringMisfitBlended": (np.sqrt(totals[3]) / denom).tolist()}
    return out, direct, misfit


def _fit_chunk(ctx: _Context, centres: np.ndarray, w0: np.ndarray, ridge: float, excess: np.ndarray,
               hats: np.ndarray, local: np.ndarray, receivers: np.ndarray, cell: np.ndarray, ring_sources: np.ndarray,
               ring: np.ndarray, ring_smooth: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Blending weights of the sources `centres` (m,) and their misfit sums.

    `excess` (T - global part), `hats` and `local` are the window pairs' of these sources;
    `ring_sources`, `ring` (r,) the pairs on their rings and `ring_smooth` (r, 3) the global part
    there. Returns weights (m, 3, 3) and stats (4, 3): row 0 the count of sources constrained (then
    zeros), per channel the ring's squared misfit of the global part alone (row 1), |T|² (row 2)
    and the squared misfit after the fit (row 3).
    """
    m = len(centres)
    ring_local = ring_sources - centres[0]
    truth = ctx.transport(ring, ring_sources)
    target = truth - ring_smooth
    design = ctx.shared(ring, ring_sources)
    normal = grouped_products(ring_local, design, design, m)
    rhs = grouped_products(ring_local, design, target, m)
    count = np.bincount(ring_local, minlength=m)
    # energy inside the window: of T minus the global part, and of each corner's hat
    weight, one = ctx.area[receivers], np.ones((len(local), 1))
    inside = grouped_products(local, hats, one, m, weight)[:, :, 0]
    extra = grouped_products(local, excess, one, m, weight)[:, :, 0]
    corner_cells = cell[ctx.corners[centres]]
    outside = corner_cells - inside
    budget = np.einsum("sa,sac->sc", corner_cells, w0) - extra
    # The pull towards w0 counts as `ridge` of a ring texel per ring texel: a ring the corners'
    # hats barely reach (small design entries) cannot pull the weights far.
    lam = ridge * count + 1e-300
    system = np.zeros((m, 4, 4))
    system[:, :3, :3] = normal + lam[:, None, None] * np.eye(3)
    right = np.zeros((m, 4, 3))
    right[:, :3] = rhs + lam[:, None, None] * w0
    # Where the corners' hats barely reach past the window, the energy cannot be steered by w
    # without weights far from w0: leave the constraint out (an identity row keeps the system regular).
    size = np.abs(outside).sum(axis=1)
    change = np.abs(budget - np.einsum("sa,sac->sc", outside, w0)).max(axis=1)
    steer = (size > CONSTRAIN * corner_cells.sum(axis=1)) & (change <= STEER_LIMIT * size * np.abs(w0).max(axis=(1, 2)))
    unit = outside / np.maximum(size, 1e-300)[:, None]
    system[steer, :3, 3] = system[steer, 3, :3] = unit[steer]
    right[steer, 3] = budget[steer] / size[steer, None]
    system[~steer, 3, 3] = 1.0
    weights = np.linalg.solve(system, right)[:, :3]
    residual = target - np.einsum("pa,pac->pc", design, weights[ring_local])
    stats = np.zeros((4, 3))
    stats[0, 0] = steer.sum()
    stats[1] = np.einsum("pc,pc->c", target, target)
    stats[2] = np.einsum("pc,pc->c", truth, truth)
    stats[3] = np.einsum("pc,pc->c", residual, residual)
    return weights, stats


def _window(r: int) -> tuple[np.ndarray, np.ndarray]:
    """The (2r + 1)² offsets in kernel order (`KernelsData.offsets`)."""
    dy, dx = np.divmod(np.arange((2 * r + 1) ** 2), 2 * r + 1)
    return dy - r, dx - r


def _ring(distance: int) -> tuple[np.ndarray, np.ndarray]:
    """Offsets at chessboard distance `distance` (8 · distance of them)."""
    span = np.arange(-distance, distance + 1)
    dy, dx = np.meshgrid(span, span, indexing="ij")
    on = np.maximum(np.abs(dy), np.abs(dx)) == distance
    return dy[on], dx[on]
