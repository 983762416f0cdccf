"""spectral tradeoff: each sweep moves its knob alone, a filter of width 0 is the plain-Lambert
baseline exactly, subsurface normals beat the file's on a bumpy ball, and the results are written
as JSON/CSV/plot."""

import json
import math
from pathlib import Path

import numpy as np
import pytest
import trimesh
from fixtures import assert_tradeoff_written

from sssbake.pipeline.cli import main
from sssbake.pipeline.core.materials import preset
from sssbake.pipeline.techniques.spectral.precompute import SpectralPrecomputeOptions
from sssbake.pipeline.techniques.spectral.tradeoff import NORMAL_BYTES, spectral_tradeoff

# A unit ball with bumps of ~0.6 units (6 mm at 10 mm per unit) against skin1's ~1.3 mm filter width.
MM = 10.0
SWEEPS = dict(eigenpairs=(20, 60), width_factors=(0.0, 1.0, 4.0), alphas=(0.5, 2.0))


@pytest.fixture(scope="module")
def bumpy(tmp_path_factory):
    path = tmp_path_factory.mktemp("spectral_tradeoff") / "bumpy.obj"
    ball = trimesh.creation.icosphere(subdivisions=3)
    v = ball.vertices
    trimesh.Trimesh(v * (1 + 0.04 * np.sin(7 * v[:, 0]) * np.cos(5 * v[:, 1]))[:, None], ball.faces).export(path)
    return path


@pytest.fixture(scope="module")
def result(bumpy):
    return spectral_tradeoff(bumpy, MM, preset("skin1"), bumpy.parent / "out", lights=2, size=64,
                             options=SpectralPrecomputeOptions(eigenpairs=60), **SWEEPS)


def sweep(result, name):
    return [r for r in result["rows"] if r["sweep"] == name]


def test_each_sweep_varies_its_knob_alone(result):
    rows = result["rows"]
    assert [r["sweep"] for r in rows] == ["plain", "default", "eigenpairs", "eigenpairs", "width", "width", "width",
                                          "naive_alpha", "naive_alpha"]
    plain, default = rows[:2]
    assert (plain["normals"], plain["bytes_per_vertex"], plain["seconds"]) == ("file", 0.0, 0.0)
    assert (default["normals"], default["eigenpairs"], default["width_factor"]) == ("spectral", 60, 1.0)
    assert [r["eigenpairs"] for r in sweep(result, "eigenpairs")] == [20, 60]
    assert all(r["width_factor"] == 1.0 and r["width_mm"] == default["width_mm"] for r in sweep(result, "eigenpairs"))
    # the default's configuration is measured once and its row reused
    assert {**sweep(result, "eigenpairs")[1], "sweep": "default"} == default
    widths = sweep(result, "width")
    assert [r["width_factor"] for r in widths] == [0.0, 1.0, 4.0]
    assert all(r["eigenpairs"] == 60 for r in widths)
    assert np.allclose([r["width_mm"] for r in widths], np.array([0.0, 1.0, 4.0]) * default["width_mm"])
    assert widths[1]["rmse_image"] == default["rmse_image"]  # the same normals, re-filtered
    assert [(r["normals"], r["alpha"]) for r in sweep(result, "naive_alpha")] == [("naive", 0.5), ("naive", 2.0)]
    assert all(r["bytes_per_vertex"] == NORMAL_BYTES and r["seconds"] > 0 for r in rows[1:])


def test_a_zero_width_filter_gives_back_the_plain_baseline(result):
    plain, zero = result["rows"][0], sweep(result, "width")[0]
    # F ≡ 1 and γ = 1 return the file's normals: the same image, fit and RMSE
    assert zero["rmse_image"] == plain["rmse_image"] and zero["scale"] == plain["scale"]


def test_subsurface_normals_beat_the_plain_baseline(result):
    plain, default = result["rows"][:2]
    assert all(math.isfinite(r["rmse_image"]) and r["rmse_image"] > 0 for r in result["rows"])
    # measured 0.0117 plain, 0.0089 spectral, 0.0094 naive (α = 0.5)
    assert default["rmse_image"] < 0.85 * plain["rmse_image"]
    assert sweep(result, "naive_alpha")[0]["rmse_image"] < plain["rmse_image"]
    # per-channel fits: skin1 scatters red furthest, so its Lambert needs the most red
    scale = np.array(default["scale"])
    assert np.all(scale > 0) and scale[0] > scale[1] > scale[2]
    # zero runtime cost: the same shader on the same mesh
    assert result["frame_ms_sss"] > 0 and result["frame_ms_plain"] > 0 and 0.5 < result["frame_ratio"] < 2.0


def test_results_are_written(result):
    assert_tradeoff_written(result, "bumpy.tradeoff.spectral.json")


def test_cli_runs_the_spectral_sweeps(bumpy, tmp_path, capsys):
    args = ["tradeoff", str(bumpy), "--technique", "spectral", "--scale-mm", str(MM), "--material", "skin1",
            "--lights", "1", "--size", "32", "--out", str(tmp_path), "--json"]
    assert main(args) == 0
    printed = json.loads(capsys.readouterr().out)
    assert [r["sweep"] for r in printed["rows"]] == ["plain", "default", *["eigenpairs"] * 5, *["width"] * 5,
                                                     *["naive_alpha"] * 4]
    assert Path(printed["outputs"]["csv"]).exists()
    assert main(args[:-1]) == 0
    assert "naive m=0" in capsys.readouterr().out
