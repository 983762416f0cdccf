"""prt precompute, visibility and the offline reference: closed form on a plane, agreement with
each other, invariance under rotation, occlusion."""

import numpy as np
import pytest
import trimesh
from fixtures import plane

from sssbake.pipeline.core import visibility
from sssbake.pipeline.core.profile import profile_for, profile_total
from sssbake.pipeline.core.directions import fibonacci_sphere
from sssbake.pipeline.core.fresnel import fresnel_transmittance
from sssbake.pipeline.core.materials import Material, preset
from sssbake.pipeline.core.reference import Light, reference_scattering
from sssbake.pipeline.core.scatter_operator import ScatterOptions
from sssbake.pipeline.core.surface import Surface, area_weighted_normals, vertex_areas
from sssbake.pipeline.core.visibility import direction_visibility, point_visibility
from sssbake.pipeline.techniques.prt.precompute import PrtPrecomputeOptions, precompute_prt

SHORT = Material("short", (1.0, 1.0, 1.0), (0.5, 0.3, 0.2), 1.4)  # short range: small exact tests


def surface_of(x: np.ndarray, f: np.ndarray) -> Surface:
    return Surface(x, f, area_weighted_normals(x, f), vertex_areas(x, f), (np.arange(len(x)),))


def two_spheres() -> Surface:
    a = trimesh.creation.icosphere(subdivisions=3)
    b = a.copy()
    b.apply_translation([3.0, 0.0, 0.0])
    both = trimesh.util.concatenate([a, b])
    return surface_of(np.asarray(both.vertices), np.asarray(both.faces))


def test_plane_q_is_transmitted_total_diffuse_reflectance():
    p = profile_for(SHORT)
    spacing = 0.25 * SHORT.mean_free_path_mm.min()  # a quarter of z_r = 1/σ'_t
    verts, faces, centre = plane(spacing, 40)
    directions = np.array([[0.0, 0.0, 1.0], [0.6, 0.0, 0.8], [0.0, 0.0, -1.0]])
    res = precompute_prt(surface_of(verts, faces), 1.0, SHORT, directions)
    rd = profile_total(p) * (1.0 - res.dropped_fraction)
    for j, cos in enumerate((1.0, 0.8)):
        expected = fresnel_transmittance(SHORT.eta, cos) * cos / np.pi * rd
        np.testing.assert_allclose(res.q[:, centre, j], expected, rtol=0.01)
    assert np.all(res.q[:, :, 2] == 0.0)  # lit from below a one-sided plane: nothing enters


def test_visibility_sees_the_horizon_and_occluders():
    s = two_spheres()
    towards_b = np.array([[1.0, 0.0, 0.0]])
    vis = direction_visibility(s.positions, s.faces, s.normals, towards_b)[:, 0]
    on_a = np.arange(len(s.positions)) < len(s.positions) // 2
    facing = s.normals @ towards_b[0] > 0
    near_axis = np.abs(s.positions[:, 1]) ** 2 + np.abs(s.positions[:, 2]) ** 2 < 0.25
    assert not vis[~facing].any()                     # below the horizon
    assert not vis[on_a & facing & near_axis].any()   # A's side facing B is shadowed by B
    assert vis[~on_a & facing].all()                  # B's far side sees the light
    # a point light between the spheres lights both inner sides, not the outer ones
    pvis = point_visibility(s.positions, s.faces, s.normals, np.array([1.5, 0.0, 0.0]))
    inner = np.abs(s.positions[:, 0] - 1.5) < 0.6
    assert pvis[inner & near_axis].all() and not pvis[s.positions[:, 0] < -0.5].any()


def test_visibility_in_many_batches_is_the_same(monkeypatch):
    s = two_spheres()
    directions = fibonacci_sphere(9)
    whole = direction_visibility(s.positions, s.faces, s.normals, directions)
    monkeypatch.setattr(visibility, "BATCH", 37)  # batches split across the threads
    assert np.array_equal(direction_visibility(s.positions, s.faces, s.normals, directions), whole)
    assert 0.2 < whole.mean() < 0.5  # the pair shadows part of the lit half


def test_reference_equals_precompute_at_a_set_direction():
    s = two_spheres()
    material = preset("ketchup")
    directions = fibonacci_sphere(12)
    options = PrtPrecomputeOptions(scatter=ScatterOptions(hierarchy=False, energy_dropped=1e-3, float32=False))
    res = precompute_prt(s, 10.0, material, directions, options)
    for j in (0, 5):
        ref = reference_scattering(s, 10.0, material, Light("directional", tuple(directions[j])), energy_dropped=1e-3)
        np.testing.assert_allclose(ref, res.q[:, :, j], rtol=1e-9, atol=1e-12 * res.q.max())
    # A tighter reference radius adds light, except where a source then reaches R_d and is held there.
    tight = reference_scattering(s, 10.0, material, Light("directional", tuple(directions[0])))
    area = s.vertex_areas
    assert np.all(tight @ area >= res.q[:, :, 0] @ area)
    assert np.all(tight >= res.q[:, :, 0] - 1e-3 * res.q[:, :, 0].max(axis=1, keepdims=True))


def test_hierarchical_precompute_is_rotation_invariant_within_its_error():
    s = surface_of(*(lambda m: (np.asarray(m.vertices) * 20.0, np.asarray(m.faces)))(trimesh.creation.icosphere(4)))
    rot = trimesh.transformations.rotation_matrix(1.1, [0.2, 0.9, -0.4])[:3, :3]
    directions = fibonacci_sphere(16)
    a = precompute_prt(s, 1.0, preset("marble"), directions).q
    rotated = Surface(s.positions @ rot.T, s.faces, s.normals @ rot.T, s.vertex_areas, s.weld)
    b = precompute_prt(rotated, 1.0, preset("marble"), directions @ rot.T).q
    assert np.sqrt(np.mean((a - b) ** 2)) <= 3e-3 * np.sqrt(np.mean(a**2))


def test_point_light_falls_off_with_distance():
    s = surface_of(*plane(0.2, 15)[:2])
    near = reference_scattering(s, 1.0, SHORT, Light("point", position=(0.0, 0.0, 10.0), intensity=100.0))
    far = reference_scattering(s, 1.0, SHORT, Light("point", position=(0.0, 0.0, 20.0), intensity=100.0))
    centre = len(s.positions) // 2
    np.testing.assert_allclose(near[:, centre] / far[:, centre], 4.0, rtol=0.02)


def test_bad_lights_and_scales_are_refused():
    with pytest.raises(ValueError, match="light: kind"):
        Light("spot")
    with pytest.raises(ValueError, match="non-zero"):
        Light("directional", (0.0, 0.0, 0.0))
    with pytest.raises(ValueError, match="mm_per_unit"):
        precompute_prt(two_spheres(), 0.0, SHORT, fibonacci_sphere(4))


def test_clustered_reference_follows_the_exact_sum():
    s = surface_of(*(lambda m: (np.asarray(m.vertices) * 20.0, np.asarray(m.faces)))(trimesh.creation.icosphere(3)))
    light = Light("directional", (0.3, -0.5, 0.8))
    exact = reference_scattering(s, 1.0, preset("marble"), light)
    clustered = reference_scattering(s, 1.0, preset("marble"), light, clustered=True)
    err = np.abs(clustered - exact)
    assert err.max() <= 5e-3 * exact.max()
    assert np.sqrt(np.mean(err**2)) <= 2e-3 * np.sqrt(np.mean(exact**2))
    assert err.max() > 0  # it did take the other path


def test_back_gain_scales_exactly_the_light_from_behind_each_vertex():
    """`Material.back_gain` multiplies what a vertex gathers from directions behind its tangent
    plane, per channel, in the bake and in the reference alike, and nothing else."""
    from dataclasses import replace

    s = surface_of(*(np.asarray(a) for a in (trimesh.creation.icosphere(subdivisions=2, radius=2.0).vertices,
                                             trimesh.creation.icosphere(subdivisions=2, radius=2.0).faces)))
    directions = fibonacci_sphere(12)
    gain = (2.0, 3.0, 0.5)
    plain = precompute_prt(s, 1.0, SHORT, directions).q
    gained = precompute_prt(s, 1.0, replace(SHORT, back_gain=gain), directions).q
    behind = s.normals @ directions.T < 0.0
    expected = plain * np.where(behind[None], np.asarray(gain)[:, None, None], 1.0)
    np.testing.assert_allclose(gained, expected, rtol=1e-6, atol=1e-12)
    assert np.all(plain[:, behind] > 0)  # the sphere carries light round: the factor has something to act on
    light = Light(direction=tuple(directions[3]))
    ref = reference_scattering(s, 1.0, SHORT, light)
    ref_gained = reference_scattering(s, 1.0, replace(SHORT, back_gain=gain), light)
    np.testing.assert_allclose(ref_gained, ref * np.where(behind[:, 3][None], np.asarray(gain)[:, None], 1.0),
                               rtol=1e-12)


def test_compiled_signal_equals_the_numpy_fresnel():
    # `precompute._transmitted` against its numpy definition, bit for bit: lights in front of,
    # grazing and behind the vertices, seen and blocked.
    from sssbake.pipeline.techniques.prt.precompute import irradiance_signal

    rng = np.random.default_rng(3)
    normals = rng.normal(size=(500, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    directions = np.r_[fibonacci_sphere(40), normals[:3], -normals[3:5]]
    visible = rng.random((500, len(directions))) < 0.7
    for eta in (1.0, 1.3, 2.4):
        cos = np.clip(normals @ directions.T, 0.0, None)
        expected = fresnel_transmittance(eta, cos) * cos * visible / np.pi
        np.testing.assert_array_equal(irradiance_signal(normals, directions, visible, eta), expected)
