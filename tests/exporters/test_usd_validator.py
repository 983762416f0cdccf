"""USD validation: our output is clean; real problems are reported as errors."""

from dataclasses import replace
from pathlib import Path

import numpy as np
from pxr import Sdf, Usd, UsdGeom, UsdShade
from test_usd import icosphere_asset

from sssbake.exporters.usd import write_usdc
from sssbake.exporters.usd_validator import MESH_CHECKER, mesh_problems, validate_stage, validate_usd
from sssbake.pipeline.mesh.scene import Mesh, Node, Scene


def minimal_stage(path: Path, binding_api: bool = True, metadata: bool = True) -> Path:
    """Save a one-triangle mesh bound to a UsdPreviewSurface material at `path`; returns `path`."""
    stage = Usd.Stage.CreateNew(str(path))
    if metadata:
        UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
        UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    root = UsdGeom.Xform.Define(stage, "/Root")
    stage.SetDefaultPrim(root.GetPrim())
    mesh = UsdGeom.Mesh.Define(stage, "/Root/Tri")
    mesh.CreatePointsAttr([(0, 0, 0), (1, 0, 0), (0, 1, 0)])
    mesh.CreateFaceVertexCountsAttr([3])
    mesh.CreateFaceVertexIndicesAttr([0, 1, 2])
    material = UsdShade.Material.Define(stage, "/Root/Mat")
    shader = UsdShade.Shader.Define(stage, "/Root/Mat/Surface")
    shader.CreateIdAttr("UsdPreviewSurface")
    material.CreateSurfaceOutput().ConnectToSource(shader.ConnectableAPI(), "surface")
    if binding_api:
        UsdShade.MaterialBindingAPI.Apply(mesh.GetPrim()).Bind(material)
    else:
        # Authoring the relationship without applying the schema is what the validator catches.
        mesh.GetPrim().CreateRelationship("material:binding").SetTargets([material.GetPath()])
    stage.GetRootLayer().Save()
    return path


def test_our_output_is_clean(tmp_path):
    write_usdc(icosphere_asset(extras={"lut": np.ones((4, 2))}), tmp_path / "a.usdc")
    report = validate_usd(tmp_path / "a.usdc")
    assert report.errors == () and report.warnings == (), report
    assert report.ok


def test_output_without_materials_and_multi_primitive_mesh_is_clean(tmp_path):
    asset = icosphere_asset()
    sphere = asset.scene.meshes[0].primitives[0]
    split = (replace(sphere, material=None), replace(sphere, faces=sphere.faces[:5], material=None))
    scene = Scene("memory", (Mesh("", split),), (Node("", mesh=0),), (0,), up_axis="Z")
    write_usdc(replace(asset, scene=scene, scattering={}, vertex_attributes={}, scale_mm={}), tmp_path / "b.usdc")
    assert validate_usd(tmp_path / "b.usdc").errors == ()


def test_minimal_correct_stage_is_clean(tmp_path):
    assert validate_usd(minimal_stage(tmp_path / "ok.usda")).errors == ()


def test_missing_material_binding_api_is_an_error(tmp_path):
    report = validate_usd(minimal_stage(tmp_path / "bad.usda", binding_api=False))
    assert len(report.errors) == 1
    assert report.errors[0].startswith("usdShadeValidators:MaterialBindingApiAppliedValidator: ")
    assert "[at /Root/Tri]" in report.errors[0]


def test_missing_stage_metadata_is_an_error(tmp_path):
    report = validate_usd(minimal_stage(tmp_path / "bad.usda", metadata=False))
    assert sum("usdGeomValidators:StageMetadataChecker" in e for e in report.errors) == 2
    assert any("metersPerUnit" in e for e in report.errors) and any("upAxis" in e for e in report.errors)


def test_element_counts_are_checked(tmp_path):
    stage = Usd.Stage.Open(str(minimal_stage(tmp_path / "counts.usda")))
    mesh = UsdGeom.Mesh(stage.GetPrimAtPath("/Root/Tri"))
    api = UsdGeom.PrimvarsAPI(mesh)
    api.CreatePrimvar("sss:thickness", Sdf.ValueTypeNames.FloatArray, UsdGeom.Tokens.vertex).Set([1.0, 2.0])
    api.CreatePrimvar("sss:dir", Sdf.ValueTypeNames.FloatArray, UsdGeom.Tokens.vertex, 3).Set([0.0] * 9)
    st = api.CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray, UsdGeom.Tokens.faceVarying)
    st.Set([(0, 0), (1, 1)])
    st.SetIndices([0, 1, 5])
    mesh.CreateNormalsAttr([(0, 0, 1)] * 4)
    mesh.SetNormalsInterpolation(UsdGeom.Tokens.vertex)
    mesh.CreateFaceVertexIndicesAttr([0, 1, 2, 3])
    problems = mesh_problems(stage)
    assert problems == [
        "faceVertexCounts sum to 3, faceVertexIndices has 4 [at /Root/Tri]",
        "faceVertexIndices outside [0, 3) [at /Root/Tri]",
        "normals has 4 elements, vertex interpolation needs 3 [at /Root/Tri]",
        "primvars:sss:thickness has 2 elements, vertex interpolation × elementSize 1 needs 3 [at /Root/Tri]",
        "primvars:st:indices has 3 elements, faceVarying interpolation × elementSize 1 needs 4 [at /Root/Tri]",
        "primvars:st:indices outside [0, 2) [at /Root/Tri]",
    ]
    report = validate_stage(stage, "counts")
    assert [e for e in report.errors if e.startswith(MESH_CHECKER + ": ")] == [f"{MESH_CHECKER}: {p}" for p in problems]


def test_unreadable_file_is_one_error(tmp_path):
    path = tmp_path / "broken.usda"
    path.write_text("#usda 1.0\ndef Mesh \"M\" {\n    point3f[] points = [(0, 0 }\n")
    report = validate_usd(path)
    assert len(report.errors) == 1 and report.errors[0].startswith("sssbake:StageOpen: line 3:")
    assert "\n" not in report.errors[0]
