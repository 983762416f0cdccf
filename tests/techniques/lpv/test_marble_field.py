import math

import numpy as np
import pytest
import trimesh

from sssbake.pipeline.core.materials import preset
from sssbake.pipeline.core.surface import Surface, area_weighted_normals, vertex_areas
from sssbake.pipeline.techniques.lpv.grid import LpvGridOptions, voxelise
from sssbake.pipeline.techniques.lpv.marble_field import (
    MARBLE_DEFAULTS,
    NOISE_GRADIENT_BOUND,
    VEIN_ABSORPTION,
    MarbleOptions,
    marble_field,
    materials,
    mean_vein_weight,
    vein_weight,
)


def points_mm(n, half=200.0, seed=0):
    return np.random.default_rng(seed).uniform(-half, half, (n, 3))


def test_same_seed_same_values_other_seed_other_values():
    p = points_mm(2000)
    a = marble_field(2.0, MarbleOptions(seed=4))(p / 2.0)
    b = marble_field(2.0, MarbleOptions(seed=4))(p / 2.0)
    c = marble_field(2.0, MarbleOptions(seed=5))(p / 2.0)
    assert np.array_equal(a[0], b[0]) and np.array_equal(a[1], b[1])
    assert np.mean(np.abs(a[1] - c[1])) > 0.1 * np.mean(np.abs(a[1] - a[1].mean(axis=0)))


def test_the_field_takes_file_units_and_scales_them():
    p = points_mm(500)
    w = vein_weight(p)
    _, a = marble_field(4.0)(p / 4.0)
    base, vein = materials()
    assert np.allclose(a, (1 - w[:, None]) * base.a + w[:, None] * vein.a, rtol=1e-12)


@pytest.mark.parametrize("vein", [None, "skin1"])
def test_coefficients_blend_between_the_two_materials(vein):
    options = MarbleOptions(vein_material=vein)
    base, vein_material = materials(options)
    s, a = marble_field(1.0, options)(points_mm(20000))
    assert s.shape == a.shape == (20000, 3)
    for value, lo_hi in ((s, (base.s, vein_material.s)), (a, (base.a, vein_material.a))):
        lo, hi = np.minimum(*lo_hi), np.maximum(*lo_hi)
        assert np.all(value >= lo - 1e-12) and np.all(value <= hi + 1e-12)
    w = vein_weight(points_mm(20000), options)
    assert w.min() >= 0 and w.max() <= 1 and w.min() < 0.01 and w.max() > 0.99  # both materials appear


def test_default_veins_absorb_more_and_scatter_the_same():
    base, vein = materials()
    assert base == preset("marble")
    assert np.allclose(vein.a, VEIN_ABSORPTION * base.a) and np.array_equal(vein.s, base.s)
    assert vein.eta == base.eta


@pytest.mark.parametrize("turbulence", [0.0, 1.0, 3.0])
def test_the_weight_is_smooth_with_a_bounded_gradient(turbulence):
    # |∇w| <= s π / vein_mm (1 + turbulence · octaves · B): finite differences must respect it at
    # every step, down to tiny ones (a discontinuity would blow them up)
    options = MarbleOptions(turbulence=turbulence)
    bound = options.sharpness * math.pi / options.vein_mm * (1 + turbulence * options.octaves * NOISE_GRADIENT_BOUND)
    p = points_mm(20000, seed=1)
    direction = np.random.default_rng(2).normal(size=(len(p), 3))
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    w = vein_weight(p, options)
    slopes = []
    for step in (1e-2, 1e-4, 1e-6):
        slope = np.abs(vein_weight(p + step * direction, options) - w) / step
        assert slope.max() <= bound
        slopes.append(slope.max())
    # and the largest slope converges (a Lipschitz field: no growth as the step shrinks)
    assert slopes[2] < 1.1 * slopes[1]


def test_share_of_space_in_veins_matches_the_profile():
    # the phase is spread evenly over a large region: the mean weight is |cos|^s's over a period,
    # and w > 1/2 on (2/π) arccos(2^(-1/s)) of it
    for options in (MARBLE_DEFAULTS, MarbleOptions(sharpness=3.0, turbulence=2.0, seed=7)):
        w = vein_weight(points_mm(200000, half=1000.0), options)
        s = options.sharpness
        assert abs(w.mean() / mean_vein_weight(s) - 1) < 0.03
        assert abs(np.mean(w > 0.5) - 2 / math.pi * math.acos(0.5 ** (1 / s))) < 0.01
    assert math.isclose(mean_vein_weight(2.0), 0.5) and math.isclose(mean_vein_weight(8.0), 35 / 128)


def test_without_turbulence_veins_are_planes_one_per_period():
    options = MarbleOptions(turbulence=0.0, axis=(0.0, 3.0, 4.0))
    axis = np.array([0.0, 0.6, 0.8])
    across = np.array([1.0, 0.0, 0.0])
    p = points_mm(5000)
    w = vein_weight(p, options)
    assert np.allclose(vein_weight(p + options.vein_mm * axis, options), w, atol=1e-9)
    assert np.allclose(vein_weight(p + 37.0 * across, options), w, atol=1e-12)
    assert not np.allclose(vein_weight(p + 0.5 * options.vein_mm * axis, options), w, atol=0.1)
    # turbulence breaks both
    turbulent = MarbleOptions(turbulence=1.0, axis=options.axis)
    assert not np.allclose(vein_weight(p + 37.0 * across, turbulent), vein_weight(p, turbulent), atol=0.05)


def test_a_marble_grid():
    v, f = (np.asarray(x) for x in (trimesh.creation.icosphere(subdivisions=3, radius=5.0).vertices,
                                     trimesh.creation.icosphere(subdivisions=3).faces))
    surf = Surface(v, f.astype(np.int64), area_weighted_normals(v, f), vertex_areas(v, f), (np.arange(len(v)),))
    options = MarbleOptions(vein_mm=10.0)
    grid = voxelise(surf, 10.0, marble_field(10.0, options), 1.5, LpvGridOptions(resolution=16))
    grid.check()
    occupied = grid.occupancy > 0
    base, vein = materials(options)
    st = grid.sigma_t[occupied]
    assert np.all(st >= (base.s + base.a) - 1e-5) and np.all(st <= (vein.s + vein.a) + 1e-5)
    albedo = grid.albedo[occupied]
    assert albedo.std(axis=0).min() > 1e-3  # heterogeneous: veins darken some cells


@pytest.mark.parametrize(
    ("options", "message"),
    [
        (MarbleOptions(vein_mm=0.0), "vein_mm"),
        (MarbleOptions(turbulence=-1.0), "turbulence"),
        (MarbleOptions(octaves=0), "octaves"),
        (MarbleOptions(sharpness=0.5), "sharpness"),
        (MarbleOptions(axis=(0.0, 0.0, 0.0)), "axis"),
    ],
)
def test_bad_options_raise(options, message):
    with pytest.raises(ValueError, match=f"^marble: {message}"):
        marble_field(1.0, options)


def test_bad_scale_raises():
    with pytest.raises(ValueError, match="^marble: mm_per_unit"):
        marble_field(0.0)
