"""Throughput factors F: the point rule far off, cell integrals close by, the threshold, and the
size guard."""

import numpy as np
import pytest
from kernels_planes import flat_surface

from sssbake.pipeline.core.profile import diffuse_reflectance_profile, profile_for, profile_total
from sssbake.pipeline.core.materials import preset
from sssbake.pipeline.core.surface import Surface, vertex_areas
from sssbake.pipeline.techniques.kernels import throughput
from sssbake.pipeline.techniques.kernels.throughput import throughput_matrix

P = profile_for(preset("skin1"))


@pytest.fixture(scope="module")
def plane_f():
    s = flat_surface(1.0, 14)
    return s, throughput_matrix(s.positions, s.faces, s.normals, P, 1e-5)


def test_far_entries_are_cell_times_rd_and_rows_are_sorted(plane_f):
    s, f = plane_f
    n = len(s.positions)
    rows = np.repeat(np.arange(n), np.diff(f.indptr))
    d = np.linalg.norm(s.positions[rows] - s.positions[f.indices], axis=1)
    far = d > 8.0
    expected = diffuse_reflectance_profile(d[far], P) * s.vertex_areas[f.indices[far], None]
    np.testing.assert_allclose(f.values[far], expected, rtol=1e-4)
    assert np.all(f.values.max(axis=1) >= 1e-5 * (1 - 1e-6))  # nothing below the threshold kept
    assert not np.any(rows == f.indices)  # the blended technique's F has no diagonal
    for j in range(0, n, 97):
        assert np.all(np.diff(f.indices[f.indptr[j]: f.indptr[j + 1]]) > 0)


def test_rows_of_a_plane_sum_to_rd(plane_f):
    # Cell integrals tile the plane: receiver sums reach R_d (bar the threshold and the diagonal).
    s, _ = plane_f
    full = throughput_matrix(s.positions, s.faces, s.normals, P, 1e-7, diagonal=True)
    centre = int(np.argmin(np.linalg.norm(s.positions, axis=1)))
    row = slice(full.indptr[centre], full.indptr[centre + 1])
    rd = profile_total(P)
    # the 28 mm plane holds all but the far tail of skin1's red
    np.testing.assert_allclose(full.values[row].sum(axis=0), rd, rtol=0.02)
    # the paper's point rule alone overestimates by the peak at the receiver (blue: z_r = 0.67 mm)
    d = np.linalg.norm(s.positions[full.indices[row]] - s.positions[centre], axis=1)
    point = (diffuse_reflectance_profile(d, P) * s.vertex_areas[full.indices[row], None]).sum(axis=0)
    assert point[2] > 1.1 * rd[2]


def test_a_higher_threshold_keeps_fewer_entries_and_the_guard_refuses_a_huge_f(plane_f):
    s, f = plane_f
    coarse = throughput_matrix(s.positions, s.faces, s.normals, P, 1e-3)
    assert 0 < coarse.nnz < f.nnz and coarse.radius_mm < f.radius_mm
    with pytest.raises(ValueError, match="raise the threshold"):
        throughput_matrix(s.positions, s.faces, s.normals, P, 1e-5, max_entries=1000)


def test_dropping_candidates_by_cell_before_the_values_changes_no_entry(monkeypatch):
    # Jittered cells, so that sources of one search class reach differently far: the bound of
    # `_may_reach` must drop candidates (else this tests nothing) and F must not change at all.
    s = flat_surface(1.0, 10)
    rng = np.random.default_rng(3)
    x = s.positions + np.c_[rng.uniform(-0.3, 0.3, (len(s.positions), 2)), np.zeros(len(s.positions))]
    s = Surface(x, s.faces, s.normals, vertex_areas(x, s.faces), s.weld)
    dropped, bound = [], throughput._may_reach

    def counted(*args):
        live = bound(*args)
        dropped.append(int((~live).sum()))
        return live

    monkeypatch.setattr(throughput, "_may_reach", counted)
    fast = throughput_matrix(s.positions, s.faces, s.normals, P, 1e-4)
    monkeypatch.setattr(throughput, "_may_reach", lambda *args: np.ones(len(args[-1]), dtype=bool))
    slow = throughput_matrix(s.positions, s.faces, s.normals, P, 1e-4)
    assert sum(dropped) > 0.05 * slow.nnz
    np.testing.assert_array_equal(fast.indptr, slow.indptr)
    np.testing.assert_array_equal(fast.indices, slow.indices)
    np.testing.assert_array_equal(fast.values, slow.values)
    np.testing.assert_allclose(fast.sent, slow.sent, rtol=1e-12)


def test_strongest_per_source_keeps_what_each_source_sends(plane_f):
    s, f = plane_f
    n, cell = len(s.positions), s.vertex_areas
    indptr, indices, values, moved = throughput.strongest_per_source(f.indptr, f.indices, f.values, cell, 5)
    rows = np.repeat(np.arange(n), np.diff(indptr))
    old_rows = np.repeat(np.arange(n), np.diff(f.indptr))
    assert np.all(np.bincount(indices, minlength=n) <= 5)
    for j in range(0, n, 53):  # still CSR by receiver, sources increasing
        assert np.all(np.diff(indices[indptr[j]: indptr[j + 1]]) > 0)
    sent_before = np.stack([np.bincount(f.indices, f.values[:, c] * cell[old_rows], minlength=n) for c in range(3)])
    sent_after = np.stack([np.bincount(indices, values[:, c] * cell[rows], minlength=n) for c in range(3)])
    np.testing.assert_allclose(sent_after, sent_before, rtol=1e-5)
    assert 0.3 < moved < 1.0  # most of skin1's light lands beyond a source's five nearest vertices
    # the kept entries of a source are its strongest, scaled by one factor per channel
    i = n // 2
    column = f.indices == i
    old, old_receivers = f.values[column], old_rows[column]
    kept = np.isin(old_receivers, rows[indices == i])
    assert kept.sum() == 5 and old[kept].max(axis=1).min() >= old[~kept].max(axis=1).max()
    ratio = values[indices == i] / old[kept]
    np.testing.assert_allclose(ratio, ratio[:1].repeat(len(ratio), axis=0), rtol=1e-5)


def test_a_bounded_build_equals_bounding_the_full_matrix(plane_f):
    # the build holds only each source's candidates, yet gives what bounding all of F gives
    s, f = plane_f
    bounded = throughput_matrix(s.positions, s.faces, s.normals, P, 1e-5, per_source=5)
    indptr, indices, values, moved = throughput.strongest_per_source(f.indptr, f.indices, f.values,
                                                                     s.vertex_areas, 5)
    np.testing.assert_array_equal(bounded.indptr, indptr)
    np.testing.assert_array_equal(bounded.indices, indices)
    np.testing.assert_allclose(bounded.values, values, rtol=1e-5)
    assert np.isclose(bounded.moved, moved, rtol=1e-6) and bounded.nnz <= 5 * len(s.positions)


def test_a_bounded_build_keeps_only_entries_beyond_the_window(plane_f):
    # receivers within 1.5 mm (the 1-ring and its diagonals on the 1 mm plane) are the kernels':
    # neither kept nor renormalised onto the others
    s, f = plane_f
    bounded = throughput_matrix(s.positions, s.faces, s.normals, P, 1e-5, per_source=5, beyond_mm=1.5)
    rows = np.repeat(np.arange(len(s.positions)), np.diff(f.indptr))
    far = np.linalg.norm(s.positions[rows] - s.positions[f.indices], axis=1) > 1.5
    counts = np.bincount(rows[far], minlength=len(s.positions))
    indptr, indices, values, _ = throughput.strongest_per_source(np.r_[0, np.cumsum(counts)], f.indices[far],
                                                                 f.values[far], s.vertex_areas, 5)
    np.testing.assert_array_equal(bounded.indptr, indptr)
    np.testing.assert_array_equal(bounded.indices, indices)
    np.testing.assert_allclose(bounded.values, values, rtol=1e-5)
    kept_rows = np.repeat(np.arange(len(s.positions)), np.diff(bounded.indptr))
    assert np.linalg.norm(s.positions[kept_rows] - s.positions[bounded.indices], axis=1).min() > 1.5
