"""The diffuse-scattering gather over a surface as a sparse linear operator.

For signals E (n, K) at the surface vertices (irradiance of K lights, say), per colour channel c::

    q_c[o, :] = Σ_i Rd_c(|x_i - x_o|) ΔA_i E[i, :]

with the vertex's own area integrated exactly (`dipole.disc_integral` over a disc of area ΔA_o)
and sources beyond the energy radius R dropped (at most `energy_dropped` of R_d on a plane).

Not O(N²): sources near a target are summed exactly; farther ones through nested voxel-grid
clusters (cell size h_0·2^l), FMM style. Two cells of one level are *near* when their integer
coordinates differ by at most `separation` in every axis. A target cell t and a source cell s of
level l interact cluster to cluster when they are not near but their parents are; pairs near at
level 0 are summed vertex by vertex. Each (target, source) vertex pair is thereby counted exactly
once. An interaction is a first-order Taylor expansion about both area-weighted centroids:
the source's moments Σ ΔA_i E_i and Σ ΔA_i E_i (y_i - ȳ) (E varying across a cluster, n·ω on a
curved surface, would otherwise cost ~3% rms on the armadillo), evaluated as a value and gradient
at the target centroid and spread to its vertices, plus ½ tr(H (Σ_s + Σ_t)) with Σ the clusters'
area covariances and H the kernel's Hessian. The error is second order in cell size / distance.

Far-field entries are stored as float32: they approximate to ~1e-3 anyway, and float64 would
double the operator's memory (150k vertices: ~1 GB of far entries in float32).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp

from .dipole import DipoleParams, disc_integral, radius_for_energy


@dataclass(frozen=True)
class ScatterOptions:
    """Knobs of the hierarchical gather.

    Attributes
    ----------
    energy_dropped : float
        Fraction of the total diffuse reflectance R_d a source may lose to the truncation radius.
    separation : int
        Cells within this many cells (per axis) of each other are near; larger is more accurate
        and costs ~(4s+3)² - (2s+1)² cluster entries per vertex and level.
    vertices_per_cell : float
        Sets the finest cell size h_0 = sqrt(vertices_per_cell · area / n).
    hierarchy : bool
        False sums every pair within the radius exactly (O(N·neighbours); for tests and references).
    """

    energy_dropped: float = 1e-2
    separation: int = 2
    vertices_per_cell: float = 0.5
    hierarchy: bool = True


SCATTER_DEFAULTS = ScatterOptions()


@dataclass(frozen=True, eq=False)
class ScatterOperator:
    """The precomputed gather. Apply it with `apply`.

    Attributes
    ----------
    near : scipy.sparse.csr_matrix (n, n)
        Sparsity of the exact pairs; ``near_values[c]`` are its entries for channel c
        (Rd ΔA_i, the self term on the diagonal).
    near_values : (3, nnz) float64
    far : list of FarLevel
        Per level of the hierarchy, the cluster-to-cluster terms.
    radius_mm : (3,) float64
        Truncation radius per channel.
    dropped_fraction : (3,) float64
        Fraction of R_d beyond `radius_mm` (<= energy_dropped).
    stats : dict
        Cell size, levels, entries per level, build seconds.
    """

    near: sp.csr_matrix
    near_values: np.ndarray
    far: list = field(default_factory=list)
    radius_mm: np.ndarray = field(default_factory=lambda: np.zeros(3))
    dropped_fraction: np.ndarray = field(default_factory=lambda: np.zeros(3))
    stats: dict = field(default_factory=dict)

    @property
    def nnz(self) -> int:
        """Stored pair entries (near pairs plus target-cluster pairs)."""
        return self.near.nnz + sum(f.pattern.nnz for f in self.far)

    @property
    def nbytes(self) -> int:
        total = self.near.indices.nbytes + self.near.indptr.nbytes + self.near_values.nbytes
        for f in self.far:
            total += sum(a.nbytes for a in (f.pattern.indices, f.pattern.indptr, f.value, f.slope, f.unit,
                                            f.aggregate.data, f.aggregate.indices, f.offsets))
        return total

    def apply(self, signal: np.ndarray) -> np.ndarray:
        """(n, K) float64 signals -> (3, n, K) float64 gathered values."""
        signal = np.asarray(signal, dtype=np.float64)
        if signal.ndim != 2 or signal.shape[0] != self.near.shape[0]:
            raise ValueError(f"scatter: signal must be ({self.near.shape[0]}, K), got {signal.shape}")
        out = np.empty((3,) + signal.shape)
        for c in range(3):
            out[c] = _with_data(self.near, self.near_values[c]) @ signal
        for f in self.far:
            # Source moments per cluster: Σ ΔA E and Σ ΔA E (x_i - x̄).
            moment0 = f.aggregate @ signal
            moment1 = [f.aggregate @ (signal * f.offsets[:, k:k + 1]) for k in range(3)]
            for c in range(3):
                # Local expansion at each target cluster: value and gradient at its centroid.
                local = _with_data(f.pattern, f.value[c]) @ moment0
                gradient = 0.0
                for k in range(3):
                    g = _with_data(f.pattern, f.slope[c] * f.unit[k])  # Rd'(D) R̂_k
                    local -= g @ moment1[k]        # ∇_y Rd(|x - y|) = -Rd' R̂ at the source
                    gradient = gradient + (g @ moment0)[f.cell] * f.offsets[:, k:k + 1]  # ∇_x = +Rd' R̂
                out[c] += local[f.cell] + gradient
        # First-order terms can dip a hair below zero where a cluster's signal ends; q cannot.
        np.maximum(out, 0.0, out=out)
        return out


@dataclass(frozen=True, eq=False)
class FarLevel:
    """One hierarchy level's cluster terms.

    Attributes
    ----------
    pattern : csr_matrix (m, m)
        Which source clusters each target cluster reads (values unused).
    value : (3, nnz) float32
        Rd(D) plus the spread terms of both clusters, per channel (D = |x̄_t - x̄_s|).
    slope : (3, nnz) float32
        Rd'(D) per channel.
    unit : (3, nnz) float32
        R̂ = (x̄_t - x̄_s) / D.
    aggregate : csr_matrix (m, n)
        Vertex areas ΔA_i summed into clusters.
    offsets : (n, 3) float64
        x_i - x̄ of each vertex's cluster.
    cell : (n,) int64
        Each vertex's cluster.
    """

    pattern: sp.csr_matrix
    value: np.ndarray
    slope: np.ndarray
    unit: np.ndarray
    aggregate: sp.csr_matrix
    offsets: np.ndarray
    cell: np.ndarray


def scatter_operator(positions_mm: np.ndarray, areas_mm2: np.ndarray, params: DipoleParams,
                     options: ScatterOptions = SCATTER_DEFAULTS) -> ScatterOperator:
    """Build the gather for a surface.

    Parameters
    ----------
    positions_mm : (n, 3) float64
        Vertex positions in millimetres.
    areas_mm2 : (n,) float64
        Area of each vertex (a third of its triangles), mm².
    params : DipoleParams
    options : ScatterOptions

    Returns
    -------
    ScatterOperator
    """
    t0 = time.perf_counter()
    x = np.asarray(positions_mm, dtype=np.float64)
    area = np.asarray(areas_mm2, dtype=np.float64)
    n = len(x)
    if x.ndim != 2 or x.shape[1] != 3 or area.shape != (n,) or n == 0:
        raise ValueError(f"scatter: need positions (n, 3) and areas (n,), got {x.shape} and {area.shape}")
    if not (np.all(np.isfinite(x)) and np.all(np.isfinite(area)) and np.all(area >= 0)):
        raise ValueError("scatter: positions and areas must be finite, areas >= 0")
    if not 0.0 < options.energy_dropped < 1.0:
        raise ValueError(f"scatter: energy_dropped must be in (0, 1), got {options.energy_dropped}")
    if options.separation < 1 or options.vertices_per_cell <= 0:
        raise ValueError("scatter: separation must be >= 1 and vertices_per_cell > 0")

    radius = radius_for_energy(options.energy_dropped, params)
    total = 0.5 * params.alpha_prime * (np.exp(-params.sigma_tr * params.z_r) + np.exp(-params.sigma_tr * params.z_v))
    dropped = np.where(total > 0, 1.0 - np.diagonal(disc_integral(radius, params)) / np.where(total > 0, total, 1), 0.0)
    r_max = float(radius.max())
    stats: dict = {"radius_mm": radius.tolist()}

    if not options.hierarchy:
        rows, cols = _pairs_within(x, r_max)
        near, values = _near_matrix(x, area, rows, cols, n, params, radius)
        stats.update(levels=0, near_nnz=near.nnz, seconds=time.perf_counter() - t0)
        return ScatterOperator(near, values, [], radius, np.clip(dropped, 0.0, 1.0), stats)

    surface_area = max(float(area.sum()), 1e-300)
    h0 = min(np.sqrt(options.vertices_per_cell * surface_area / n), r_max)
    a = options.separation
    # Above the level whose near pairs cover the radius (or the whole object) nothing is far.
    reach = min(r_max, float(np.linalg.norm(np.ptp(x, axis=0))) + h0)
    top = max(0, int(np.ceil(np.log2(max(reach / (a * h0), 1.0)))))
    origin = x.min(axis=0)
    cells = [_cells(x, origin, h0 * 2.0**level) for level in range(top + 1)]

    # Start: near pairs among the top level's cells; farther cells are beyond the radius.
    pairs = _near_cell_pairs(cells[top][1], a)
    far = []
    far_counts = []
    for level in range(top, -1, -1):
        ids, coords = cells[level]
        if level < top:
            pairs = _children_pairs(pairs, cells[level + 1][0], ids)
            diff = np.abs(coords[pairs[:, 0]] - coords[pairs[:, 1]]).max(axis=1)
            interacting = pairs[diff > a]
            pairs = pairs[diff <= a]
            if len(interacting):
                far.append(_far_level(x, area, ids, interacting, params, radius))
                far_counts.append(far[-1].pattern.nnz)
    # Pairs still near at level 0: every vertex pair, exactly.
    rows, cols = _expand_to_vertices(pairs, cells[0][0])
    keep = np.einsum("ij,ij->i", x[rows] - x[cols], x[rows] - x[cols]) <= r_max * r_max
    near, values = _near_matrix(x, area, rows[keep], cols[keep], n, params, radius)
    stats.update(cell_mm=h0, levels=top + 1, separation=a, near_nnz=near.nnz, far_nnz=far_counts,
                 seconds=time.perf_counter() - t0)
    return ScatterOperator(near, values, far, radius, np.clip(dropped, 0.0, 1.0), stats)


def _with_data(m: sp.csr_matrix, data: np.ndarray) -> sp.csr_matrix:
    return sp.csr_matrix((data, m.indices, m.indptr), shape=m.shape)


def _cells(x: np.ndarray, origin: np.ndarray, h: float) -> tuple[np.ndarray, np.ndarray]:
    """Per vertex its cell id at cell size h, and per cell its integer coordinates (m, 3)."""
    coords = np.floor((x - origin) / h).astype(np.int64)
    unique, ids = np.unique(coords, axis=0, return_inverse=True)
    return ids.reshape(-1), unique


def _key(coords: np.ndarray) -> np.ndarray:
    # Coordinates are offset so they are non-negative and below 2^20 per axis.
    c = coords + 2
    return (c[:, 0] << 42) | (c[:, 1] << 21) | c[:, 2]


def _near_cell_pairs(coords: np.ndarray, a: int) -> np.ndarray:
    """(p, 2) all pairs of occupied cells within `a` cells of each other (both orders, self included)."""
    keys = _key(coords)
    order = np.argsort(keys)
    sorted_keys = keys[order]
    span = np.arange(-a, a + 1)
    offsets = np.stack(np.meshgrid(span, span, span, indexing="ij"), -1).reshape(-1, 3)
    out = []
    for off in offsets:
        k = _key(coords + off)
        pos = np.clip(np.searchsorted(sorted_keys, k), 0, len(keys) - 1)
        hit = sorted_keys[pos] == k
        out.append(np.column_stack([np.flatnonzero(hit), order[pos[hit]]]))
    return np.concatenate(out)


def _children_pairs(parent_pairs: np.ndarray, parent_of_vertex: np.ndarray, child_of_vertex: np.ndarray) -> np.ndarray:
    """All (child of t, child of s) for the parent pairs (t, s)."""
    parent_of_child = np.empty(child_of_vertex.max() + 1, dtype=np.int64)
    parent_of_child[child_of_vertex] = parent_of_vertex
    return np.column_stack(_expand_to_vertices(parent_pairs, parent_of_child))


def _expand_to_vertices(cell_pairs: np.ndarray, cell_of_vertex: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """All (member of t, member of s) for group pairs (t, s), members given by their group."""
    order = np.argsort(cell_of_vertex, kind="stable")
    starts = np.searchsorted(cell_of_vertex[order], np.arange(cell_of_vertex.max() + 2))
    count = np.diff(starts)
    t, s = cell_pairs[:, 0], cell_pairs[:, 1]
    per_pair = count[t] * count[s]
    pair = np.repeat(np.arange(len(cell_pairs)), per_pair)
    local = np.arange(per_pair.sum()) - np.repeat(np.cumsum(per_pair) - per_pair, per_pair)
    rows = order[starts[t[pair]] + local // count[s[pair]]]
    cols = order[starts[s[pair]] + local % count[s[pair]]]
    return rows, cols


def _pairs_within(x: np.ndarray, r: float) -> tuple[np.ndarray, np.ndarray]:
    from scipy.spatial import cKDTree

    tree = cKDTree(x)
    pairs = tree.query_pairs(r, output_type="ndarray")
    n = len(x)
    rows = np.concatenate([pairs[:, 0], pairs[:, 1], np.arange(n)])
    cols = np.concatenate([pairs[:, 1], pairs[:, 0], np.arange(n)])
    return rows, cols


def _near_matrix(x, area, rows, cols, n, params: DipoleParams, radius) -> tuple[sp.csr_matrix, np.ndarray]:
    """Exact pair entries Rd(|x_o - x_i|) ΔA_i, the exact disc integral on the diagonal."""
    matrix = sp.csr_matrix((np.arange(len(rows), dtype=np.float64) + 1, (rows, cols)), shape=(n, n))
    matrix.sum_duplicates()
    where = matrix.data.astype(np.int64) - 1  # entry -> its pair, in CSR order
    r_idx, c_idx = rows[where], cols[where]
    d = np.sqrt(np.einsum("ij,ij->i", x[r_idx] - x[c_idx], x[r_idx] - x[c_idx]))
    values = np.empty((3, len(where)))
    own = r_idx == c_idx
    disc = disc_integral(np.sqrt(area[r_idx[own]] / np.pi), params)  # (m, 3)
    for c in range(3):
        rd = _profile(d, params, c) * area[c_idx]
        rd[d > radius[c]] = 0.0
        rd[own] = disc[:, c]
        values[c] = rd
    return matrix, values


def _far_level(x, area, cell_of_vertex, pairs, params: DipoleParams, radius):
    """Cluster-to-cluster terms of one level for the interacting cell pairs (target t, source s)."""
    m = cell_of_vertex.max() + 1
    n = len(x)
    aggregate = sp.csr_matrix((area, (cell_of_vertex, np.arange(n))), shape=(m, n))
    cluster_area = np.asarray(aggregate.sum(axis=1)).ravel()
    safe = np.where(cluster_area > 0, cluster_area, 1.0)
    centroid = (aggregate @ x) / safe[:, None]
    # Area-weighted covariance of each cluster (its spread about the centroid).
    offsets = x - centroid[cell_of_vertex]
    outer = np.einsum("ij,ik->ijk", offsets, offsets).reshape(n, 9)
    spread = (aggregate @ outer).reshape(m, 3, 3) / safe[:, None, None]

    matrix = sp.csr_matrix((np.arange(len(pairs), dtype=np.float64) + 1, (pairs[:, 0], pairs[:, 1])), shape=(m, m))
    where = matrix.data.astype(np.int64) - 1
    t_idx, s_idx = pairs[where, 0], pairs[where, 1]
    delta = centroid[t_idx] - centroid[s_idx]
    d = np.sqrt(np.einsum("ij,ij->i", delta, delta))
    unit = delta / np.maximum(d, 1e-300)[:, None]
    # Both clusters' spreads: the source's averages the kernel over its vertices, the target's
    # is the mean of the quadratic term its vertices would see.
    both = spread[s_idx] + spread[t_idx]
    radial = np.einsum("ij,ijk,ik->i", unit, both, unit)
    trace = np.trace(both, axis1=1, axis2=2)
    value = np.empty((3, len(where)), dtype=np.float32)
    slope = np.empty((3, len(where)), dtype=np.float32)
    for c in range(3):
        f, f1, f2 = _profile_derivatives(d, params, c)
        # ½ tr(H Σ) for a radial function: H = f'' r̂r̂ᵀ + (f'/r)(I - r̂r̂ᵀ).
        v = f + 0.5 * (f2 * radial + f1 / np.maximum(d, 1e-300) * (trace - radial))
        beyond = d > radius[c]
        v[beyond] = 0.0
        f1[beyond] = 0.0
        value[c] = v
        slope[c] = f1
    matrix.data = np.ones_like(matrix.data)
    return FarLevel(matrix, value, slope, unit.T.astype(np.float32), aggregate, offsets, cell_of_vertex)


def _profile(r: np.ndarray, p: DipoleParams, c: int) -> np.ndarray:
    return _profile_derivatives(r, p, c)[0]


def _profile_derivatives(r: np.ndarray, p: DipoleParams, c: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rd_c(r) and its first and second derivatives in r (per channel c)."""
    s = p.sigma_tr[c]
    f = np.zeros_like(r)
    f1 = np.zeros_like(r)
    f2 = np.zeros_like(r)
    for z in (p.z_r[c], p.z_v[c]):
        d2 = r * r + z * z
        d = np.sqrt(d2)
        e = np.exp(-s * d)
        g = (1.0 + s * d) * e / (d2 * d)
        # dg/dd = -e (s²d² + 3sd + 3) / d⁴ ; d²g/dd² = e (s³d³ + 5s²d² + 12sd + 12) / d⁵
        g1 = -e * (s * s * d2 + 3.0 * s * d + 3.0) / (d2 * d2)
        g2 = e * (s**3 * d2 * d + 5.0 * s * s * d2 + 12.0 * s * d + 12.0) / (d2 * d2 * d)
        # chain rule with d(d)/dr = r/d, d²(d)/dr² = z²/d³
        f += z * g
        f1 += z * g1 * r / d
        f2 += z * (g2 * (r / d) ** 2 + g1 * z * z / (d2 * d))
    k = p.alpha_prime[c] / (4.0 * np.pi)
    return k * f, k * f1, k * f2
