"""The planner on synthetic scenes whose right answer is known: an opaque brick, a nearly opaque
one, a thin leaf, a thick ball, a skinned arm, veined marble; the pilot's check against best-fit
Lambert, which ships the fallback alone where the planned technique does not beat it; and the
command's JSON."""

import json

import numpy as np
import trimesh
from pxr import Usd, UsdGeom, UsdSkel

from sssbake.pipeline.cli import main
from sssbake.pipeline.core.profile import profile_for
from sssbake.pipeline.core.materials import preset
from sssbake.pipeline.options import BAKE_DEFAULTS
from sssbake.pipeline.planning.plan import PHYSICS_LIMITS, THIN, lambert_line, plan_asset, worse_than_lambert


def mesh_file(folder, name, mesh):
    path = folder / name
    mesh.export(path)
    return path


def only(entries):
    (entry,) = entries
    return entry


def test_opaque_and_nearly_opaque_bricks_get_no_scattering_data(tmp_path):
    brick = mesh_file(tmp_path, "brick.obj", trimesh.creation.box(extents=(200.0, 100.0, 60.0)))
    opaque = only(plan_asset(brick, BAKE_DEFAULTS.merged({"material": "opaque", "scale_mm": 1.0})))
    assert opaque.techniques == () and opaque.reasons[0].startswith("opaque")
    # a mean free path of 1 um: half of R_d within microns, far under a 0.45 mm texel
    dense = {"albedo": [0.5, 0.5, 0.5], "mean_free_path_mm": [0.001, 0.001, 0.001], "eta": 1.5}
    nearly = only(plan_asset(brick, BAKE_DEFAULTS.merged({"material": dense, "scale_mm": 1.0})))
    assert nearly.techniques == () and "nearly opaque" in nearly.reasons[0]
    assert nearly.measures["median_radius_mm"] < nearly.measures["texel_mm"]


def test_a_thin_leaf_needs_a_global_technique_and_a_thick_ball_a_local_one(tmp_path):
    """Both beat best-fit Lambert on the pilot by far and ship, the reason giving both figures."""
    leaf = only(plan_asset(mesh_file(tmp_path, "leaf.obj", trimesh.creation.box(extents=(60.0, 60.0, 1.0)).subdivide()),
                           BAKE_DEFAULTS.merged({"material": "skin1", "scale_mm": 1.0})))
    assert leaf.techniques == ("prt",) and "light crosses it" in leaf.reasons[0]
    assert leaf.measures["median_thickness_mm"] < THIN * max(leaf.measures["diffusion_mm"])
    ball = only(plan_asset(mesh_file(tmp_path, "ball.obj", trimesh.creation.icosphere(subdivisions=3, radius=1.0)),
                           BAKE_DEFAULTS.merged({"material": "skin1", "scale_mm": 100.0})))
    assert ball.techniques == ("screen",) and "thick and local" in ball.reasons[0]
    # each choice says what it is known to miss against physics (docs/fidelity.md), and only its own
    assert f"; prt; {PHYSICS_LIMITS['prt']}; " in leaf.reasons[0] and "screen misses" not in leaf.reasons[0]
    assert ball.reasons[0].endswith(f"; screen, nothing per vertex; {PHYSICS_LIMITS['screen']}")
    # 1 mm of skin1 is under 3 reduced mean free paths (red: 1/σ'_t = 1.3 mm): crossed in a few
    # scatterings, which no technique models; 200 mm is not
    np.testing.assert_allclose(leaf.measures["free_path_mm"], 1.0 / (0.74 + 0.032), rtol=1e-6)
    assert leaf.reasons[0].endswith("which diffusion does not model, so against physics every technique may lose to "
                                    "best-fit Lambert (docs/fidelity.md)")
    assert "mean free paths" not in ball.reasons[0]
    np.testing.assert_allclose(ball.measures["median_thickness_mm"], 200.0, rtol=0.02)  # a diameter
    # measured: prt 0.0081 against Lambert's 0.0909 on the leaf's 26 vertices, screen 0.0041 against 0.0151
    for entry, technique, vertices in ((leaf, "prt", 26), (ball, "screen", 642)):
        check = entry.lambert_check
        assert check["technique"] == technique and check["shipped"] and check["beats_lambert"]
        assert check["vertices"] == vertices and check["reference"] == "montecarlo" and check["margin"] == 0.1
        assert 0 < check["rmse_object"] < 0.5 * check["lambert_rmse_object"] < 0.5
        assert len(entry.reasons) == 2 and entry.reasons[1] == (
            f"pilot on {vertices} vertices, object RMSE against the montecarlo reference: {check['label']} "
            f"{check['rmse_object']:.4f}, best-fit Lambert {check['lambert_rmse_object']:.4f}: under 0.9 x Lambert's, "
            "shipped")
    assert leaf.lambert_check["label"] == "prt (planned, 26 reference points)"  # the floor's 256, capped at 26


def test_a_skinned_arm_gets_no_per_vertex_bake(tmp_path):
    path = tmp_path / "arm.usda"
    stage = Usd.Stage.CreateNew(str(path))
    UsdGeom.SetStageMetersPerUnit(stage, 0.001)
    UsdSkel.Root.Define(stage, "/Arm")
    skeleton = UsdSkel.Skeleton.Define(stage, "/Arm/Skeleton")
    skeleton.CreateJointsAttr(["shoulder"])
    arm = trimesh.creation.cylinder(radius=4.0, height=60.0)  # thin for skin: prt if it did not deform
    mesh = UsdGeom.Mesh.Define(stage, "/Arm/Mesh")
    mesh.CreatePointsAttr([tuple(map(float, v)) for v in arm.vertices])
    mesh.CreateFaceVertexCountsAttr([3] * len(arm.faces))
    mesh.CreateFaceVertexIndicesAttr([int(i) for i in arm.faces.reshape(-1)])
    UsdSkel.BindingAPI.Apply(mesh.GetPrim()).CreateSkeletonRel().SetTargets([skeleton.GetPath()])
    stage.GetRootLayer().Save()
    # what the rules plan (the pilot's check then ships it or the fallback: `lambert_check`)
    skinned = only(plan_asset(path, BAKE_DEFAULTS.merged({"material": "skin1"})))
    assert skinned.lambert_check["technique"] == "screen" and "deforming" in skinned.reasons[0]
    # unbound, the same arm is thin and gets prt
    UsdSkel.BindingAPI(mesh.GetPrim()).GetSkeletonRel().ClearTargets(True)
    stage.GetRootLayer().Save()
    unbound = only(plan_asset(path, BAKE_DEFAULTS.merged({"material": "skin1"})))
    assert unbound.lambert_check["technique"] == "prt" and "light crosses it" in unbound.reasons[0]


def test_veined_marble_gets_lpv_with_a_grid_that_resolves_it_but_lpv_worse_than_lambert_ships_the_fallback(
        tmp_path, capsys):
    block = mesh_file(tmp_path, "block.obj", trimesh.creation.box(extents=(300.0, 100.0, 100.0)))
    options = {"material": "marble", "scale_mm": 1.0, "lpv_field": "marble"}
    veined = only(plan_asset(block, BAKE_DEFAULTS.merged(options)))
    check = veined.lambert_check
    assert check["technique"] == "lpv" and check["params"]["lpv_field"] == "marble"
    # marble's σ_tr reaches 0.25/mm: 300 mm in cells of at most 2 / σ_tr (38 cells of 7.9 mm)
    sigma_tr = profile_for(preset("marble")).sigma_tr.max()
    assert check["params"]["lpv_resolution"] == int(np.ceil(300.0 * sigma_tr / 2.0)) == 38
    # against its own reference (the same field at twice the grid, whatever the diffusion profile) the
    # grid is clearly worse than best-fit Lambert (measured 0.3045 against 0.1279): the fallback alone
    assert check["rmse_object"] > 1.5 * check["lambert_rmse_object"] > 0 and not check["beats_lambert"]
    assert veined.techniques == () and veined.params == {} and not check["shipped"]
    assert "grid 38" in veined.reasons[0] and len(veined.reasons) == 2
    why = veined.reasons[1]
    assert why.startswith("pilot on 8 vertices, object RMSE against the lpv 2x") and why.endswith(
        f"lpv (planned) {check['rmse_object']:.4f}, best-fit Lambert {check['lambert_rmse_object']:.4f}: "
        "not under 0.9 x Lambert's; the standard fallback only")
    # `sssbake plan` prints the same, and its JSON keeps its fields and adds the check
    config = tmp_path / "veined.toml"
    config.write_text('[defaults]\nmaterial = "marble"\nscale_mm = 1.0\nlpv_field = "marble"\n')
    assert main(["plan", str(block), "--config", str(config)]) == 0
    out = capsys.readouterr().out
    assert out.count("\n") == 1 and "block.obj / sssbake_default: no SSS data" in out and why in out
    assert main(["plan", str(block), "--config", str(config), "--json"]) == 0
    (entry,) = json.loads(capsys.readouterr().out)
    assert {"asset", "mesh", "material", "techniques", "params", "reasons", "measures", "lambert_check"} == set(entry)
    assert entry["lambert_check"] == check and entry["reasons"] == list(veined.reasons)


def test_the_margin_over_best_fit_lambert_is_an_option_and_a_bad_one_one_line(tmp_path, capsys):
    ball = mesh_file(tmp_path, "ball.obj", trimesh.creation.icosphere(subdivisions=3, radius=1.0))
    strict = only(plan_asset(ball, BAKE_DEFAULTS.merged({"material": "skin1", "scale_mm": 100.0,
                                                         "lambert_margin": 0.9})))
    check = strict.lambert_check
    # screen is better than Lambert (measured 0.0041 against 0.0151) but not ten times better
    assert check["rmse_object"] < check["lambert_rmse_object"] and check["margin"] == 0.9
    assert not check["beats_lambert"] and strict.techniques == () and "not under 0.1 x Lambert's" in strict.reasons[1]
    assert main(["plan", str(ball), "--scale-mm", "100", "--lambert-margin", "1.5"]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("error: ") and "lambert_margin must be a finite number below 1, " \
        "got 1.5" in err


def test_the_summary_counts_what_shipped_worse_than_best_fit_lambert():
    def check(technique, rmse, lambert, shipped=True):
        return {"mesh": "m", "material": "x", "technique": technique, "rmse_object": rmse,
                "lambert_rmse_object": lambert, "shipped": shipped}

    report = {"lambert_checks": [check("prt", 0.05, 0.04), check("screen", 0.01, 0.04),
                                 check("lpv", 0.04, 0.04),  # no better at all: worse
                                 check("lpv", 0.3, 0.1, shipped=False)]}  # the planner shipped the fallback
    marks = [{"asset": "/in/a.obj", **m} for m in worse_than_lambert(report)]
    assert [m["technique"] for m in marks] == ["prt", "lpv"]
    marks.append({"asset": "b.glb", "technique": "lpv", "rmse_object": 0.0556, "lambert_rmse_object": 0.054})
    assert lambert_line(marks, "on the pilot's subsample") == (
        "3 techniques worse than best-fit Lambert (object RMSE on the pilot's subsample): a.obj m/x prt 0.0500 "
        "against 0.0400; a.obj m/x lpv 0.0400 against 0.0400; b.glb lpv 0.0556 against 0.0540")
    assert lambert_line(marks[:1], "here").startswith("1 technique worse")
    assert lambert_line([], "here") is None and worse_than_lambert({}) == []  # a report from before the check


def test_the_command_prints_the_plan_as_json(tmp_path, capsys):
    mesh_file(tmp_path, "ball.obj", trimesh.creation.icosphere(subdivisions=3, radius=1.0))
    (tmp_path / "broken.obj").write_text("v 0 0\n")
    assert main(["plan", str(tmp_path), "--scale-mm", "100", "--material", "skin1", "--json"]) == 1
    out, err = capsys.readouterr()
    (entry,) = json.loads(out)
    assert {"asset", "material", "techniques", "params", "reasons"} <= set(entry)
    assert entry["techniques"] == ["screen"] and len(entry["reasons"]) == 2 and entry["lambert_check"]["shipped"]
    assert "broken.obj" in err and err.count("\n") == 1


def test_the_command_runs_the_pilot_under_a_budget(tmp_path, capsys):
    mesh_file(tmp_path, "ball.obj", trimesh.creation.icosphere(subdivisions=3, radius=1.0))
    assert main(["plan", str(tmp_path), "--scale-mm", "100", "--material", "skin1", "--budget-rmse", "0.05",
                 "--json"]) == 0
    (entry,) = json.loads(capsys.readouterr().out)
    pilot = entry["pilot"]
    chosen = pilot["candidates"][pilot["chosen"]]
    row = pilot["rows"][pilot["chosen"]]
    assert pilot["budget"] == 0.05 and pilot["met"] and row["rmse_image"] <= 0.05 and row["beats_lambert"]
    assert entry["techniques"] == [chosen["technique"]] and entry["params"] == chosen["params"]
    assert "pilot on 642 vertices, image RMSE" in entry["reasons"][1] and len(entry["reasons"]) == 3
    assert entry["lambert_check"]["rmse_object"] == row["rmse_object"] and "shipped" in entry["reasons"][2]


def test_bake_auto_runs_what_the_plan_chose_and_reports_it(tmp_path, capsys):
    src = tmp_path / "in"
    src.mkdir()
    mesh_file(src, "leaf.obj", trimesh.creation.box(extents=(0.6, 0.6, 0.01)).subdivide())  # 60 x 60 x 1 mm
    mesh_file(src, "ball.obj", trimesh.creation.icosphere(subdivisions=3, radius=1.0))  # 200 mm across
    out = tmp_path / "out"
    assert main(["bake", str(src), "-o", str(out), "--scale-mm", "100", "--material", "skin1",
                 "--techniques", "auto", "--prt-directions", "48", "--no-validate", "-q"]) == 0
    leaf = json.loads((out / "leaf.report.json").read_text())
    ball = json.loads((out / "ball.report.json").read_text())
    assert [e["techniques"] for e in leaf["plan"]] == [["prt"]] and [e["techniques"] for e in ball["plan"]] == [["screen"]]
    assert leaf["stages"]["prt"]["runs"] == 1 and "plan chose it for no object" in leaf["stages"]["screen"]["skipped"]
    assert ball["stages"]["screen"]["runs"] == 1 and "skipped" in ball["stages"]["prt"]
    assert leaf["prt"] and not leaf["screen"] and ball["screen"] and not ball["prt"]
    assert main(["bake", str(src), "-o", str(out), "--scale-mm", "100", "--techniques", "auto,prt", "-q"]) != 0
    assert "auto plans every technique itself" in capsys.readouterr().err


def test_a_byte_budget_goes_to_prt_or_turns_it_down(tmp_path):
    leaf = trimesh.creation.box(extents=(60.0, 60.0, 1.0))
    for _ in range(4):
        leaf = leaf.subdivide()
    path = mesh_file(tmp_path, "leaf.obj", leaf)
    options = BAKE_DEFAULTS.merged({"material": "skin1", "scale_mm": 1.0, "prt_directions": 16})
    # what the rules plan (the pilot's check then ships it or the fallback: `lambert_check`)
    generous = only(plan_asset(path, options.merged({"max_bytes_per_vertex": 40.0})))
    assert generous.lambert_check["technique"] == "prt" and "prt within 40 bytes" in generous.reasons[0]
    assert generous.lambert_check["params"] == {"prt_byte_budget": 40.0, "prt_reference_floor": 0}
    tight = only(plan_asset(path, options.merged({"max_bytes_per_vertex": 2.0})))
    assert tight.lambert_check["technique"] == "screen" and "prt needs at least" in tight.reasons[0]


def test_the_bake_applies_the_plans_parameters_and_says_when_a_budget_did_not_hold(tmp_path):
    src = tmp_path / "in"
    src.mkdir()
    for name, thickness in (("slab.obj", 8.0), ("leaf.obj", 1.0)):
        mesh = trimesh.creation.box(extents=(60.0, 60.0, thickness))
        for _ in range(3):
            mesh = mesh.subdivide()
        mesh_file(src, name, mesh)
    out = tmp_path / "out"
    # about the byte budget, not the check against best-fit Lambert: prt on these slabs measured within 15 % of
    # Lambert either way, so the margin tolerates up to twice Lambert's RMSE
    assert main(["bake", str(src), "-o", str(out), "--scale-mm", "1", "--material", "skin1", "--techniques", "auto",
                 "--prt-directions", "16", "--max-bytes-per-vertex", "30", "--lambert-margin", "-1", "--no-validate",
                 "-q"]) == 0
    slab = json.loads((out / "slab.report.json").read_text())
    assert slab["plan"][0]["params"]["prt_byte_budget"] == 30.0 and slab["prt"]["slab.obj"]["byteBudget"] == 30.0
    assert slab["prt"]["slab.obj"]["bytesPerVertex"]["total"] <= 30.0 and not slab["warnings"]
    # 1 mm thin: fast-simplification will not collapse its faces far enough, and the report says so
    leaf = json.loads((out / "leaf.report.json").read_text())
    assert leaf["prt"]["leaf.obj"]["bytesPerVertex"]["total"] > 30.0
    assert any("over its 30 B/vertex budget" in w for w in leaf["warnings"])


def test_the_median_thickness_is_weighted_by_area():
    from sssbake.pipeline.planning.plan import area_median

    # many small rim vertices of 60 mm against a few big-face vertices of 1 mm
    values, areas = np.array([60.0] * 9 + [1.0] * 3), np.array([0.1] * 9 + [10.0] * 3)
    assert area_median(values, areas) == 1.0 and np.median(values) == 60.0
    assert area_median(np.array([3.0, 1.0, 2.0]), np.ones(3)) == 2.0
