"""screen tradeoff: each sweep moves its knob alone, more samples buy accuracy and cost frame time,
and the results are written as JSON/CSV/plot."""

import json
from pathlib import Path

import pytest
import trimesh
from fixtures import assert_tradeoff_written

from sssbake.pipeline.cli import main
from sssbake.pipeline.core.materials import preset
from sssbake.pipeline.techniques.screen.tradeoff import RUNTIME_CHANGES, screen_tradeoff

# A ball of radius 20 mm (5 units at 4 mm per unit) in skin1.
MM = 4.0
SWEEPS = dict(samples=(2, 32), uniform=(0, 8))


@pytest.fixture(scope="module")
def ball(tmp_path_factory):
    path = tmp_path_factory.mktemp("screen_tradeoff") / "ball.obj"
    trimesh.creation.icosphere(subdivisions=3, radius=5.0).export(path)
    return path


@pytest.fixture(scope="module")
def result(ball):
    return screen_tradeoff(ball, MM, preset("skin1"), ball.parent / "out", lights=1, size=96, frames=2, **SWEEPS)


def test_each_sweep_varies_its_knob_alone(result):
    rows = result["rows"]
    assert [r["sweep"] for r in rows] == ["default", "samples", "samples", "uniform", "uniform"] + ["runtime"] * 3
    default = rows[0]
    assert (default["samples"], default["uniform"], default["jacobian"], default["fill"], default["interleave"]) == (
        32, 8, True, True, 4)
    assert [r["samples"] for r in rows[1:3]] == [2, 32] and all(r["uniform"] == 8 for r in rows[1:3])
    assert [r["uniform"] for r in rows[3:5]] == [0, 8] and all(r["samples"] == 32 for r in rows[3:5])
    for row, change in zip(rows[5:], RUNTIME_CHANGES):
        assert all(row[k] == v for k, v in change.items()) and (row["samples"], row["uniform"]) == (32, 8)
    # the default's configuration is measured once and its row reused
    assert {**rows[2], "sweep": "default"} == default == {**rows[4], "sweep": "default"}
    # the tables grow by 12 bytes per sample (offset and weight, float32); nothing per vertex
    assert rows[2]["bytes"] - rows[1]["bytes"] == 12 * 30
    assert all(r["bytes_per_vertex"] == 0.0 and r["frame_ms"] > 0 and r["rmse_object"] >= r["rmse_image"]
               for r in rows)


def test_samples_buy_accuracy(result):
    two, thirty_two = result["rows"][1:3]
    assert thirty_two["rmse_image"] < two["rmse_image"]
    # the fill (self-normalised gather) matters most: without it the estimate carries the sample
    # set's own quadrature error
    no_fill = next(r for r in result["rows"] if r["sweep"] == "runtime" and not r["fill"])
    assert no_fill["rmse_image"] > result["rows"][0]["rmse_image"]


def test_outputs_are_written(result):
    assert_tradeoff_written(result, "ball.tradeoff.screen.json")
    assert result["reference_vertices"] == result["vertices"]  # no subdivision by default
    assert result["frame_ms_sss"] > 0 and result["frame_ratio"] > 0


def test_cli_runs_the_screen_tradeoff(ball, tmp_path, capsys):
    assert main(["tradeoff", str(ball), "--technique", "screen", "--material", "skin1", "--scale-mm", "4",
                 "--samples", "4", "--uniform", "2", "--lights", "1", "--size", "48", "--out", str(tmp_path),
                 "--reference-subdivisions", "1", "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert [r["samples"] for r in result["rows"] if r["sweep"] == "samples"] == [4]
    # the reference on the ball cut 4:1 (642 vertices, 1280 faces -> 2562 vertices)
    assert (result["vertices"], result["reference_vertices"]) == (642, 2562)
    assert Path(result["outputs"]["plot"]).exists()
    assert main(["tradeoff", str(ball), "--technique", "screen", "--material", "skin1", "--scale-mm", "4",
                 "--samples", "4", "--uniform", "2", "--lights", "1", "--size", "48", "--out", str(tmp_path)]) == 0
    assert "B/material" in capsys.readouterr().out
