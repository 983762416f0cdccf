"""Reading the lpv grids back from the files the bake writes: the glb and the usdc give the
stage's grid, matrices and scales; the command line's lpv flags reach the stage."""

import json
from importlib import resources

import jsonschema
import numpy as np
import pygltflib
import pytest
import trimesh

from sssbake.pipeline.cli import main
from sssbake.pipeline.techniques.lpv.reader import LpvReadError, read_lpv_glb, read_lpv_usd


@pytest.fixture(scope="module")
def baked(tmp_path_factory):
    folder = tmp_path_factory.mktemp("read_lpv")
    trimesh.creation.icosphere(subdivisions=2, radius=5.0).export(folder / "ball.obj")
    assert main(["bake", str(folder / "ball.obj"), "-o", str(folder / "out"), "--scale-mm", "2", "--material",
                 "marble", "--techniques", "lpv", "--lpv-resolution", "10", "--lpv-field", "marble",
                 "--lpv-vein-mm", "6", "--lpv-max-steps", "20", "-q"]) == 0
    return folder / "out"


def test_glb_and_usd_hold_the_same_grid(baked):
    (glb,) = read_lpv_glb(baked / "ball.glb").values()
    (usd,) = read_lpv_usd(baked / "ball.usdc").values()
    for a, b in zip(glb, usd):
        if isinstance(a, np.ndarray):
            np.testing.assert_array_equal(a, b)
    grid, matrices, scales = glb
    assert grid.shape == (12, 12, 12) and grid.mm_per_unit == 2.0 and scales.shape == (20, 3)
    for name in ("occupancy", "sigma_t", "albedo", "g"):
        np.testing.assert_array_equal(getattr(grid, name), getattr(usd[0], name))
    np.testing.assert_allclose(grid.origin, usd[0].origin)
    report = json.loads((baked / "ball.report.json").read_text())
    (entry,) = report["lpv"].values()
    assert entry["field"] == "marble" and entry["shape"] == [12, 12, 12] and entry["maxSteps"] == 20
    assert report["stages"]["lpv"]["runs"] == 1
    assert report["validation"]["gltf"]["errors"] == 0 and report["validation"]["usd"]["errors"] == 0


def test_the_block_matches_the_documented_schema(baked):
    schema = json.loads(resources.files("sssbake.exporters").joinpath("schema/sssbake.schema.json").read_text())
    mesh = pygltflib.GLTF2.load(str(baked / "ball.glb")).meshes[0].extensions["SSSBAKE_subsurface"]
    jsonschema.Draft202012Validator({"$defs": schema["$defs"], "$ref": "#/$defs/mesh"}).validate(mesh)
    assert mesh["lpv"]["technique"] == "lpv"
    broken = {**mesh, "lpv": {**mesh["lpv"], "field": "wood"}}
    with pytest.raises(jsonschema.ValidationError):
        jsonschema.Draft202012Validator({"$defs": schema["$defs"], "$ref": "#/$defs/mesh"}).validate(broken)


def test_files_without_lpv_and_bad_flags_are_refused(baked, tmp_path, capsys):
    trimesh.creation.box().export(tmp_path / "box.obj")
    assert main(["bake", str(tmp_path / "box.obj"), "-o", str(tmp_path / "out"), "--scale-mm", "2", "-q",
                 "--no-validate"]) == 0
    with pytest.raises(LpvReadError, match="bake with --techniques lpv"):
        read_lpv_glb(tmp_path / "out" / "box.glb")
    capsys.readouterr()
    assert main(["bake", str(tmp_path / "box.obj"), "-o", str(tmp_path / "bad"), "--scale-mm", "2",
                 "--techniques", "lpv", "--lpv-resolution", "1", "-q"]) != 0
    assert "lpv grid: resolution" in capsys.readouterr().err
