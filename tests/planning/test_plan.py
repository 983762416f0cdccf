"""The planner on synthetic scenes whose right answer is known: an opaque brick, a nearly opaque
one, a thin leaf, a thick ball, a skinned arm, veined marble; and the command's JSON."""

import json

import numpy as np
import trimesh
from pxr import Usd, UsdGeom, UsdSkel

from sssbake.pipeline.cli import main
from sssbake.pipeline.core.dipole import DipoleParams
from sssbake.pipeline.core.materials import preset
from sssbake.pipeline.options import BAKE_DEFAULTS
from sssbake.pipeline.planning.plan import THIN, plan_asset


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
    leaf = only(plan_asset(mesh_file(tmp_path, "leaf.obj", trimesh.creation.box(extents=(60.0, 60.0, 1.0))),
                           BAKE_DEFAULTS.merged({"material": "skin1", "scale_mm": 1.0})))
    assert leaf.techniques == ("prt",) and "light crosses it" in leaf.reasons[0]
    assert leaf.measures["median_thickness_mm"] < THIN * max(leaf.measures["diffusion_mm"])
    ball = only(plan_asset(mesh_file(tmp_path, "ball.obj", trimesh.creation.icosphere(subdivisions=3, radius=1.0)),
                           BAKE_DEFAULTS.merged({"material": "skin1", "scale_mm": 100.0})))
    assert ball.techniques == ("screen",) and "thick and local" in ball.reasons[0]
    np.testing.assert_allclose(ball.measures["median_thickness_mm"], 200.0, rtol=0.02)  # a diameter


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
    skinned = only(plan_asset(path, BAKE_DEFAULTS.merged({"material": "skin1"})))
    assert skinned.techniques == ("screen",) and "deforming" in skinned.reasons[0]
    # unbound, the same arm is thin and gets prt
    UsdSkel.BindingAPI(mesh.GetPrim()).GetSkeletonRel().ClearTargets(True)
    stage.GetRootLayer().Save()
    assert only(plan_asset(path, BAKE_DEFAULTS.merged({"material": "skin1"}))).techniques == ("prt",)


def test_veined_marble_gets_lpv_with_a_grid_that_resolves_it(tmp_path):
    block = mesh_file(tmp_path, "block.obj", trimesh.creation.box(extents=(300.0, 100.0, 100.0)))
    veined = only(plan_asset(block, BAKE_DEFAULTS.merged({"material": "marble", "scale_mm": 1.0,
                                                          "lpv_field": "marble"})))
    assert veined.techniques == ("lpv",) and veined.params["lpv_field"] == "marble"
    # marble's σ_tr reaches 0.25/mm: 300 mm in cells of at most 2 / σ_tr (38 cells of 7.9 mm)
    sigma_tr = DipoleParams.from_material(preset("marble")).sigma_tr.max()
    assert veined.params["lpv_resolution"] == int(np.ceil(300.0 * sigma_tr / 2.0)) == 38


def test_the_command_prints_the_plan_as_json(tmp_path, capsys):
    mesh_file(tmp_path, "ball.obj", trimesh.creation.icosphere(subdivisions=2, radius=1.0))
    (tmp_path / "broken.obj").write_text("v 0 0\n")
    assert main(["plan", str(tmp_path), "--scale-mm", "100", "--material", "skin1", "--json"]) == 1
    out, err = capsys.readouterr()
    (entry,) = json.loads(out)
    assert {"asset", "material", "techniques", "params", "reasons"} <= set(entry)
    assert entry["techniques"] == ["screen"] and len(entry["reasons"]) == 1
    assert "broken.obj" in err and err.count("\n") == 1


def test_the_command_runs_the_pilot_under_a_budget(tmp_path, capsys):
    mesh_file(tmp_path, "ball.obj", trimesh.creation.icosphere(subdivisions=2, radius=1.0))
    assert main(["plan", str(tmp_path), "--scale-mm", "100", "--material", "skin1", "--budget-rmse", "0.05",
                 "--json"]) == 0
    (entry,) = json.loads(capsys.readouterr().out)
    pilot = entry["pilot"]
    chosen = pilot["candidates"][pilot["chosen"]]
    assert pilot["budget"] == 0.05 and pilot["met"] and pilot["rows"][pilot["chosen"]]["rmse_image"] <= 0.05
    assert entry["techniques"] == [chosen["technique"]] and entry["params"] == chosen["params"]
    assert "pilot on 162 vertices" in entry["reasons"][-1] and len(entry["reasons"]) == 2


def test_bake_auto_runs_what_the_plan_chose_and_reports_it(tmp_path, capsys):
    src = tmp_path / "in"
    src.mkdir()
    mesh_file(src, "leaf.obj", trimesh.creation.box(extents=(0.6, 0.6, 0.01)))  # 60 x 60 x 1 mm
    mesh_file(src, "ball.obj", trimesh.creation.icosphere(subdivisions=3, radius=1.0))  # 200 mm across
    out = tmp_path / "out"
    assert main(["bake", str(src), "-o", str(out), "--scale-mm", "100", "--material", "skin1",
                 "--techniques", "auto", "--prt-directions", "16", "--no-validate", "-q"]) == 0
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
    generous = only(plan_asset(path, options.merged({"max_bytes_per_vertex": 40.0})))
    assert generous.techniques == ("prt",) and generous.params == {"prt_byte_budget": 40.0, "prt_reference_floor": 0}
    tight = only(plan_asset(path, options.merged({"max_bytes_per_vertex": 2.0})))
    assert tight.techniques == ("screen",) and "prt needs at least" in tight.reasons[0]


def test_the_bake_applies_the_plans_parameters_and_says_when_a_budget_did_not_hold(tmp_path):
    src = tmp_path / "in"
    src.mkdir()
    for name, thickness in (("slab.obj", 8.0), ("leaf.obj", 1.0)):
        mesh = trimesh.creation.box(extents=(60.0, 60.0, thickness))
        for _ in range(3):
            mesh = mesh.subdivide()
        mesh_file(src, name, mesh)
    out = tmp_path / "out"
    assert main(["bake", str(src), "-o", str(out), "--scale-mm", "1", "--material", "skin1", "--techniques", "auto",
                 "--prt-directions", "16", "--max-bytes-per-vertex", "30", "--no-validate", "-q"]) == 0
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
