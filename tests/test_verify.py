"""verify: the prt export against the offline reference, end to end through the command line."""

import json
from pathlib import Path

import numpy as np

from generate import generate
from sssbake.pipeline.cli import main

KEYS = {"technique", "light_dir", "rmse_image", "rmse_object", "rmse_object_lambert", "bytes_per_vertex",
        "bake_seconds", "frame_ms_sss", "frame_ms_plain"}


def test_uncompressed_prt_beats_lambert_against_the_reference(tmp_path, capsys):
    src = tmp_path / "in"
    generate(src)
    out = tmp_path / "out"
    assert main(["bake", str(src / "sphere.obj"), "-o", str(out), "--config", str(src / "sssbake.toml"),
                 "--techniques", "prt", "--prt-mode", "lloyd", "--prt-directions", "100", "-q"]) == 0
    capsys.readouterr()
    assert main(["verify", str(out / "sphere.glb"), "--size", "96", "--frames", "2", "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert KEYS <= set(result)
    assert result["technique"] == "prt" and np.isclose(np.linalg.norm(result["light_dir"]), 1.0)
    # 8-bit tables and 100 interpolated directions stay close to the exact sum; Lambert does not
    assert result["rmse_object"] < 0.02
    assert result["rmse_object"] < 0.75 * result["rmse_object_lambert"]
    assert result["rmse_image"] <= result["rmse_object"]
    assert Path(result["pngs"]["comparison"]).stat().st_size > 0
    # A point light: per-vertex direction and 1/d² falloff in the runtime and in the reference.
    assert main(["verify", str(out / "sphere.glb"), "--size", "96", "--frames", "2", "--json",
                 "--light-pos", "25,15,20"]) == 0  # the ball has radius 10, centred at the origin
    point = json.loads(capsys.readouterr().out)
    assert point["light_pos"] == [25.0, 15.0, 20.0]
    assert np.allclose(point["light_dir"], np.array([25.0, 15.0, 20.0]) / np.linalg.norm([25.0, 15.0, 20.0]), atol=0.05)
    assert point["rmse_object"] < 0.03 and point["rmse_object"] < 0.75 * point["rmse_object_lambert"]
    # The clustered reference (for big meshes) gives nearly the same figures.
    assert main(["verify", str(out / "sphere.glb"), "--size", "96", "--frames", "2", "--json",
                 "--reference", "clustered"]) == 0
    clustered = json.loads(capsys.readouterr().out)
    assert clustered["reference"] == "clustered" and result["reference"] == "exact"
    assert abs(clustered["rmse_object"] - result["rmse_object"]) < 0.1 * result["rmse_object"]
    assert main(["verify", str(out / "sphere.glb"), "--light-pos", "1,2"]) == 1
    assert "--light-pos takes three comma-separated numbers" in capsys.readouterr().err
    assert main(["verify", str(out / "sphere.glb"), "--light-pos", "2,1,1"]) == 1  # inside the ball
    assert "the light reaches no vertex" in capsys.readouterr().err


def test_files_without_prt_get_a_clear_error(tmp_path, capsys):
    src = tmp_path / "in"
    generate(src)
    out = tmp_path / "out"
    assert main(["bake", str(src / "sphere.obj"), "-o", str(out), "--config", str(src / "sssbake.toml"), "-q"]) == 0
    capsys.readouterr()
    assert main(["verify", str(out / "sphere.glb")]) == 1
    assert "bake with --techniques prt" in capsys.readouterr().err
    assert main(["verify", str(src / "sphere.obj")]) == 2


def test_kernels_export_renders_close_to_the_reference_and_blending_matters(tmp_path, capsys):
    src = tmp_path / "in"
    generate(src)
    results = {}
    for blend in ("optimised", "none"):
        out = tmp_path / blend
        assert main(["bake", str(src / "sphere.obj"), "-o", str(out), "--config", str(src / "sssbake.toml"),
                     "--techniques", "kernels", "--atlas-resolution", "128", "--kernels-blend", blend, "-q"]) == 0
        capsys.readouterr()
        assert main(["verify", str(out / "sphere.glb"), "--technique", "kernels", "--size", "96", "--frames", "2",
                     "--json"]) == 0
        results[blend] = json.loads(capsys.readouterr().out)
        report = json.loads((out / "sphere.report.json").read_text())
        (mesh_report,) = report["kernels"].values()
        assert results[blend]["bytes_per_vertex"] == mesh_report["bytes"]["perVertex"] > 0
    result = results["optimised"]
    assert KEYS <= set(result) and result["technique"] == "kernels"
    assert result["rmse_object"] < min(0.02, result["rmse_object_lambert"])
    # local and global responses simply added count the light twice where it enters (§5.4)
    assert results["none"]["rmse_object"] > 2 * result["rmse_object"]
    assert main(["verify", str(tmp_path / "optimised" / "sphere.glb"), "--technique", "prt"]) == 1
    assert "bake with --techniques prt" in capsys.readouterr().err
