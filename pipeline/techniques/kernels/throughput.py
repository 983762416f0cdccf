"""Vertex-to-vertex throughput factors of the kernels technique's global response (Lensch et al.
2002, §5.2): ``F_ij ≈ (A_i / 3) Rd(|v_i - v_j|)``, what source vertex i's hat coefficient of
irradiance sends to receiver vertex j, with entries below a threshold dropped.

The paper's point rule is kept where it is accurate; for vertex pairs close compared with their
cells (`CLOSE`, and F_ii) the entry is ∫_{cell_i} Rd(|p - v_j|) dp (`near_field.NearField`), because
the point rule's error there does not vanish with finer atlases: on a plane of 1 mm spacing in
skin1, Σ_i (A_i / 3) Rd(|v_i - v_j|) overestimates R_d by 4 % (red) to 22 % (blue, z_r = 0.67 mm),
while the cells' integrals tile the plane and sum to R_d.

The threshold is on the largest channel of an entry, so all three channels share one sparsity
pattern. Pairs are found per chunk of receivers with a k-d tree over a radius that bounds every
kept entry (Rd falls monotonically with distance), so no dense N × N matrix is ever formed.

With a per-source entry bound (`strongest_per_source`, the budget that bounds F's bytes) each
source keeps only its largest entries, scaled per channel so that it still sends what all of its
entries sent (the light a source sends is kept; where it lands moves towards the source). The
build then holds only the candidates for those entries (`_source_cuts`), never all of F.
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from sssbake.pipeline.core.profile import Profile, diffuse_reflectance_profile, profile_total
from sssbake.pipeline.core.integer_keys import argsort_keys
from sssbake.pipeline.core.near_field import NearField
from sssbake.pipeline.core.profile_table import ProfileTable

#: Pairs closer than this many times the sum of their cells' radii get the cell integral; beyond,
#: the point rule errs by about (a² / 8)(9 / d² + σ_tr²) relative: below 1 % here.
CLOSE = 6.0
#: Receivers per chunk of the pair search (bounds the chunk's pair arrays).
CHUNK = 1024
#: Entries F may hold (16 bytes each as stored): 100M is 1.6 GB.
MAX_ENTRIES = 100_000_000
#: Receivers sampled to predict F's size before building it.
SAMPLE = 400
THREADS = 2


@dataclass(frozen=True, eq=False)
class Throughput:
    """F as CSR by receiver.

    Attributes
    ----------
    indptr : (n + 1,) int64
    indices : (nnz,) int64
        Source vertex of each entry, increasing within a row.
    values : (nnz, 3) float32
    sent : (3,) float64
        Σ_ij F_ij (A_j / 3) / (R_d Σ_i A_i / 3) per channel: what F carries, relative to what
        the sources would send out over an infinite plane (the diagonal, the threshold and the
        object's finite extent all lower it).
    moved : float
        Share of the carried light (summed over channels) that the per-source bound moved from the
        dropped entries onto the kept ones of the same source (0 without a bound).
    radius_mm : float
        The search radius: no entry farther apart reaches the threshold.
    field : NearField
        The cells' integrals of close pairs.
    table : ProfileTable
        The Rd of the other pairs (`throughput_values` with both gives the values again).
    """

    indptr: np.ndarray
    indices: np.ndarray
    values: np.ndarray
    sent: np.ndarray
    radius_mm: float
    field: NearField
    table: ProfileTable
    moved: float = 0.0

    @property
    def nnz(self) -> int:
        return int(len(self.indices))


def throughput_values(field: NearField, table: ProfileTable, threshold: float, sources: np.ndarray,
                      receivers: np.ndarray, diagonal: bool = False, d2: np.ndarray | None = None) -> np.ndarray:
    """F for given pairs, with the same rules as `throughput_matrix`.

    Parameters
    ----------
    field : NearField
        Positions (mm), cells and the close-pair integrals of the surface.
    table : ProfileTable
        The material's Rd, for the pairs where a point value is accurate.
    threshold : float
    sources, receivers : (m,) int64
    diagonal : bool
        Keep i == j entries (the cell's own integral); else they are 0.
    d2 : (m,) float64, optional
        The pairs' squared distances when the caller has them (a pair search does).

    Returns
    -------
    (m, 3) float64
    """
    if d2 is None:
        delta = field.positions[sources] - field.positions[receivers]
        d2 = np.einsum("ij,ij->i", delta, delta)
    radius = np.sqrt(field.area / np.pi)
    close = np.flatnonzero(d2 < (CLOSE * (radius[sources] + radius[receivers])) ** 2)
    value = table(d2)
    value *= field.area[sources, None]
    if len(close):
        value[close] = field.weights(receivers[close], sources[close])
    keep = np.maximum(np.maximum(value[:, 0], value[:, 1]), value[:, 2]) >= threshold
    if not diagonal:
        keep &= sources != receivers
    value *= keep[:, None]  # cheaper than a masked assignment of the dropped rows
    return value


def throughput_matrix(positions_mm: np.ndarray, faces: np.ndarray, normals: np.ndarray, params: Profile,
                      threshold: float, diagonal: bool = False, max_entries: int = MAX_ENTRIES,
                      per_source: int = 0, beyond_mm: float = 0.0, whole_entries: int = 0) -> Throughput:
    """All entries of F at or above `threshold` (see the module docstring).

    Parameters
    ----------
    positions_mm : (n, 3) float64
    faces : (m, 3) int64
    normals : (n, 3) float64
        Unit vertex normals.
    params : Profile
    threshold : float
        Entries whose largest channel is below it are dropped.
    diagonal : bool
        Keep F_ii (the unblended technique); the blended one zeroes them.
    max_entries : int
        Refuse (ValueError naming the fix) when a sample of receivers predicts more entries.
    per_source : int
        Keep at most this many entries per source (`strongest_per_source`); 0: all.
    beyond_mm : float
        With `per_source`: only entries whose receiver lies farther than this from the source are
        kept, and only their light is renormalised onto the kept ones (the kernels' window, where
        the blended kernels give the true response whatever F holds).
    whole_entries : int
        With `per_source`: F keeps all its entries, exactly as with `per_source` 0, where they number
        at most this many (built whole where a sample of receivers predicts so); 0: never.
    """
    field = NearField.build(positions_mm, faces, normals, params)
    x, cell = field.positions, field.area
    n = len(x)
    if not (np.isfinite(threshold) and threshold > 0):
        raise ValueError(f"throughput: threshold must be a positive number, got {threshold}")
    radius = search_radius(float(cell.max()) if n else 0.0, params, threshold)
    table = ProfileTable.build(params, radius)
    # Sources grouped by how far they reach (their cells differ): each group is searched only
    # as far as its own largest cell reaches, not as far as the mesh's largest.
    classes = _cell_classes(cell)
    reach = np.array([search_radius(float(c), params, threshold) for c in classes])
    group = np.searchsorted(classes, cell)
    groups = [(np.flatnonzero(group == g), reach[g]) for g in range(len(reach)) if np.any(group == g)]
    trees = [(members, cKDTree(x[members]), r) for members, r in groups]
    # the bound costs accuracy (light moved towards its source), so it applies only where F overflows
    if per_source and whole_entries and _estimated_entries(x, trees, field, table, threshold,
                                                           diagonal) <= whole_entries:
        whole = throughput_matrix(positions_mm, faces, normals, params, threshold, diagonal, max_entries)
        if whole.nnz <= whole_entries:
            return whole
    # with a bound only candidates of each source's strongest entries are held (`_source_cuts`)
    cut = _source_cuts(x, field, table, threshold, diagonal, per_source, beyond_mm) if per_source else None
    estimate = 0.0 if per_source else _estimated_entries(x, trees, field, table, threshold, diagonal)
    if estimate > max_entries:
        raise ValueError(f"kernels: F would hold ~{estimate / 1e6:.0f}M entries ({estimate * 16 / 2**30:.1f} GB) at "
                         f"threshold {threshold:g}; bound it (--kernels-f-bytes, 64 by default), raise the threshold "
                         "(--kernels-threshold) or simplify the mesh")

    # Each source's cell bounds its point-rule value, so the candidates (searched as far as the
    # source's class reaches) that fall short of the threshold are dropped before the sort and the
    # values: about 30 % of them on the dragon.
    # (the margin covers the rounding of the table's interpolation and of value · cell >= threshold)
    node_limit = _node_limits(table, threshold * (1.0 - 1e-9) / np.maximum(cell, 1e-300))
    cell_radius = np.sqrt(cell / np.pi)

    def rows(start: int):
        stop = min(n, start + CHUNK)
        receiver, source, d2 = _candidates(x[start:stop], trees)
        live = np.flatnonzero(_may_reach(table, node_limit, cell_radius, source, receiver + start, d2))
        receiver, source, d2 = receiver[live], source[live], d2[live]
        # pairs in CSR order before their values, so that only the pairs' small arrays are permuted
        order = argsort_keys(receiver * n + source, (stop - start) * n)
        receiver, source, d2 = receiver[order] + start, source[order], d2[order]
        value = throughput_values(field, table, threshold, source, receiver, diagonal, d2)
        keep = value[:, 0] + value[:, 1] + value[:, 2] > 0
        if per_source and beyond_mm > 0:  # inside the kernels' window their light replaces F's
            keep &= d2 > beyond_mm * beyond_mm
        # what each source sends with all its entries (the bound's renormalisation), then its candidates
        energy = value * (cell[receiver] * keep)[:, None]
        sends = (np.stack([np.bincount(source, weights=energy[:, c], minlength=n) for c in range(3)], axis=1)
                 if per_source else None)
        if per_source:
            keep &= value.max(axis=1) >= cut[source]
        return (np.bincount(receiver[keep] - start, minlength=stop - start), source[keep],
                value[keep].astype(np.float32), cell[receiver] @ value, sends)

    with ThreadPoolExecutor(THREADS) as pool:
        counts, indices, values, sent, sends = (zip(*pool.map(rows, range(0, n, CHUNK))) if n
                                                else ([], [], [], [], []))
    # one field at a time, each chunk's copy dropped once joined: the peak holds F once and one field twice
    indptr = np.r_[0, np.cumsum(np.concatenate(counts) if n else np.zeros(0, np.int64))].astype(np.int64)
    values = np.concatenate(values) if n else np.zeros((0, 3), np.float32)
    indices = np.concatenate(indices) if n else np.zeros(0, np.int64)
    sent = np.sum(sent, axis=0) if n else np.zeros(3)
    total = profile_total(params) * max(float(cell.sum()), 1e-300)
    moved = 0.0
    if per_source and n:
        indptr, indices, values, moved = strongest_per_source(indptr, indices, values, cell, per_source,
                                                              np.sum(sends, axis=0))
    return Throughput(indptr, indices, values, sent / total, radius, field, table, moved)


def strongest_per_source(indptr: np.ndarray, indices: np.ndarray, values: np.ndarray, cell: np.ndarray, keep: int,
                         sends: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """F with at most `keep` entries per source (column): its largest by the largest channel, each
    channel of a source's kept entries scaled so that it sends ``Σ_j F_ij A_j`` as before.

    Parameters
    ----------
    indptr : (n + 1,) int64
    indices : (nnz,) int64
    values : (nnz, 3) float32
        F as CSR by receiver, sources increasing within a row.
    cell : (n,) float64
        The receivers' cell areas A_j (what each receiver's radiosity stands for).
    keep : int
        >= 1.
    sends : (n, 3) float64, optional
        ``Σ_j F_ij A_j`` per source over all of F, where `values` hold only some of its entries
        (those that may be among each source's strongest); by default the sums of `values`.

    Returns
    -------
    indptr, indices, values
        The bounded F, same layout.
    moved : float
        The share of Σ_ij F_ij A_j (all channels) that had to move onto the kept entries.
    """
    n = len(indptr) - 1
    receiver = np.repeat(np.arange(n, dtype=np.int64), np.diff(indptr))
    strength = values.max(axis=1)
    # by source, then strongest first: an entry's rank within its source is its place in the run
    # (np.lexsort's order: stable by strength, then a stable radix sort by source, ~40 % faster)
    by_strength = np.argsort(-strength, kind="stable")
    order = by_strength[argsort_keys(indices[by_strength], n)]
    runs = np.bincount(indices, minlength=n)
    rank = np.arange(len(order)) - np.repeat(np.cumsum(runs) - runs, runs)
    kept = np.zeros(len(order), dtype=bool)
    kept[order[rank < keep]] = True
    energy = values.astype(np.float64) * cell[receiver, None]
    before = (np.stack([np.bincount(indices, weights=energy[:, c], minlength=n) for c in range(3)], axis=1)
              if sends is None else sends)
    after = np.stack([np.bincount(indices[kept], weights=energy[kept, c], minlength=n) for c in range(3)], axis=1)
    # every source keeps its strongest entry, so `after` is 0 only where `before` is
    scale = np.divide(before, after, out=np.ones_like(before), where=after > 0)
    out = (values[kept] * scale[indices[kept]]).astype(np.float32)
    moved = float((before.sum() - after.sum()) / max(before.sum(), 1e-300))
    counts = np.bincount(receiver[kept], minlength=n)
    return np.r_[0, np.cumsum(counts)].astype(np.int64), indices[kept], out, moved


def _source_cuts(x: np.ndarray, field: NearField, table: ProfileTable, threshold: float, diagonal: bool,
                 keep: int, beyond_mm: float) -> np.ndarray:
    """(n,) a strength (largest channel) below which an entry cannot be among its source's `keep`
    strongest: half the weakest of the `keep` strongest of its entries to its nearest receivers
    farther than `beyond_mm`. Those are `keep` entries at least that strong, so the `keep`-th
    strongest of all is too, whichever they are (the half is a margin for rounding only; the
    nearest are simply where strong entries are: ``A_i Rd(d)`` falls with distance). All 0 when
    the mesh has too few vertices."""
    n, tree = len(x), cKDTree(x)
    inside = (tree.query_ball_point(x, beyond_mm, return_length=True, workers=THREADS) if beyond_mm > 0
              else np.ones(n, int))
    wanted = keep + int(inside.max())  # the source itself is inside (distance 0)
    if n < wanted:
        return np.zeros(n)
    d, near = tree.query(x, k=wanted, workers=THREADS)
    d, near = d.reshape(n, wanted), near.reshape(n, wanted)

    def cuts(start: int) -> np.ndarray:  # per chunk of sources, on threads as the rows of F are
        own = np.arange(start, min(n, start + CHUNK))
        strength = throughput_values(field, table, threshold, np.repeat(own, wanted), near[own].reshape(-1),
                                     diagonal).max(axis=1)
        strength = np.where((d[own] > beyond_mm) & (near[own] != own[:, None]), strength.reshape(-1, wanted), 0.0)
        return 0.5 * np.sort(strength, axis=1)[:, -keep]  # the weakest of the `keep` strongest found

    with ThreadPoolExecutor(THREADS) as pool:
        return np.concatenate(list(pool.map(cuts, range(0, n, CHUNK))))


def _cell_classes(cell: np.ndarray) -> np.ndarray:
    """Upper cell sizes of the source groups: the median, 90th, 99th percentile and the largest."""
    return np.unique(np.percentile(cell, [50, 90, 99, 100])) if len(cell) else np.zeros(1)


def _node_limits(table: ProfileTable, limit: np.ndarray) -> np.ndarray:
    """(n,) int64: for each source, the first table node from which on the table's Rd stays below
    its `limit` (Rd level the source's cell must reach for its point value to be kept) in every
    channel; the table's node count where it never does.

    Between nodes j and j + 1 the table interpolates linearly, so beyond node J every interpolated
    value is at most the largest node value from J on (a suffix maximum: no monotony assumed).
    """
    peak = table.values.max(axis=0)
    suffix = np.maximum.accumulate(peak[::-1])[::-1]  # non-increasing
    # first J with suffix[J] < limit: suffix is non-increasing, so search its negation
    return np.searchsorted(-suffix, -limit, side="right").astype(np.int64)


def _may_reach(table: ProfileTable, node_limit: np.ndarray, radius: np.ndarray, source: np.ndarray,
               receiver: np.ndarray, d2: np.ndarray) -> np.ndarray:
    """(m,) bool: the candidate pairs (source, receiver vertex, squared distance d2 in mm²) whose F
    entry may reach the threshold: the close pairs of `throughput_values` (`radius`: (n,) the cells'
    disc radii, mm; their cell integral is not bounded here), those whose table node comes before
    the source's `node_limit`, and those the table does not cover (the closed form below its
    ``exact_below`` or past its end)."""
    at = d2 * (1.0 / table.step)
    return ((at < node_limit[source]) | (d2 < (CLOSE * (radius[source] + radius[receiver])) ** 2)
            | (d2 < table.exact_below) | (at > table.values.shape[1] - 1))


def _candidates(points: np.ndarray, trees: list) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(receiver in `points`, source vertex, squared distance) of the pairs within each source
    group's reach (i == j included)."""
    receivers, sources, d2 = [], [], []
    for members, tree, r in trees:
        pairs = cKDTree(points).sparse_distance_matrix(tree, r, output_type="ndarray")
        receivers.append(pairs["i"].astype(np.int64))
        sources.append(members[pairs["j"]])
        d2.append(np.square(pairs["v"]))
    return np.concatenate(receivers), np.concatenate(sources), np.concatenate(d2)


def _estimated_entries(x: np.ndarray, trees: list, field: NearField, table: ProfileTable, threshold: float,
                       diagonal: bool) -> float:
    """F's entry count predicted from `SAMPLE` receivers spread over the mesh."""
    n = len(x)
    picked = np.unique(np.linspace(0, n - 1, min(n, SAMPLE)).astype(np.int64))
    receiver, source, d2 = _candidates(x[picked], trees)
    value = throughput_values(field, table, threshold, source, picked[receiver], diagonal, d2)
    return float((value.max(axis=1) > 0).sum()) * n / max(len(picked), 1)


def search_radius(largest_cell_mm2: float, params: Profile, threshold: float) -> float:
    """Distance (mm) beyond which no source of cell area <= `largest_cell_mm2` reaches `threshold`
    in any channel (bisection on the monotone profile)."""
    if largest_cell_mm2 * diffuse_reflectance_profile(0.0, params).max() < threshold:
        return 0.0
    lo, hi = 0.0, 1.0
    while largest_cell_mm2 * diffuse_reflectance_profile(hi, params).max() >= threshold:
        lo, hi = hi, 2.0 * hi
        if hi > 1e12:
            return hi
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        if largest_cell_mm2 * diffuse_reflectance_profile(mid, params).max() >= threshold:
            lo = mid
        else:
            hi = mid
    return hi
