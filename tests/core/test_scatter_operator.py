"""The hierarchical scattering gather: closed form on a plane, agreement with exact pair sums,
energy bound, invariance, extremes."""

import numpy as np
import pytest
import scipy.sparse as sp
import trimesh
from fixtures import plane

from sssbake.pipeline.core.profile import classical_dipole, profile_for, profile_of, profile_total, radius_for_energy
from sssbake.pipeline.core.materials import preset, preset_names
from sssbake.pipeline.core.scatter_operator import ScatterOptions, scatter_operator
from sssbake.pipeline.core.surface import area_weighted_normals, vertex_areas

EXACT = ScatterOptions(hierarchy=False, float32=False)


def sphere(radius_mm: float, subdivisions: int = 4):
    s = trimesh.creation.icosphere(subdivisions=subdivisions, radius=radius_mm)
    x, f = np.asarray(s.vertices), np.asarray(s.faces)
    return x, f, vertex_areas(x, f), area_weighted_normals(x, f)


def up(verts: np.ndarray) -> np.ndarray:
    """Normals of a plane in z = 0."""
    return np.tile([0.0, 0.0, 1.0], (len(verts), 1))


def lit(normals: np.ndarray, k: int = 6, seed: int = 0) -> np.ndarray:
    """(n, k) clamped-cosine irradiance of k random directional lights."""
    d = np.random.default_rng(seed).normal(size=(k, 3))
    return np.clip(normals @ (d / np.linalg.norm(d, axis=1, keepdims=True)).T, 0.0, None)


def channel_csr(m, c: int) -> sp.csr_matrix:
    """Channel c of a `ChannelRows` as a scipy (T, width) matrix (a shared layout's 0.0 included)."""
    ptr, values = m.channel(c)
    lo, hi = ptr[0], ptr[-1]
    return sp.csr_matrix((values[lo:hi], m.indices[lo:hi], ptr - lo), shape=(m.rows, m.width))


def matrices(op) -> list:
    return [op.near] + [level.matrix for level in op.levels]


def force_layout(monkeypatch, shared: bool | None) -> None:
    """Store every matrix shared (True) or split (False), or whichever takes fewer bytes (None)."""
    from sssbake.pipeline.core import scatter_operator as module

    if shared is not None:
        monkeypatch.setattr(module, "_shared_layout", lambda *args: shared)


@pytest.mark.parametrize("model", ["montecarlo", "dipole"])
@pytest.mark.parametrize("hierarchy", [False, True])
@pytest.mark.parametrize("spacing_zr, tol", [(0.5, 0.005), (1.0, 0.005), (2.0, 0.01), (4.0, 0.01)])
def test_plane_under_uniform_light_gives_total_diffuse_reflectance(hierarchy, spacing_zr, tol, model):
    # Cells integrated as they tile keep R_d on coarse tessellations too (point samples lost 5 %
    # at a spacing of z_r and 11 % at 2 z_r). A short-range material keeps the plane small.
    p = profile_of((1.0, 1.0, 1.0), (0.5, 0.3, 0.2), 1.4, model)
    options = ScatterOptions(energy_dropped=1e-2, hierarchy=hierarchy, float32=False)
    spacing = spacing_zr / 1.5  # z_r = 1/σ'_t, the largest σ'_t 1.5/mm
    verts, faces, centre = plane(spacing, int(np.ceil(radius_for_energy(1e-2, p).max() / spacing)) + 2)
    op = scatter_operator(verts, faces, up(verts), p, options)
    q = op.apply(np.ones((len(verts), 1)))[:, centre, 0]
    rd = profile_total(p)
    np.testing.assert_allclose(q, rd * (1.0 - op.dropped_fraction), rtol=tol)
    assert np.all(op.dropped_fraction <= 1e-2 + 1e-12)


def test_coarse_sources_never_send_out_more_than_total_reflectance():
    # At 4 z_r overlapping source discs would return ~1 % more than R_d; the limit holds them at R_d.
    p = classical_dipole([1.0, 1.0, 1.0], [0.5, 0.3, 0.2], 1.4)
    verts, faces, centre = plane(4.0 * p.depth[0].min(), 12)
    area = vertex_areas(verts, faces)
    rd = profile_total(p)
    for options in (EXACT, ScatterOptions(float32=False)):
        op = scatter_operator(verts, faces, up(verts), p, options)
        impulse = np.zeros((len(verts), 1))
        impulse[centre] = 1.0 / area[centre]  # unit flux from the centre vertex
        out = np.einsum("i,ci->c", area, op.apply(impulse)[:, :, 0])
        assert np.all(out <= rd) and np.all(out >= 0.98 * rd)


@pytest.mark.parametrize("separation, rms, peak", [(1, 1e-2, 3e-2), (2, 3e-3, 8e-3)])
def test_hierarchy_agrees_with_exact_pairs(separation, rms, peak):
    x, f, area, normals = sphere(25.0)  # marble: the radius spans a large part of the sphere
    p = profile_for(preset("marble"))
    signal = lit(normals)
    exact = scatter_operator(x, f, normals, p, EXACT).apply(signal)
    op = scatter_operator(x, f, normals, p, ScatterOptions(separation=separation))
    assert op.stats["levels"] >= 2 and len(op.levels) >= 1
    got = op.apply(signal)
    err = np.abs(got - exact)
    assert np.sqrt(np.mean(err**2)) <= rms * np.sqrt(np.mean(exact**2))
    assert err.max() <= peak * exact.max()
    assert op.nnz < scatter_operator(x, f, normals, p, EXACT).nnz  # cheaper than the pairs it replaces


@pytest.mark.parametrize("name", preset_names())
def test_never_gains_energy(name):
    x, f, area, normals = sphere(10.0, subdivisions=3)
    p = profile_for(preset(name))
    signal = lit(normals, k=3)
    budget = profile_total(p)[:, None] * (area @ signal)[None, :]
    for options in (EXACT, ScatterOptions()):
        q = scatter_operator(x, f, normals, p, options).apply(signal)
        out = np.einsum("i,cik->ck", area, q)
        assert np.all(out <= budget * (1 + 1e-9)), (name, options.hierarchy)
        assert np.all(q >= 0) and np.all(np.isfinite(q))


def test_rotation_invariance():
    x, f, area, normals = sphere(20.0, subdivisions=3)
    p = profile_for(preset("ketchup"))
    rot = trimesh.transformations.rotation_matrix(0.7, [0.3, -0.5, 0.8])[:3, :3]
    signal = lit(normals)
    for options in (EXACT, ScatterOptions()):
        a = scatter_operator(x, f, normals, p, options).apply(signal)
        b = scatter_operator(x @ rot.T, f, normals @ rot.T, p, options).apply(signal)
        # The grid is not rotated with the mesh: the hierarchy's clusters change, within its error.
        tol = 1e-10 if not options.hierarchy else 1.5e-2
        assert np.abs(a - b).max() <= tol * a.max()


@pytest.mark.parametrize("sigma_s, sigma_a, eta", [
    (1e-6, 1.0, 1.3),      # α' -> 0
    (1.0, 1e-9, 1.3),      # α' -> 1, σ_tr -> 0
    (2.0, 0.0, 1.0),       # no absorption, index matched
    (1e4, 1e2, 2.0),       # huge σ'_t: z_r -> 0
])
def test_extremes_stay_finite(sigma_s, sigma_a, eta):
    x, f, area, normals = sphere(5.0, subdivisions=2)
    p = classical_dipole([sigma_s] * 3, [sigma_a] * 3, eta)
    for options in (EXACT, ScatterOptions()):
        q = scatter_operator(x, f, normals, p, options).apply(lit(normals, k=2))
        assert np.all(np.isfinite(q)) and np.all(q >= 0)


def test_bad_input_is_refused():
    p = profile_for(preset("marble"))
    with pytest.raises(ValueError, match="scatter: need positions"):
        scatter_operator(np.zeros((3, 2)), np.array([[0, 1, 2]]), np.zeros((3, 2)), p)
    with pytest.raises(ValueError, match="finite"):
        scatter_operator(np.full((3, 3), np.nan), np.array([[0, 1, 2]]), np.eye(3), p)
    with pytest.raises(ValueError, match="energy_dropped"):
        scatter_operator(np.zeros((3, 3)), np.array([[0, 1, 2]]), np.eye(3), p, ScatterOptions(energy_dropped=0.0))


def test_float32_and_threads_change_nothing_but_rounding():
    x, f, area, normals = sphere(25.0)
    p = profile_for(preset("marble"))
    signal = lit(normals, k=40)  # more signals than one block: blocks run on both threads
    ref = scatter_operator(x, f, normals, p, ScatterOptions(float32=False, threads=1)).apply(signal)
    single = scatter_operator(x, f, normals, p, ScatterOptions(float32=True, threads=2, block=7)).apply(signal)
    # float32 entries round at ~1e-7 relative; the sums stay within 1e-5 of the largest q.
    assert np.abs(single - ref).max() <= 1e-5 * ref.max()
    assert np.abs(single - ref).max() > 0  # it really ran in float32
    # Written into a view of a larger array (as the precompute does), one block per thread.
    op = scatter_operator(x, f, normals, p, ScatterOptions(float32=False, threads=2, block=64))
    q = np.full((3, len(x), 50), -1.0)
    op.apply(signal[:, 3:33], out=q[:, :, 10:40])
    np.testing.assert_allclose(q[:, :, 10:40], ref[:, :, 3:33], rtol=1e-12, atol=1e-15 * ref.max())
    assert np.all(q[:, :, :10] == -1.0) and np.all(q[:, :, 40:] == -1.0)
    with pytest.raises(ValueError, match="out must be"):
        op.apply(signal, out=q)


def test_far_kernel_table_interpolates_to_its_bound():
    # The table's documented error (< 1e-5 relative) at points between its nodes.
    from sssbake.pipeline.core.profile import profile_derivatives
    from sssbake.pipeline.core.scatter_operator import _KernelTable
    for name in ("marble", "ketchup", "skin1"):
        p = profile_for(preset(name))
        radius = radius_for_energy(1e-2, p)
        table = _KernelTable.build(p, 0.3, float(radius.max()))
        at = np.linspace(0.0, table.nodes - 2, 5001)[1:-1] + 0.37
        d = np.exp(table.log_lo + at * table.step)
        node, w = at.astype(int), at - at.astype(int)
        for c in range(3):
            inside = d <= radius[c]  # entries beyond a channel's radius are never read
            exact = profile_derivatives(d[inside], p, c)[0]
            got = table.value[c, 0, node[inside]] + w[inside] * table.slope[c, 0, node[inside]]
            assert np.abs(got / exact - 1).max() < 1e-5, name


def test_chunked_assembly_gives_the_same_matrices(monkeypatch):
    # The build hands out blocks of rows to its threads (ENTRIES_PER_CHUNK candidate pairs each):
    # small blocks must give exactly the matrices of one block, and a float32 `out` (the precompute's
    # q) the float32 products themselves.
    from sssbake.pipeline.core import scatter_operator as module

    x, f, _, normals = sphere(25.0)
    p = profile_for(preset("marble"))
    options = ScatterOptions(threads=2)
    monkeypatch.setattr(module, "ENTRIES_PER_CHUNK", 10**9)
    whole = scatter_operator(x, f, normals, p, options)
    monkeypatch.setattr(module, "ENTRIES_PER_CHUNK", 997)
    chunked = scatter_operator(x, f, normals, p, options)
    assert {a.shared for a in matrices(whole)} == {True, False}  # both layouts built in blocks
    for a, b in zip(matrices(whole), matrices(chunked)):
        for name in ("data", "indices", "indptr", "within"):
            np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    signal = lit(normals, k=9)
    q32 = chunked.apply(signal, out=np.empty((3, len(x), 9), dtype=np.float32))
    np.testing.assert_array_equal(q32, chunked.apply(signal).astype(np.float32))


def row_entries(m, c: int, j: int, d: np.ndarray, radius: np.ndarray, columns: np.ndarray, values: np.ndarray):
    """Checks channel c's row j of a `ChannelRows` against its candidate sources' distances d,
    columns and values: the sources within the channel's radius, in candidate order, or in a
    shared layout those within the largest radius, 0.0 beyond the channel's."""
    ptr, stored = m.channel(c)
    got = slice(ptr[j], ptr[j + 1])
    keep = d <= (radius.max() if m.shared else radius[c])
    np.testing.assert_array_equal(m.indices[got], columns[keep])
    np.testing.assert_allclose(stored[got], np.where(d <= radius[c], values, 0.0)[keep], rtol=1e-9)
    if m.shared:
        assert m.within[c, j] == np.count_nonzero(d <= radius[c])


@pytest.mark.parametrize("shared", [True, False])
def test_compiled_entries_equal_their_numpy_definitions(monkeypatch, shared):
    # The compiled build (`scatter_kernels`) against the formulation it replaced: each row's
    # exact pairs in the order of its cells' vertex runs, with `NearField.weights`, and each
    # cluster term Rd(D) + ½ tr(H Σ) from the kernel table, in numpy; same pattern, values
    # within float32 rounding; in either layout. A bumpy sphere, so that sources sit off each
    # other's planes; ketchup, whose blue radius leaves out some of the exact pairs.
    from sssbake.pipeline.core.scatter_operator import scatter_plan

    force_layout(monkeypatch, shared)
    x, f, _, normals = sphere(12.0, subdivisions=3)
    x = x * (1.0 + 0.04 * np.sin(3.0 * x[:, :1]))
    normals = area_weighted_normals(x, f)
    p = profile_for(preset("ketchup"))
    plan = scatter_plan(x, f, normals, p, ScatterOptions(float32=False))
    n = len(x)
    rows = np.arange(0, n, 3)
    near, levels = plan.matrices(rows)
    field, r = plan.builder.field, plan.radius_mm
    vertex_ptr = np.r_[plan.starts[0], n]
    for j, o in enumerate(rows):
        cell = plan.cell_of[0][o]
        sources = np.concatenate([np.arange(vertex_ptr[g], vertex_ptr[g + 1])
                                  for g in plan.near_lists[plan.near_ptr[cell]:plan.near_ptr[cell + 1]]])
        d = np.linalg.norm(x[plan.order][sources] - x[plan.order][o], axis=1)
        weights = field.weights(np.full(len(sources), o), sources)
        assert np.any(d > r.min()) and np.all(d <= r.max())  # the padded 0.0 are checked, too
        for c in range(3):
            row_entries(near, c, j, d, r, sources, weights[:, c])
    table = plan.builder.table
    xt = plan.positions.T
    assert levels
    for (level, clusters), far in zip(plan.far[::-1], levels):
        m = clusters.count
        for j, o in enumerate(rows):
            key = plan.cell_of[level][o]
            s = clusters.lists[clusters.ptr[key]:clusters.ptr[key + 1]]
            off = xt[:, o, None] - clusters.centroid[:, s]
            d2 = (off**2).sum(axis=0)
            sp6 = clusters.spread[:, s]
            radial = (sp6[0] * off[0]**2 + sp6[1] * off[1]**2 + sp6[2] * off[2]**2
                      + 2.0 * (sp6[3] * off[0] * off[1] + sp6[4] * off[0] * off[2] + sp6[5] * off[1] * off[2])) / d2
            at = (0.5 * np.log(d2) - table.log_lo) / table.step
            node = np.clip(at.astype(np.int64), 0, table.nodes - 2)
            w = at - node
            assert far.matrix.width == far.matrix.stride == m
            for c in range(3):
                terms = table.value[c][:, node] + w * table.slope[c][:, node]  # (3 terms, entries)
                kernel = terms[0] + terms[1] * radial + terms[2] * clusters.trace[s]
                row_entries(far.matrix, c, j, np.sqrt(d2), r, s, kernel)


def scipy_apply(op, signal: np.ndarray) -> np.ndarray:
    """`ScatterOperator.apply` as scipy products (the form the compiled one replaced): per channel
    near_c @ e, plus each level's matrix_c @ its clusters' moments of channel c (numpy's
    reduceat), clamped at 0."""
    n, dtype = len(op.order), op.near.dtype
    e = signal[op.order]
    out = np.empty((3, n, signal.shape[1]), dtype)
    for c in range(3):
        q = channel_csr(op.near, c) @ e.astype(dtype)
        for f in op.levels:
            q += channel_csr(f.matrix, c) @ np.add.reduceat(e * op.source_area[c][:, None], f.starts, axis=0).astype(dtype)
        out[c, op.order] = q
    return np.maximum(out, 0.0) if np.all(signal >= 0) else out


@pytest.mark.parametrize("float32, threads, block", [(True, 2, 32), (True, 2, 3), (False, 1, 4), (True, 3, 5)])
def test_compiled_apply_equals_the_scipy_products(float32, threads, block):
    # `scatter_kernels.csr_rows_product` and `shared_rows_product` sum each row as scipy's
    # products do, `cluster_moments` the moments in vertex order (numpy's reduceat pairwise):
    # equal to the rounding of the moments, in one pass or several (k > threads · block), on any
    # number of threads, and for signals of any sign (no clamp).
    x, f, _, normals = sphere(25.0)
    op = scatter_operator(x, f, normals, profile_for(preset("marble")),
                          ScatterOptions(float32=float32, threads=threads, block=block))
    assert len(op.levels) >= 2 and {m.shared for m in matrices(op)} == {True, False}
    rtol = 1e-6 if float32 else 1e-13
    signal = lit(normals, k=23)
    for s in (signal, signal - 0.3):
        got = op.apply(s, out=np.empty((3, len(x), 23), dtype=op.near.dtype))
        ref = scipy_apply(op, s)
        np.testing.assert_allclose(got, ref, rtol=rtol, atol=rtol * np.abs(ref).max())
    assert np.all(got == 0) == np.all(ref == 0) and np.any(got < 0)


@pytest.mark.parametrize("shared", [True, False])
def test_compiled_products_and_moments_equal_their_numpy_definitions(monkeypatch, shared):
    from sssbake.pipeline.core.scatter_kernels import cluster_moments

    force_layout(monkeypatch, shared)
    x, f, _, normals = sphere(25.0)
    for dtype in (np.float32, np.float64):
        op = scatter_operator(x, f, normals, profile_for(preset("marble")),
                              ScatterOptions(float32=dtype == np.float32))
        e = lit(normals, k=11)[op.order] - 0.2
        sources = [e.astype(dtype)]
        for level in op.levels:
            got = np.empty((3 * len(level.starts), 11))
            cluster_moments(e, op.source_area, level.starts, got)
            ref = np.concatenate([np.add.reduceat(e * op.source_area[c][:, None], level.starts, axis=0)
                                  for c in range(3)])
            np.testing.assert_allclose(got, ref, rtol=1e-13, atol=1e-15 * np.abs(ref).max())
            sources.append(ref.astype(dtype))
        # the products, near (one signal) and far (channel c's moments): bit for bit scipy's per
        # channel, written or added
        for m, x_all in zip(matrices(op), sources):
            assert m.shared == shared
            t = m.rows
            want = np.concatenate([channel_csr(m, c) @ x_all[c * m.stride:c * m.stride + m.width] for c in range(3)])
            y = np.ones((3 * t, 11), dtype)
            m.product(0, t, x_all, y, False)
            np.testing.assert_array_equal(y, want)
            m.product(5, t, x_all, y, True)
            first = np.isin(np.arange(3 * t) % t, np.arange(5))  # each channel's first 5 rows
            np.testing.assert_array_equal(y[~first], want[~first] * 2)
            np.testing.assert_array_equal(y[first], want[first])


def test_layout_changes_no_bit_of_q(monkeypatch):
    # Every matrix shared, every one split, or each the smaller (as built): a shared layout's 0.0
    # beyond a channel's radius add nothing to the products, and `_limit_energy` sums each
    # channel in the same chunks of its own entries, so source_area and q are equal bit for bit.
    # skin2: its blue radius is ~1/3 of red's, so the padding is most of a shared level.
    from sssbake.pipeline.core import scatter_operator as module

    x, f, _, _ = sphere(25.0)
    x = x * (1.0 + 0.15 * np.sin(0.2 * x[:, :1]) * np.cos(0.16 * x[:, 1:2]))  # bumps: many sources limited
    area, normals = vertex_areas(x, f), area_weighted_normals(x, f)
    p = profile_for(preset("skin2"))
    signal = lit(normals, k=9)
    monkeypatch.setattr(module, "ENTRIES_PER_CHUNK", 997)  # many chunks: their bounds would show
    ops = []
    for shared in (None, True, False):
        force_layout(monkeypatch, shared)
        ops.append(scatter_operator(x, f, normals, p, ScatterOptions(threads=2)))
    assert {m.shared for m in matrices(ops[0])} == {True, False}
    assert ops[1].nbytes > ops[0].nbytes and ops[2].nbytes > ops[0].nbytes
    assert np.any(ops[0].source_area < area[ops[0].order])  # the energy limit scaled sources
    q = ops[0].apply(signal)
    for op in ops[1:]:
        assert np.array_equal(op.source_area, ops[0].source_area)
        assert np.array_equal(op.apply(signal), q)


def expand_runs(pairs: np.ndarray, first: np.ndarray, count: np.ndarray) -> np.ndarray:
    """(p', 2) all (first[t] + i, first[s] + j), i < count[t], j < count[s], for pairs (t, s): the
    numpy expansion `scatter_kernels.child_pairs` replaced."""
    ct, cs = count[pairs[:, 0]], count[pairs[:, 1]]
    per = ct * cs
    which = np.repeat(np.arange(len(pairs)), per)
    local = np.arange(per.sum()) - np.repeat(np.cumsum(per) - per, per)
    cs_w = cs[which]
    return np.column_stack([first[pairs[which, 0]] + local // cs_w, first[pairs[which, 1]] + local % cs_w])


def test_compiled_child_pairs_equal_the_numpy_expansion():
    from sssbake.pipeline.core.scatter_kernels import child_pairs

    rng = np.random.default_rng(5)
    count = rng.integers(0, 9, size=60)
    first = np.r_[0, np.cumsum(count)[:-1]]
    coords = rng.integers(0, 12, size=(int(count.sum()), 3))
    pairs = rng.integers(0, 60, size=(400, 2))
    every = expand_runs(pairs, first, count)
    gap = np.abs(coords[every[:, 0]] - coords[every[:, 1]]).max(axis=1)
    near, far = child_pairs(pairs, first, count, coords, 2)
    np.testing.assert_array_equal(near, every[gap <= 2])
    np.testing.assert_array_equal(far, every[gap > 2])
    assert near.dtype == far.dtype == np.int64 and len(near) and len(far)
