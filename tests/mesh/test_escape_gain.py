"""The escape gain: against an independent walk in an exact sphere, its flat limit, open and
inward-wound surfaces."""

import numpy as np
import trimesh

from sssbake.pipeline.core.materials import preset
from sssbake.pipeline.mesh.escape_gain import escape_gain
from sssbake.pipeline.mesh.winding import edge_defects


def test_a_small_sphere_lets_out_what_a_walk_in_an_exact_sphere_does():
    """benchmarks/bench_escape_gain.py walks the exact sphere (ray-sphere intersection, numba, its
    own random numbers, 20k photons per channel): skin1 in a 10 mm radius 1.300, 1.187, 1.105,
    of which 0.119, 0.026, 0.005 behind the light it entered from; marble 1.115, 1.115, 1.104. A
    light that does not matter (a flat surface's 1) is far off."""
    sphere = trimesh.creation.icosphere(subdivisions=5, radius=10.0)
    g = escape_gain(sphere.vertices, sphere.faces, 1.0, preset("skin1"))
    assert g.closed and min(g.photons) >= 16_384
    np.testing.assert_allclose(g.gain, [1.300, 1.187, 1.105], atol=0.03)
    np.testing.assert_allclose(g.back, [0.119, 0.026, 0.005], atol=0.01)
    np.testing.assert_allclose(np.add(g.front, g.back), g.gain, rtol=1e-12)
    # the shares themselves: more leaves the sphere than the plane, and both are shares
    assert all(0 < p < e < 1 for p, e in zip(g.plane, g.escape))
    # the same sphere in centimetres (file units of 10 mm): the same gain, the same random numbers
    again = escape_gain(sphere.vertices / 10.0, sphere.faces, 10.0, preset("skin1"))
    np.testing.assert_allclose(again.gain, g.gain, rtol=1e-6)


def test_a_large_sphere_is_a_half_space():
    sphere = trimesh.creation.icosphere(subdivisions=4, radius=1000.0)
    g = escape_gain(sphere.vertices, sphere.faces, 1.0, preset("skin1"))
    np.testing.assert_allclose(g.gain, 1.0, atol=0.02)


def test_winding_does_not_matter_and_an_open_surface_keeps_the_half_space():
    sphere = trimesh.creation.icosphere(subdivisions=3, radius=10.0)
    outward = escape_gain(sphere.vertices, sphere.faces, 1.0, preset("skin1"))
    inward = escape_gain(sphere.vertices, sphere.faces[:, ::-1], 1.0, preset("skin1"))
    # other entry points (a triangle's corners come in another order), the same gain within the noise;
    # photons started outside a wrongly oriented surface would walk off and never count
    np.testing.assert_allclose(inward.gain, outward.gain, atol=0.02)
    bowl = sphere.faces[sphere.triangles_center[:, 2] < 5.0]  # the cap cut off: photons would walk out
    assert not edge_defects(bowl).closed and edge_defects(sphere.faces).closed
    g = escape_gain(sphere.vertices, bowl, 1.0, preset("skin1"))
    assert not g.closed and g.gain == (1.0, 1.0, 1.0) and g.photons == (0, 0, 0)


def test_a_thin_slab_lets_through_what_a_walk_between_two_planes_does():
    """benchmarks/bench_escape_gain.py walks the infinite 2 mm slab between two exact planes: skin1
    lets out 1.764, 1.916, 1.561 × the plane's share, 0.974, 0.943, 0.561 of it through the far
    face. The mesh is a 400 mm wide box: its rim is 1 % of the area."""
    box = trimesh.creation.box(extents=(400.0, 400.0, 2.0))
    g = escape_gain(box.vertices, box.faces, 1.0, preset("skin1"))
    np.testing.assert_allclose(g.gain, [1.764, 1.916, 1.561], rtol=0.03)
    np.testing.assert_allclose(g.back, [0.974, 0.943, 0.561], rtol=0.04)
    assert min(g.behind) > 10_000  # the count the back gain's trust rests on


def test_the_compiled_walk_draws_the_random_numbers_the_numpy_walk_did():
    """The walk's counts for a fixed seed, as the walk drew them in numpy a flight at a time (before
    its flights ran compiled from blocks drawn ahead): the same random numbers meet the same fates."""
    sphere = trimesh.creation.icosphere(subdivisions=3, radius=5.0)
    g = escape_gain(sphere.vertices, sphere.faces, 1.0, preset("skin1"))
    assert g.photons == (48394, 133100, 262144)
    assert g.escape == (0.7212670992271769, 0.32632607062359126, 0.15494918823242188)
    assert g.plane == (0.4576187130636029, 0.22844477836213373, 0.124908447265625)
    assert g.behind == (8207, 4709, 1389)


def test_the_stage_gathers_on_the_field_built_beside_its_walk_as_on_its_own():
    """`bake.stages.escape_gain_stage` builds the gather's near field before the walk (its disc
    table on threads beside it) and hands it to the gather: the same bits as the walk and the gather
    one after the other, each building what it needs (a 10 mm skin1 ball lets out more than
    `MIN_BEHIND` photons behind)."""
    from sssbake.pipeline.bake.stages import EscapeGainParams, escape_gain_stage
    from sssbake.pipeline.core.back_share import MIN_BEHIND, gathered_shares, object_gains
    from sssbake.pipeline.core.profile import profile_for
    from sssbake.pipeline.core.surface import Surface

    ball = trimesh.creation.icosphere(subdivisions=3, radius=5.0)
    x = np.asarray(ball.vertices, dtype=np.float64)
    areas = np.bincount(ball.faces.ravel(), weights=np.repeat(ball.area_faces / 3.0, 3), minlength=len(x))
    surface = Surface(x, np.asarray(ball.faces, dtype=np.int64), np.asarray(ball.vertex_normals), areas, ())
    material = preset("skin1")
    walk, gain, back = escape_gain_stage(surface, EscapeGainParams(material, 1.0))
    alone = escape_gain(x, ball.faces, 1.0, material)
    assert walk == alone and max(alone.behind) >= MIN_BEHIND
    front, behind = gathered_shares(x, surface.faces, surface.normals, areas, profile_for(material))
    assert (gain, back) == object_gains(alone.front, alone.back, alone.behind, front, behind)
    assert back != (1.0, 1.0, 1.0)  # the gather ran
    # an open surface is not walked, and nothing is built for it
    open_surface = Surface(x, surface.faces[1:], surface.normals, areas, ())
    assert escape_gain_stage(open_surface, EscapeGainParams(material, 1.0))[1:] == ((1.0, 1.0, 1.0), (1.0, 1.0, 1.0))
