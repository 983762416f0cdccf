"""Where the profile's gather puts its light, in front of or behind its receivers: against
closed forms."""

import numpy as np
import pytest
import trimesh
from scipy.spatial import cKDTree

from sssbake.pipeline.core.back_share import (_MU_NODES, ENERGY_DROPPED, MIN_BEHIND, behind_share, gathered,
                                              gathered_shares, object_gains)
from sssbake.pipeline.core.materials import preset
from sssbake.pipeline.core.near_field import NearField
from sssbake.pipeline.core.profile import disc_integral, profile_for, profile_total, radius_for_energy


def test_behind_share_closed_forms():
    mu = np.linspace(-1.0, 1.0, 41)
    h = behind_share(mu)
    # a source facing the receiver's way sends nothing from behind it, one facing away all, a
    # perpendicular one half (the cosine lobe is symmetric about the receiver's plane)
    np.testing.assert_allclose(behind_share(np.array([1.0, 0.0, -1.0])), [0.0, 0.5, 1.0], atol=1e-4)
    # a receiver turned round sees in front what it saw behind
    np.testing.assert_allclose(h + h[::-1], 1.0, atol=1e-4)
    assert np.all(np.diff(h) < 0)
    # μ = cos 60°: the cosine lobe's share beyond a plane tilted 60° from the source's, by sampling
    # directions (independent of the azimuth formula)
    rng = np.random.default_rng(3)
    u, phi = rng.random(400_000), 2 * np.pi * rng.random(400_000)
    w = np.c_[np.sqrt(1 - u) * np.cos(phi), np.sqrt(1 - u) * np.sin(phi), np.sqrt(u)]  # cosine-distributed
    receiver = np.array([np.sin(np.pi / 3), 0.0, 0.5])
    assert behind_share(np.array([0.5]))[0] == pytest.approx(np.mean(w @ receiver < 0), abs=3e-3)


def _slab(thickness: float):
    box = trimesh.creation.box(extents=(40.0, thickness, 40.0)).subdivide_to_size(0.8, max_iter=20)
    box.merge_vertices()
    return box


def test_a_receiver_mid_slab_gathers_its_own_face_in_front_and_the_far_face_behind():
    """At the middle of a face of a slab much wider than the profile, the gather holds its own
    face's R_tot in front (μ = 1, h = 0) and behind it the far face's 2π ∫_d^∞ R(r) r dr (μ = -1,
    h = 1): what the profile holds beyond the thickness d."""
    d = 1.5
    slab = _slab(d)
    p = profile_for(preset("skin1"))
    x = np.asarray(slab.vertices)
    middle = np.flatnonzero((slab.vertex_normals[:, 1] > 0.99) & (np.abs(x[:, 0]) < 4) & (np.abs(x[:, 2]) < 4))
    total, behind = gathered(x, slab.faces, slab.vertex_normals, p, middle)
    beyond = profile_total(p) - disc_integral(d, p)
    np.testing.assert_allclose(behind.mean(axis=0), beyond, rtol=0.03)
    np.testing.assert_allclose((total - behind).mean(axis=0), profile_total(p), rtol=0.03)
    assert behind[:, 0].mean() > behind[:, 1].mean() > behind[:, 2].mean()  # red crosses best


def test_the_energy_limit_keeps_a_thin_slabs_light_at_r_tot():
    """Each source of a thin slab reaches both faces, ~(1 + beyond/R_tot) R_tot in all: the bake
    scales it back to R_tot, so the shares add to ~1 (the rim's points a little less) and split in
    the proportion of the two faces."""
    d = 1.5
    slab = _slab(d)
    p = profile_for(preset("skin1"))
    areas = np.bincount(slab.faces.ravel(), np.repeat(slab.area_faces / 3.0, 3), len(slab.vertices))
    front, back = gathered_shares(np.asarray(slab.vertices), slab.faces, slab.vertex_normals, areas, p)
    np.testing.assert_allclose(front + back, 1.0, atol=0.04)
    beyond = 1.0 - disc_integral(d, p) / profile_total(p)
    np.testing.assert_allclose(back, beyond / (1.0 + beyond), rtol=0.1, atol=0.005)


def test_object_gains_match_the_walks_front_and_back_and_fall_back_to_one_factor():
    front, back = np.array([0.7, 0.8, 0.95]), np.array([0.3, 0.16, 0.05])
    gain, back_gain = object_gains((0.8, 1.0, 1.0), (1.0, 1.0, 0.6), (MIN_BEHIND, 10 * MIN_BEHIND, MIN_BEHIND - 1),
                                   front, back)
    np.testing.assert_allclose(gain[:2], [0.8 / 0.7, 1.0 / 0.8])
    # the gather times the two factors lets out in front and behind what the walk does
    np.testing.assert_allclose(np.multiply(gain, back_gain)[:2] * back[:2], [1.0, 1.0])
    # too few photons behind: one factor for all of the channel's light
    assert gain[2] == pytest.approx(1.6 / 1.0) and back_gain[2] == 1.0


def test_the_compiled_gather_is_the_sum_over_the_pairs_within_the_radius():
    """`gathered` against its definition in numpy: the k-d tree's pairs within each channel's
    radius, `NearField.weights`, h interpolated in μ, summed per receiver."""
    sphere = trimesh.creation.icosphere(subdivisions=4, radius=6.0)
    x, normals = np.asarray(sphere.vertices), np.asarray(sphere.vertex_normals)
    p = profile_for(preset("skin1"))
    points = np.arange(0, len(x), 7)
    total, behind = gathered(x, sphere.faces, normals, p, points)
    radius = radius_for_energy(ENERGY_DROPPED, p)
    lists = cKDTree(x).query_ball_point(x[points], radius.max())
    local = np.repeat(np.arange(len(points)), [len(lst) for lst in lists])
    rows, cols = points[local], np.concatenate([np.asarray(lst, dtype=np.int64) for lst in lists])
    weight = NearField.build(x, sphere.faces, normals, p).weights(rows, cols)
    mu_grid = np.linspace(-1.0, 1.0, _MU_NODES)
    h = np.interp(np.einsum("ij,ij->i", normals[rows], normals[cols]), mu_grid, behind_share(mu_grid))
    within = np.linalg.norm(x[rows] - x[cols], axis=1)[:, None] <= radius
    expected_total, expected_behind = np.zeros((len(points), 3)), np.zeros((len(points), 3))
    np.add.at(expected_total, local, np.where(within, weight, 0.0))
    np.add.at(expected_behind, local, np.where(within, weight * h[:, None], 0.0))
    np.testing.assert_allclose(total, expected_total, rtol=1e-12)
    np.testing.assert_allclose(behind, expected_behind, rtol=1e-12)
