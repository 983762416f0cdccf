"""The diffuse-scattering gather over a surface as a sparse linear operator.

For signals E (n, K) at the surface vertices (irradiance of K lights, say), per colour channel c::

    q_c[o, :] = Σ_i ∫_{cell_i} Rd_c(|p - x_o|) dp E[i, :]

over each source's cell (a third of its triangles): a disc of its area in its tangent plane
(`disc_average`: point samples under-resolve Rd on meshes coarser than z_r), split into its
sub-triangles near the receiver so that cells tile (`near_field`), the receiver's own cell
integrated exactly (`cell_integral`); sources beyond the energy radius R_c dropped (at
most `energy_dropped` of R_d on a plane), and no source sending out more than R_d in all.

Not O(N²): the energy radius of marble at realistic scale covers thousands of vertices. Vertices
are bucketed in nested voxel grids (cell size h_0·2^l); two cells of one level are *near* when
their integer coordinates differ by at most `separation` in every axis. Descending from the top
level, a (target cell, source cell) pair that is not near but whose parents are is *well
separated*: each target vertex x_o reads the source cell as one cluster, from the cluster's
area-weighted centroid ȳ at distance D >= separation·h_l:

    (Rd(D) + ½ tr(H Σ)) Σ_i ΔA_i E_i

with Σ the cluster's area covariance (its vertices' own discs included) and H the kernel's
Hessian at D, so the cluster's extent enters to second order. Pairs still near at level 0 are summed vertex by vertex. Each (target,
source) vertex pair is thereby counted exactly once.

A wider separation buys accuracy more cheaply than clusters' first moments Σ ΔA E (y - ȳ)
(benchmarks/README.md#scatter-operator-separation).

`scatter_plan` does all of this but the entries: the cells, the pairs each level reads and the
clusters' moments; its `build` computes the entries, and `scatter_forecast` builds a sample of its
rows to say beforehand what the whole will hold and take.

Vertices are kept in Morton order of their finest cell, so every cell of every level is a
contiguous run of vertices (clusters are sums over runs) and the sparse products read memory
that lies close together.

The three colour channels' entries of a matrix (`ChannelRows`) share one column index each where
that stores fewer bytes: the exact pairs are within every channel's radius but on rare meshes,
the finest levels' clusters mostly too, the coarse ones of skin-like materials only within red's.
"""

from __future__ import annotations

import os
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree

from sssbake.pipeline.core.profile import (
    Profile,
    disc_integral,
    profile_derivatives,
    profile_total,
    radius_for_energy,
)
from sssbake.pipeline.core.freed_memory import release_freed_memory
from sssbake.pipeline.core.morton import morton_codes
from sssbake.pipeline.core.near_field import NearField
from sssbake.pipeline.core.scatter_kernels import (
    child_pairs,
    cluster_moments,
    csr_rows_product,
    far_fill,
    near_fill,
    pair_counts,
    shared_rows_product,
)
from sssbake.pipeline.core.scatter_options import SCATTER_DEFAULTS, ScatterOptions
from sssbake.pipeline.core.surface import vertex_areas

#: Candidate pairs per block of rows a thread builds at once: small enough that the threads share
#: the work evenly, large enough that handing out a block costs nothing beside it (the compiled
#: build writes entries in place); also the entries `_limit_energy` reads at once, which bounds its
#: float64 temporaries.
ENTRIES_PER_CHUNK = 100_000
#: Step in ln D of the far-field kernel table.
TABLE_STEP = 1e-3


@dataclass(frozen=True, eq=False)
class ScatterOperator:
    """The precomputed gather; `apply` it to signals.

    Internally vertices are in Morton order; `apply` takes and returns the caller's order.

    Attributes
    ----------
    order : (n,) int64
        Caller's index of each internal vertex.
    source_area : (3, n) float64
        Per channel, ΔA of each internal vertex (mm²) times its energy scale (`_limit_energy`):
        what the clusters' Σ ΔA E weigh.
    near : ChannelRows (n targets, n sources, stride 0)
        Exact pairs in internal order: ∫_{cell_i} Rd_c, times the source's energy scale.
    levels : list of FarLevel
        The cluster terms of each level that has any.
    radius_mm : (3,) float64
        Truncation radius per channel.
    dropped_fraction : (3,) float64
        Fraction of R_d beyond `radius_mm` (<= energy_dropped).
    stats : dict
        ``cell_mm``, ``levels``, ``separation``, ``near_nnz`` and ``near_shared`` (its stored
        values, `ChannelRows.nnz`, and whether its layout is shared), and per level with cluster
        terms (finest first) ``cells``, ``far_nnz`` and ``far_shared``; ``seconds`` to build.
    threads, block : int
        From the options.
    """

    order: np.ndarray
    source_area: np.ndarray
    near: "ChannelRows"
    levels: list = field(default_factory=list)
    radius_mm: np.ndarray = field(default_factory=lambda: np.zeros(3))
    dropped_fraction: np.ndarray = field(default_factory=lambda: np.zeros(3))
    stats: dict = field(default_factory=dict)
    threads: int = 1
    block: int = 32

    @property
    def nnz(self) -> int:
        """Stored values over all channels (exact pairs plus vertex-cluster terms, `ChannelRows.nnz`:
        a shared layout's entry counts three, its 0.0 beyond a channel's radius included)."""
        return self.near.nnz + sum(f.matrix.nnz for f in self.levels)

    @property
    def nbytes(self) -> int:
        """Bytes of the stored matrices and index arrays."""
        total = self.order.nbytes + self.source_area.nbytes + self.near.nbytes
        return total + sum(f.matrix.nbytes + f.starts.nbytes for f in self.levels)

    def apply(self, signal: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        """Gather signals.

        Parameters
        ----------
        signal : (n, K) float64
            Per vertex (caller's order) and signal, the irradiance-like quantity E; finite.
        out : (3, n, K) float64 or float32, optional
            Where to write the result (a view of a larger array, say); a new float64 array if
            None. A float32 `out` loses nothing to a float32 operator, whose products are float32.

        Returns
        -------
        (3, n, K) float64 or float32
            q per channel, vertex (caller's order) and signal; >= 0 where the signal is >= 0.
        """
        signal = np.asarray(signal, dtype=np.float64)
        n = len(self.order)
        if signal.ndim != 2 or signal.shape[0] != n:
            raise ValueError(f"scatter apply: signal must be ({n}, K), got {signal.shape}")
        if not np.all(np.isfinite(signal)):
            raise ValueError("scatter apply: signal contains NaN or Inf")
        k = signal.shape[1]
        if out is None:
            out = np.empty((3, n, k))
        elif out.shape != (3, n, k):
            raise ValueError(f"scatter apply: out must be (3, {n}, {k}), got {out.shape}")
        dtype = self.near.dtype
        matrices = [self.near, *(f.matrix for f in self.levels)]
        # Targets in blocks of about equal stored values, several per thread so that the threads
        # finish together.
        entries = sum(m.values_before() for m in matrices)
        cuts = np.searchsorted(entries, np.linspace(0, entries[-1], 8 * self.threads + 1)[1:-1])
        bounds = np.unique(np.r_[0, cuts, n]).tolist()
        blocks = list(zip(bounds[:-1], bounds[1:]))
        clamp = bool(np.all(signal >= 0))
        # Passes of `threads · block` signals: every thread reads its rows of the matrices once per
        # pass for all the pass's signals.
        count = -(-k // (self.threads * self.block))
        edges = np.linspace(0, k, count + 1).round().astype(int)
        for a, b in zip(edges[:-1], edges[1:]):
            e = signal[self.order, a:b]
            moments = [np.empty((3 * len(f.starts), b - a), dtype) for f in self.levels]
            # Each level's moments read every vertex once: as much work per level, one level a thread.
            _run_all(lambda f_m: cluster_moments(e, self.source_area, f_m[0].starts, f_m[1]),
                     list(zip(self.levels, moments)), self.threads)
            sources = [e.astype(dtype, copy=False), *moments]
            q = np.empty((3 * n, b - a), dtype)

            def run(rows: tuple) -> None:
                # near first, then each level's sum added: q's rounding is scipy's `near_c @ e + Σ_l F_lc @ m_lc`
                for i, (m, x) in enumerate(zip(matrices, sources)):
                    m.product(rows[0], rows[1], x, q, i > 0)

            _run_all(run, blocks, self.threads)
            if clamp:
                # The spread term is an expansion: it can dip a hair below zero, which q cannot.
                np.maximum(q, 0.0, out=q)
            out[:, self.order, a:b] = q.reshape(3, n, -1)
        return out


@dataclass(frozen=True, eq=False)
class FarLevel:
    """One level's vertex-cluster terms.

    Attributes
    ----------
    matrix : ChannelRows (n targets, m clusters, stride m)
        Each target's kernel for the clusters' Σ ΔA E, channel c's read from the moments' rows
        c·m + cluster (`scatter_kernels.cluster_moments`).
    starts : (m,) int64
        First internal vertex of each cluster (clusters are contiguous runs).
    """

    matrix: "ChannelRows"
    starts: np.ndarray


@dataclass(frozen=True, eq=False)
class ChannelRows:
    """Per colour channel c a sparse (T, width) matrix A_c, its row o the sources within the
    channel's radius of target o in CSR order; the products read x_c = x[c·stride : c·stride + width].

    Stored in one of two layouts, whichever takes fewer bytes (`_shared_layout`):

    - shared: one pattern for the three channels, the union of theirs (the sources within the
      largest radius): indptr (T + 1,), indices (U,), data (U, 3), 0.0 where a source is beyond
      the channel's radius. Adding 0·x leaves a float sum as it was, so each channel's products
      and column sums equal its own pattern's bit for bit, and each index is read once for three
      values: 16 bytes per entry in float32 against 24 for three.
    - split: channel c's row o is CSR row c·T + o: indptr (3T + 1,), indices and data (N,), N the
      entries within their channel's radius over the channels: 8 bytes each.

    Attributes
    ----------
    indptr, indices, data
        As above; int32 indices where the entries and columns allow.
    width : int
        Columns: sources (exact pairs) or clusters.
    stride : int
        Rows of x between channels: 0 where the three read one signal (the exact pairs' E),
        `width` where each reads its own (channel c's moments at rows c·m + cluster).
    within : (3, T) int32 or None
        Shared layout: per channel and row the entries within the channel's radius (what the
        split layout stores), so that `_limit_energy` sums in the same chunks whichever the layout.
    """

    indptr: np.ndarray
    indices: np.ndarray
    data: np.ndarray
    width: int
    stride: int
    within: np.ndarray | None = None

    @property
    def shared(self) -> bool:
        return self.data.ndim == 2

    @property
    def rows(self) -> int:
        """T, the targets."""
        return (len(self.indptr) - 1) // (1 if self.shared else 3)

    @property
    def dtype(self) -> np.dtype:
        return self.data.dtype

    @property
    def nnz(self) -> int:
        """Stored values: 3 per entry of a shared layout (its 0.0 included), 1 per entry of a split one."""
        return self.data.size

    @property
    def nbytes(self) -> int:
        within = 0 if self.within is None else self.within.nbytes
        return self.data.nbytes + self.indices.nbytes + self.indptr.nbytes + within

    def channel(self, c: int) -> tuple[np.ndarray, np.ndarray]:
        """(ptr (T + 1,), values) of channel c: row o's entries are indices[ptr[o]:ptr[o + 1]] with
        values[ptr[o]:ptr[o + 1]] (views: writing values writes the matrix)."""
        if self.shared:
            return self.indptr, self.data[:, c]
        t = self.rows
        return self.indptr[c * t:(c + 1) * t + 1], self.data

    def channel_ptr(self) -> np.ndarray:
        """(3T + 1,) int64: entries within their channel's radius before channel c's row o, at
        c·T + o: the split layout's indptr."""
        if self.shared:
            return np.r_[0, np.cumsum(self.within, dtype=np.int64)]
        return self.indptr.astype(np.int64)

    def values_before(self) -> np.ndarray:
        """(T + 1,) int64: stored values of the targets before each, over the channels."""
        ptr = self.indptr.astype(np.int64)
        if self.shared:
            return 3 * ptr
        t = self.rows
        return ptr[:t + 1] + (ptr[t:2 * t + 1] - ptr[t]) + (ptr[2 * t:] - ptr[2 * t])

    def product(self, o0: int, o1: int, x: np.ndarray, y: np.ndarray, add: bool) -> None:
        """Targets o0..o1 - 1 of A_c x_c into y[c·T + o] (rows, K) in place, or added to it where `add`;
        each (row, channel) summed in CSR order (`scatter_kernels`)."""
        if self.shared:
            shared_rows_product(o0, o1, self.indptr, self.indices, self.data, self.stride, x, y, add)
            return
        t = self.rows
        for c in range(3):
            x_c = x[c * self.stride:c * self.stride + self.width]
            csr_rows_product(c * t + o0, c * t + o1, self.indptr, self.indices, self.data, x_c, y, add)


def scatter_operator(positions_mm: np.ndarray, faces: np.ndarray, normals: np.ndarray, params: Profile,
                     options: ScatterOptions = SCATTER_DEFAULTS) -> ScatterOperator:
    """Build the gather for a surface.

    Parameters
    ----------
    positions_mm : (n, 3) float64
        Vertex positions in millimetres.
    faces : (m, 3) int
        Triangles; each vertex owns a third of its triangles (its area ΔA, mm²).
    normals : (n, 3) float64
        Unit vertex normals: each source is a disc in its tangent plane.
    params : Profile
    options : ScatterOptions

    Returns
    -------
    ScatterOperator
    """
    if options.hierarchy:
        return scatter_plan(positions_mm, faces, normals, params, options).build()
    t0 = time.perf_counter()
    x, tri, nrm, area = _checked(positions_mm, faces, normals, options)
    n = len(x)
    radius, total, dropped = _radius(params, options)
    dtype = np.float32 if options.float32 else np.float64
    build = _Builder(params, radius, dtype, options.threads, NearField.build(x, tri, nrm, params))
    lists = cKDTree(x).query_ball_point(x, float(radius.max()))
    count = np.fromiter((len(v) for v in lists), dtype=np.int64, count=len(lists))
    # Each row's list is its own vertices, each source a range of one vertex.
    rows = np.arange(n)
    near = build.near(rows, rows, np.r_[0, np.cumsum(count)], np.concatenate(lists).astype(np.int32), np.arange(n + 1),
                      count)
    source_area = _limit_energy(near, [], area, total)
    stats = dict(levels=0, separation=0, near_nnz=near.nnz, near_shared=near.shared, far_nnz=[], far_shared=[],
                 cells=[], seconds=time.perf_counter() - t0)
    return ScatterOperator(np.arange(n), source_area, near, [], radius, dropped, stats, options.threads, options.block)


@dataclass(frozen=True, eq=False)
class ScatterPlan:
    """The hierarchical gather before its entries: the vertices' Morton order, the cells of every
    level and which (target cell, source cell) pairs each level reads (`scatter_plan`). `build` it,
    or build the rows of a few targets to forecast the whole (`scatter_forecast`).

    Attributes
    ----------
    order : (n,) int64
        Caller's index of each internal vertex.
    positions : (n, 3) float64
        Internal order, millimetres.
    area : (n,) float64
        ΔA of each internal vertex (mm²).
    total : (3,) float64
        R_d per channel (what `_limit_energy` holds each source to).
    radius_mm, dropped_fraction : (3,) float64
    starts : list of (m_l,) int64
        Per level, the first internal vertex of each cell.
    cell_of : list of (n,) int64
        Per level, each internal vertex's cell.
    far : list of (int, _Clusters)
        (level, its clusters and which of them each target cell reads) for each level with
        well-separated pairs, coarsest first.
    near_ptr, near_lists : (m_0 + 1,) and (p,) int
        Per level-0 cell, the cells whose vertices it sums vertex by vertex (`_lists`).
    near_per_cell : (m_0,) int64
        Source vertices each level-0 cell's targets read so.
    builder : _Builder
    stats : dict
        ``cell_mm``, ``levels``, ``separation``.
    options : ScatterOptions
    """

    order: np.ndarray
    positions: np.ndarray
    area: np.ndarray
    total: np.ndarray
    radius_mm: np.ndarray
    dropped_fraction: np.ndarray
    starts: list
    cell_of: list
    far: list
    near_ptr: np.ndarray
    near_lists: np.ndarray
    near_per_cell: np.ndarray
    builder: "_Builder"
    stats: dict
    options: ScatterOptions

    @property
    def workers(self) -> int:
        """Threads the forecasts count as working at once: `options.threads`, at most one a core."""
        return min(self.options.threads, os.cpu_count() or 1)

    def matrices(self, rows: np.ndarray) -> tuple[ChannelRows, list]:
        """The rows of the targets `rows` (T,) internal indices: (near (T targets), FarLevel per level
        with cluster terms, finest first), before `_limit_energy`."""
        levels = [FarLevel(self.builder.far(clusters, self.cell_of[level], rows), self.starts[level])
                  for level, clusters in self.far]
        # Pairs still near at level 0: every vertex pair, exactly.
        keys = self.cell_of[0][rows]
        vertex_ptr = np.r_[self.starts[0], len(self.positions)]
        near = self.builder.near(rows, keys, self.near_ptr, self.near_lists, vertex_ptr, self.near_per_cell[keys])
        return near, levels[::-1]

    def build(self) -> ScatterOperator:
        """The operator: every vertex a target."""
        t0 = time.perf_counter()
        near, levels = self.matrices(np.arange(len(self.positions)))
        source_area = _limit_energy(near, levels, self.area, self.total)
        release_freed_memory()  # the build's temporaries, before the caller allocates q
        stats = dict(self.stats, near_nnz=near.nnz, near_shared=near.shared, far_nnz=[f.matrix.nnz for f in levels],
                     far_shared=[f.matrix.shared for f in levels], cells=[len(f.starts) for f in levels],
                     seconds=self.stats["seconds"] + time.perf_counter() - t0)
        return ScatterOperator(self.order, source_area, near, levels, self.radius_mm, self.dropped_fraction, stats,
                               self.options.threads, self.options.block)


def scatter_plan(positions_mm: np.ndarray, faces: np.ndarray, normals: np.ndarray, params: Profile,
                 options: ScatterOptions = SCATTER_DEFAULTS) -> ScatterPlan:
    """The hierarchy of `scatter_operator` (same arguments, `options.hierarchy` true) without its entries."""
    t0 = time.perf_counter()
    x, tri, nrm, area = _checked(positions_mm, faces, normals, options)
    if not options.hierarchy:
        raise ValueError("scatter: a plan needs the hierarchy (options.hierarchy)")
    n = len(x)
    radius, total, dropped = _radius(params, options)
    r_max = float(radius.max())
    dtype = np.float32 if options.float32 else np.float64
    # Finest cell: about `vertices_per_cell` vertices of area; at least extent / 2^20 so that
    # Morton codes (21 bits per axis) hold every coordinate.
    a = options.separation
    extent = float(np.ptp(x, axis=0).max())
    h0 = max(np.sqrt(options.vertices_per_cell * area.sum() / n), extent * 2.0**-20, 1e-12)
    coords = np.floor((x - x.min(axis=0)) / h0).astype(np.int64)
    code = morton_codes(coords)
    order = np.argsort(code, kind="stable")
    x, area, nrm, coords, code = x[order], area[order], nrm[order], coords[order], code[order]
    inverse = np.empty(n, dtype=np.int64)
    inverse[order] = np.arange(n)
    # Well-separated clusters are at least a·h_0 from their targets.
    build = _Builder(params, radius, dtype, options.threads, NearField.build(x, inverse[tri], nrm, params),
                     closest=a * h0)
    # Top level: pairs it leaves out (more than `a` cells apart) are beyond the radius, or there
    # are none because the whole object spans at most `a` cells.
    top = 0
    while a * h0 * 2.0**top < r_max and np.ptp(coords >> top, axis=0).max() > a:
        top += 1
    cell_of = [_runs(code >> (3 * level)) for level in range(top + 1)]  # per level: vertex -> cell
    starts = [np.flatnonzero(np.r_[True, c[1:] != c[:-1]]) for c in cell_of]
    cell_coords = [coords[s] >> level for level, s in enumerate(starts)]

    pairs = _near_cell_pairs(cell_coords[top], a)
    far = []
    for level in range(top - 1, -1, -1):
        # Children of near parent pairs: near ones descend, the others are well separated here.
        first_child = cell_of[level][starts[level + 1]]
        n_children = np.diff(np.r_[first_child, len(starts[level])])
        pairs, separated = child_pairs(pairs, first_child, n_children, cell_coords[level], a)
        if len(separated):
            far.append((level, _Clusters.build(x, area, nrm, starts[level], cell_of[level], separated)))
    near_ptr, near_lists = _lists(pairs.astype(np.int32), len(starts[0]))
    size = np.diff(np.r_[starts[0], n])
    per_cell = np.bincount(pairs[:, 0], weights=size[pairs[:, 1]], minlength=len(starts[0])).astype(np.int64)
    stats = dict(cell_mm=float(h0), levels=top + 1, separation=a)
    plan = ScatterPlan(order, x, area, total, radius, dropped, starts, cell_of, far, near_ptr, near_lists, per_cell,
                       build, stats, options)
    # One target's rows load the compiled build from numba's cache (1-3 s, once per process) here,
    # not inside `scatter_forecast`'s timed sample, which scales its time ~50-fold.
    plan.matrices(np.zeros(1, dtype=np.int64))
    stats["seconds"] = time.perf_counter() - t0
    return plan


def _checked(positions_mm, faces, normals, options: ScatterOptions):
    """(x, faces, normals, vertex areas) as arrays, or ValueError naming what is wrong."""
    x = np.asarray(positions_mm, dtype=np.float64)
    tri = np.asarray(faces)
    nrm = np.asarray(normals, dtype=np.float64)
    if x.ndim != 2 or x.shape[1] != 3 or len(x) == 0 or nrm.shape != x.shape or tri.ndim != 2 or tri.shape[1] != 3:
        raise ValueError(f"scatter: need positions (n, 3), faces (m, 3) and normals (n, 3) with n > 0, got {x.shape}, "
                         f"{tri.shape} and {nrm.shape}")
    if not (np.all(np.isfinite(x)) and np.all(np.isfinite(nrm))):
        raise ValueError("scatter: positions and normals must be finite")
    if len(tri) and (tri.dtype.kind not in "iu" or tri.min() < 0 or tri.max() >= len(x)):
        raise ValueError(f"scatter: faces must index the {len(x)} vertices")
    area = vertex_areas(x, tri)
    if not 0.0 < options.energy_dropped < 1.0:
        raise ValueError(f"scatter: energy_dropped must be in (0, 1), got {options.energy_dropped}")
    if options.separation < 1 or not options.vertices_per_cell > 0:
        raise ValueError("scatter: separation must be >= 1 and vertices_per_cell > 0")
    if options.threads < 1 or options.block < 1:
        raise ValueError("scatter: threads and block must be >= 1")
    return x, tri, nrm, area


def _radius(params: Profile, options: ScatterOptions) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(truncation radius, R_d, fraction of R_d beyond the radius), each (3,) per channel."""
    radius = radius_for_energy(options.energy_dropped, params)
    total = profile_total(params)
    kept = np.diagonal(disc_integral(radius, params))
    dropped = np.clip(np.where(total > 0, 1.0 - kept / np.where(total > 0, total, 1.0), 0.0), 0.0, 1.0)
    return radius, total, dropped


def _limit_energy(near: ChannelRows, levels: list, area: np.ndarray, total: np.ndarray) -> np.ndarray:
    """Scale down every source that would send out more than R_d; returns `source_area` (3, n).

    A source's outgoing fraction Σ_o ΔA_o K(o, i) / ΔA_i is at most R_d on a plane and on convex
    surfaces (chords are the plane's distances there); across folds and thin parts the Euclidean
    kernel counts receivers on both sides and the sum can exceed R_d, which light cannot. Such a
    source is scaled as a whole (its exact pairs in `near`, in place, and its weight in the
    clusters), so the shape of its spread does not depend on where the near field ends. Needs
    every vertex as a target (rows and columns in the same, internal, order).
    """
    n = len(area)
    headroom = 1.0 - 1e-6  # room for float32 rounding
    source_area = np.tile(area, (3, 1))
    far = [_column_sums(f.matrix, area, 0, 3 * n) for f in levels]  # Σ_o ΔA_o K(o, cluster)
    for c in range(3):
        fraction = np.divide(_column_sums(near, area, c * n, (c + 1) * n)[c], area, out=np.zeros(n), where=area > 0)
        for f, per_cluster in zip(levels, far):
            fraction += np.repeat(per_cluster[c], np.diff(np.r_[f.starts, n]))
        over = fraction > headroom * total[c]
        if np.any(over):
            scale = np.ones(n)
            scale[over] = headroom * total[c] / fraction[over]
            ptr, values = near.channel(c)
            for r0, r1 in _row_chunks(ptr, 0, n):
                lo, hi = ptr[r0], ptr[r1]
                values[lo:hi] = (values[lo:hi].astype(np.float64) * scale[near.indices[lo:hi]]).astype(near.dtype)
            source_area[c] *= scale
    return source_area


def _row_chunks(indptr: np.ndarray, row0: int, row1: int) -> list:
    """(r0, r1) ranges of the rows row0..row1 - 1 of a CSR `indptr` with about ENTRIES_PER_CHUNK entries each."""
    cuts = np.searchsorted(indptr, np.arange(indptr[row0], indptr[row1], ENTRIES_PER_CHUNK))
    bounds = np.unique(np.r_[row0, np.clip(cuts, row0, row1), row1])
    return list(zip(bounds[:-1], bounds[1:]))


def _column_sums(matrix: ChannelRows, weights: np.ndarray, row0: int, row1: int) -> np.ndarray:
    """(3, width): per channel c, Σ_o weights[o] A_c[o, :] over its rows o with c·T + o in row0..row1 - 1
    (the channels' rows one after another, as the split layout stores them), in float64 and in
    chunks of rows with about ENTRIES_PER_CHUNK entries within their channels' radii: the same
    chunks, so the same rounding, whichever the layout (a shared layout's 0.0 adds nothing).
    scipy's `matrix.T @ weights` would first copy a float32 matrix to float64."""
    t = matrix.rows
    out = np.zeros((3, matrix.width))
    for r0, r1 in _row_chunks(matrix.channel_ptr(), row0, row1):
        for c in range(r0 // t, -(-r1 // t)):  # the channels the chunk reaches
            a, b = max(r0 - c * t, 0), min(r1 - c * t, t)
            ptr, values = matrix.channel(c)
            lo, hi = ptr[a], ptr[b]
            w = np.repeat(weights[a:b], np.diff(ptr[a:b + 1]))
            out[c] += np.bincount(matrix.indices[lo:hi], weights=w * values[lo:hi], minlength=matrix.width)
    return out


@dataclass(frozen=True, eq=False)
class _Clusters:
    """One level's clusters, as its targets read them: centroid (3, m), area covariance spread
    (6, m: xx, yy, zz, xy, xz, yz) and its trace (m,), and per target cell the clusters it reads
    (`_lists`: ptr, lists)."""

    centroid: np.ndarray
    spread: np.ndarray
    trace: np.ndarray
    ptr: np.ndarray
    lists: np.ndarray

    @property
    def count(self) -> int:
        return self.centroid.shape[1]

    @staticmethod
    def build(x: np.ndarray, area: np.ndarray, nrm: np.ndarray, starts: np.ndarray, cell_of: np.ndarray,
              pairs: np.ndarray) -> "_Clusters":
        """`pairs` (p, 2) are the level's well-separated (target cell, source cell) pairs."""
        m = len(starts)
        cluster_area = np.add.reduceat(area, starts)
        safe = np.where(cluster_area > 0, cluster_area, 1.0)
        centroid = (np.add.reduceat(area[:, None] * x, starts, axis=0) / safe[:, None]).T.copy()  # (3, m)
        off = x.T - centroid[:, cell_of]
        products = np.stack([off[0] * off[0], off[1] * off[1], off[2] * off[2],
                             off[0] * off[1], off[0] * off[2], off[1] * off[2]])
        # Each vertex is a disc of its area in its tangent plane (as in the near pairs), of
        # covariance (a²/4)(I - n nᵀ) with a² = ΔA/π.
        nx, ny, nz = nrm.T
        disc = np.stack([1.0 - nx * nx, 1.0 - ny * ny, 1.0 - nz * nz, -nx * ny, -nx * nz, -ny * nz]) * (area / (4 * np.pi))
        spread = np.add.reduceat((products + disc) * area, starts, axis=1) / safe
        # Clusters without area gather nothing: leave them out.
        # int32: the plan keeps every level's lists until the build (cells are far fewer than 2^31)
        ptr, lists = _lists(pairs[cluster_area[pairs[:, 1]] > 0].astype(np.int32), m)
        return _Clusters(centroid, spread, spread[0] + spread[1] + spread[2], ptr, lists)


class _Builder:
    """Computes the matrices' entries (compiled, `scatter_kernels`) in blocks of rows, on `threads` threads."""

    def __init__(self, params: Profile, radius: np.ndarray, dtype, threads: int, field: NearField,
                 closest: float = 0.0):
        self.params, self.radius, self.dtype, self.threads, self.field = params, radius, dtype, threads, field
        self.positions_t = field.positions.T.copy()  # (3, n): the far entries read coordinates apart
        self.table = _KernelTable.build(params, closest, float(radius.max())) if closest > 0 else None

    def near(self, rows: np.ndarray, keys: np.ndarray, ptr: np.ndarray, lists: np.ndarray, ranges: np.ndarray,
             per_row: np.ndarray) -> ChannelRows:
        """T targets × n sources: ∫_{cell_i} Rd_c(|p - x_o|) dp (`NearField.weights`) for each target
        o = rows[j] and its sources i within the channel's radius.

        Row j's sources are the vertices ranges[g] .. ranges[g + 1] - 1 of each g in
        lists[ptr[keys[j]]:ptr[keys[j] + 1]], in that order; `per_row` (T,) counts them."""
        x, args = self.field.positions, self.field.kernel_args
        return self._assemble(
            per_row, len(x), 0,
            lambda j0, j1, counts: pair_counts(j0, j1, rows, keys, ptr, lists, ranges, x, x, self.radius, counts),
            lambda j0, j1, shared, indptr, indices, data: near_fill(
                j0, j1, rows, keys, ptr, lists, ranges, self.radius, *args, shared, indptr, indices, data))

    def far(self, clusters: "_Clusters", cell_of: np.ndarray, rows: np.ndarray) -> ChannelRows:
        """T targets × m clusters: each target's cluster kernel Rd_c(D) + ½ tr(H Σ) for the clusters
        its cell reads at this level; channel c's products read channel c's moments."""
        m, c, table = clusters.count, clusters, self.table
        keys = cell_of[rows]
        xt = self.positions_t
        centroids, each = np.ascontiguousarray(c.centroid.T), np.arange(m + 1)  # clusters as one-item ranges
        return self._assemble(
            c.ptr[keys + 1] - c.ptr[keys], m, m,
            lambda j0, j1, counts: pair_counts(j0, j1, rows, keys, c.ptr, c.lists, each, self.field.positions,
                                               centroids, self.radius, counts),
            lambda j0, j1, shared, indptr, indices, data: far_fill(
                j0, j1, rows, keys, c.ptr, c.lists, xt, c.centroid, c.spread, c.trace, self.radius, table.log_lo,
                table.step, table.value, table.slope, shared, indptr, indices, data))

    def _assemble(self, per_row: np.ndarray, width: int, stride: int, count, fill) -> ChannelRows:
        """The T targets' rows, built in blocks of rows of about ENTRIES_PER_CHUNK candidate
        pairs (`per_row` (T,) counts each row's): `count(j0, j1, counts)` writes each row's
        entries per channel and their union into counts (4, T), then `fill(j0, j1, shared,
        indptr, indices, data)` writes them in place in the layout that takes fewer bytes, so
        the arrays are allocated once at their final size."""
        t = len(per_row)
        cum = np.cumsum(per_row)
        bounds = np.unique(np.r_[0, np.searchsorted(cum, np.arange(ENTRIES_PER_CHUNK, cum[-1] if t else 0,
                                                                   ENTRIES_PER_CHUNK)), t])
        blocks = list(zip(bounds[:-1].tolist(), bounds[1:].tolist()))
        counts = np.zeros((4, t), dtype=np.int64)
        _run_all(lambda b: count(b[0], b[1], counts), blocks, self.threads)
        within, union = counts[:3], counts[3]
        shared = _shared_layout(t, int(union.sum()), int(within.sum()), width, np.dtype(self.dtype).itemsize)
        indptr = np.r_[0, np.cumsum(union if shared else within.ravel())]
        size = int(indptr[-1])
        index_dtype = _index_dtype(size, width)
        indices = np.empty(size, dtype=index_dtype)
        data = np.empty((size, 3) if shared else size, dtype=self.dtype)
        _run_all(lambda b: fill(b[0], b[1], shared, indptr, indices, data.reshape(-1)), blocks, self.threads)
        return ChannelRows(indptr.astype(index_dtype), indices, data, width, stride,
                           within.astype(np.int32) if shared else None)


def _index_dtype(size: int, width: int):
    """int32 where the entries and columns fit (half the bytes of int64)."""
    return np.int32 if max(size, width) < 2**31 else np.int64


def layout_bytes(shared: bool, rows: int, entries: int, width: int, itemsize: int) -> int:
    """Bytes of a `ChannelRows` of `rows` targets holding `entries` (the union of the channels'
    patterns where `shared`, else the channels' entries over the three), values of `itemsize`."""
    index = np.dtype(_index_dtype(entries, width)).itemsize
    if shared:
        return entries * (index + 3 * itemsize) + (rows + 1) * index + 3 * rows * 4  # `within` int32
    return entries * (index + itemsize) + (3 * rows + 1) * index


def _shared_layout(rows: int, union: int, within: int, width: int, itemsize: int) -> bool:
    """Whether the shared layout takes fewer bytes than the split one."""
    return layout_bytes(True, rows, union, width, itemsize) < layout_bytes(False, rows, within, width, itemsize)


@dataclass(frozen=True, eq=False)
class _KernelTable:
    """The far-field kernel Rd(D) + ½ tr(H Σ) = A(D) + B(D) ûᵀΣû + C(D) tr Σ per channel,
    tabulated on a log-spaced grid of D and interpolated linearly.

    With steps of `TABLE_STEP` in ln D the interpolation error is ~Δ²/8 |g''/g| ≈ 1e-7 (3 + σ_tr D)²
    relative: below 1e-5 for every preset, far below the clustering error (tests measure it).
    """

    log_lo: float
    step: float
    nodes: int
    value: np.ndarray  # (3 channels, 3 terms, nodes)
    slope: np.ndarray  # value[..., i + 1] - value[..., i]

    @staticmethod
    def build(params: Profile, lo: float, hi: float) -> "_KernelTable":
        span = max(np.log(max(hi, lo) / lo), TABLE_STEP)
        nodes = int(np.ceil(span / TABLE_STEP)) + 2
        d = lo * np.exp(np.linspace(0.0, span, nodes))
        value = np.empty((3, 3, nodes))
        for c in range(3):
            f, f1, f2 = profile_derivatives(d, params, c)
            # ½ tr(H Σ) for a radial function: H = f'' ûûᵀ + (f'/D)(I - ûûᵀ).
            value[c] = f, 0.5 * (f2 - f1 / d), 0.5 * f1 / d
        slope = np.diff(value, axis=2, append=value[..., -1:])
        return _KernelTable(float(np.log(lo)), span / (nodes - 1), nodes, value, slope)


def _run_all(fn, items: list, threads: int) -> list:
    if threads > 1 and len(items) > 1:
        with ThreadPoolExecutor(min(threads, len(items))) as pool:
            return list(pool.map(fn, items))
    return [fn(item) for item in items]


def _runs(sorted_keys: np.ndarray) -> np.ndarray:
    """Index of the run of equal values each element of a sorted array belongs to."""
    return np.cumsum(np.r_[False, sorted_keys[1:] != sorted_keys[:-1]])


def _near_cell_pairs(coords: np.ndarray, a: int) -> np.ndarray:
    """(p, 2) all pairs of cells within `a` cells of each other per axis (both orders, self included).

    `coords` (m, 3) must be in Morton order, as the cells of `scatter_operator` are.
    """
    keys = morton_codes(coords)
    span = np.arange(-a, a + 1)
    out = []
    for off in np.stack(np.meshgrid(span, span, span, indexing="ij"), -1).reshape(-1, 3):
        shifted = coords + off
        ok = np.flatnonzero((shifted >= 0).all(axis=1))
        k = morton_codes(shifted[ok])
        pos = np.minimum(np.searchsorted(keys, k), len(keys) - 1)
        hit = keys[pos] == k
        out.append(np.column_stack([ok[hit], pos[hit]]))
    return np.concatenate(out)


def _lists(pairs: np.ndarray, m: int) -> tuple[np.ndarray, np.ndarray]:
    """Pairs (t, s) as per-t lists: (ptr (m + 1,), items) with t's items at items[ptr[t]:ptr[t+1]]."""
    by_t = np.argsort(pairs[:, 0], kind="stable")
    return np.r_[0, np.cumsum(np.bincount(pairs[:, 0], minlength=m))], pairs[by_t, 1]
