"""The planner's pilot: candidates cheapest first, a subsample that keeps the shape, and the first
candidate within the budget that beats best-fit Lambert chosen from what the pilot measured against
the reference."""

import numpy as np
import pytest
import trimesh

from sssbake.pipeline.core.directions import direction_set
from sssbake.pipeline.core.materials import preset
from sssbake.pipeline.mesh.clean import clean_scene
from sssbake.pipeline.mesh.load import load_scene
from sssbake.pipeline.options import BAKE_DEFAULTS
from sssbake.pipeline.planning.pilot import beats_lambert, candidates, pilot_surface, run_pilot
from sssbake.pipeline.techniques.lpv.verify import LPV_SELF_REFERENCE
from sssbake.pipeline.techniques.prt.compress import budget_reference_count
from sssbake.pipeline.techniques.prt.pilot import PRT_BUDGETS, PRT_DIRECTIONS
from sssbake.pipeline.techniques.screen.pilot import SCREEN_SAMPLES


def surface_of(tmp_path, mesh, name="m.obj"):
    mesh.export(tmp_path / name)
    (surface,) = clean_scene(load_scene(str(tmp_path / name))).surfaces
    return surface


def test_candidates_run_from_cheap_to_dear_and_respect_the_byte_ceiling():
    options = BAKE_DEFAULTS.merged({"prt_directions": 16})
    screen = candidates("screen", {}, options, 5000, deforming=False)
    assert [c.params.get("screen_samples") for c in screen[:len(SCREEN_SAMPLES)]] == list(SCREEN_SAMPLES)
    prt = [c for c in screen if c.technique == "prt"]  # screen falls back to prt on a rigid mesh
    for k in PRT_DIRECTIONS + (16,):  # the given K is tried too
        at_k = [c for c in prt if c.params["prt_directions"] == k]
        counts = [budget_reference_count(c.params["prt_byte_budget"], 5000, direction_set(k), 0, "shared", 8)
                  for c in at_k]
        assert at_k and counts == sorted(counts) and len(set(counts)) == len(counts)  # each buys more points
    budgets = [c.params["prt_byte_budget"] for c in prt]
    assert budgets == sorted(budgets) and set(budgets) <= set(PRT_BUDGETS)  # bytes first, then K
    assert all(c.technique == "screen" for c in candidates("screen", {}, options, 5000, deforming=True))
    # 800k vertices: K = 400's integrals would not fit
    big = candidates("prt", {}, BAKE_DEFAULTS, 800_000, False)
    assert {c.params["prt_directions"] for c in big} == {100, 200}
    # _SSS_PRT_REF alone is 12 B/vertex (float32 VEC3): budgets under ~14 hold no reference points
    capped = candidates("prt", {}, options.merged({"max_bytes_per_vertex": 16.0}), 5000, False)
    assert max(c.params["prt_byte_budget"] for c in capped) == 16.0  # the ceiling itself is the last
    lpv = candidates("lpv", {"lpv_resolution": 38, "lpv_field": "marble"}, options, 5000, False)
    assert [c.params["lpv_resolution"] for c in lpv] == [38, 48, 64, 96, 128]
    assert all(c.params["lpv_field"] == "marble" for c in lpv)
    with pytest.raises(ValueError, match="no candidates"):
        candidates("kernels", {}, options, 5000, False)


def test_the_subsample_keeps_the_shape_with_its_own_normals(tmp_path):
    ball = surface_of(tmp_path, trimesh.creation.icosphere(subdivisions=5, radius=1.0))  # 10242 vertices
    small = pilot_surface(ball, 1000)
    assert 700 < len(small.positions) < 1300
    np.testing.assert_allclose(np.linalg.norm(small.positions, axis=1), 1.0, atol=0.02)  # still the sphere
    np.testing.assert_allclose(np.linalg.norm(small.normals, axis=1), 1.0)
    assert np.all(np.sum(small.normals * small.positions, axis=1) > 0.99)  # outward, as on the sphere
    np.testing.assert_allclose(small.vertex_areas.sum(), 4 * np.pi, rtol=0.02)
    assert pilot_surface(ball, 8000) is ball  # not much larger: itself


def test_the_pilot_takes_the_first_candidate_within_the_budget(tmp_path):
    ball = surface_of(tmp_path, trimesh.creation.icosphere(subdivisions=3, radius=1.0))
    options = BAKE_DEFAULTS.merged({"prt_directions": 16})
    found = candidates("screen", {}, options, len(ball.positions), False)[:6]  # 4 screen, 2 prt
    skin = preset("skin1")
    loose = run_pilot(found, ball, 100.0, skin, options, 0.5, len(ball.positions))
    errors = [r["rmse_image"] for r in loose.rows]
    assert len(errors) == len(found) and all(0 < e < 0.5 for e in errors)
    assert loose.chosen == 0 and loose.met and loose.reference == "montecarlo"
    # a budget between the candidates' errors: the first at or under it, whatever comes after
    budget = sorted(errors)[2]
    mid = run_pilot(found, ball, 100.0, skin, options, budget, len(ball.positions))
    np.testing.assert_allclose([r["rmse_image"] for r in mid.rows], errors)  # deterministic
    assert mid.chosen == next(i for i, e in enumerate(errors) if e <= budget) and mid.met
    tight = run_pilot(found, ball, 100.0, skin, options, 1e-9, len(ball.positions))
    assert not tight.met and tight.chosen == int(np.argmin(errors))


def test_a_veined_medium_is_measured_against_the_same_field_at_twice_the_resolution(tmp_path):
    block = surface_of(tmp_path, trimesh.creation.box(extents=(1.0, 0.5, 0.5)))
    options = BAKE_DEFAULTS.merged({"lpv_field": "marble", "lpv_vein_mm": 20.0})
    found = candidates("lpv", {"lpv_resolution": 16, "lpv_field": "marble"}, options, len(block.positions), False)[:3]
    loose = run_pilot(found, block, 100.0, preset("marble"), options, 0.5, len(block.positions))
    assert loose.reference == LPV_SELF_REFERENCE
    # lpv stops at the first within that beats best-fit Lambert: grids 16 and 24 are within 0.5 but do not
    beaten = [r["beats_lambert"] for r in loose.rows]
    assert loose.met and beaten == [False, False, True] and loose.chosen == 2
    tight = run_pilot(found, block, 100.0, preset("marble"), options, 1e-9, len(block.positions))
    errors = [r["rmse_image"] for r in tight.rows]
    assert len(errors) == 3 and not tight.met and errors == [r["rmse_image"] for r in loose.rows]
    assert errors[2] < errors[0]  # finer grids sit nearer their own 2x


def test_the_pilot_sees_the_mesh_where_its_node_puts_it(tmp_path):
    ball = surface_of(tmp_path, trimesh.creation.icosphere(subdivisions=2, radius=1.0))
    options = BAKE_DEFAULTS
    found = candidates("screen", {}, options, len(ball.positions), True)[:1]
    at_origin = run_pilot(found, ball, 100.0, preset("skin1"), options, 0.5, len(ball.positions))
    moved = np.eye(4)
    moved[:3, 3] = (40.0, -7.0, 3.0)  # the camera follows the object: the same picture
    away = run_pilot(found, ball, 100.0, preset("skin1"), options, 0.5, len(ball.positions), moved)
    np.testing.assert_allclose(away.rows[0]["rmse_image"], at_origin.rows[0]["rmse_image"], rtol=1e-3)
    # a ball turned a quarter round under the same world light looks the same, if the reference
    # is lit from the light's direction in the ball's own frame (from the world one: the wrong side)
    turn = np.eye(4)
    turn[:3, :3] = [[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]
    turned = run_pilot(found, ball, 100.0, preset("skin1"), options, 0.5, len(ball.positions), turn)
    np.testing.assert_allclose(turned.rows[0]["rmse_image"], at_origin.rows[0]["rmse_image"], rtol=0.15)


def test_every_candidate_is_measured_against_best_fit_lambert(tmp_path):
    """A veined block (its reference the same field at twice the grid, whatever the diffusion
    profile): the coarse grids are clearly worse than best-fit Lambert, the finest is not. Without
    a budget every candidate is measured; a margin no grid meets leaves none eligible."""
    block = surface_of(tmp_path, trimesh.creation.box(extents=(1.0, 0.5, 0.5)))
    options = BAKE_DEFAULTS.merged({"lpv_field": "marble", "lpv_vein_mm": 20.0})
    found = candidates("lpv", {"lpv_resolution": 16, "lpv_field": "marble"}, options, len(block.positions), False)[:3]
    pilot = run_pilot(found, block, 100.0, preset("marble"), options, None, len(block.positions))
    rows = pilot.rows
    assert len(rows) == 3 and pilot.met and pilot.chosen == 2  # no budget: all measured, the first eligible
    assert rows[0]["rmse_object"] > 1.4 * rows[0]["lambert_rmse_object"]  # measured 0.211 against 0.118
    assert [beats_lambert(r["rmse_object"], r["lambert_rmse_object"], options.lambert_margin) for r in rows] == \
           [r["beats_lambert"] for r in rows] == [False, False, True]
    for r in rows:  # object RMSE over the object's pixels exceeds the image's, diluted by the background
        assert 0 < r["rmse_image"] < r["rmse_object"] < 1 and 0 < r["lambert_rmse_object"] < 1
    # each grid has its own reference, so best-fit Lambert's figure differs from row to row
    assert len({round(r["lambert_rmse_object"], 6) for r in rows}) == 3
    strict = run_pilot(found, block, 100.0, preset("marble"), options.merged({"lambert_margin": 0.9}), None,
                       len(block.positions))
    assert not any(r["beats_lambert"] for r in strict.rows) and not strict.met
    assert strict.chosen == int(np.argmin([r["rmse_image"] for r in strict.rows]))  # the least RMSE all the same
    assert beats_lambert(0.05, 0.1, 0.4) and not beats_lambert(0.07, 0.1, 0.4) and not beats_lambert(0.1, 0.1, 0.0)
