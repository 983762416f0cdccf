"""lpv tradeoff: every grid resolution × step count runs on the GPU runtime, finer grids buy
accuracy against the dipole, a veined medium is measured against its finest configuration, and
the results are written as JSON/CSV/plot."""

import json

import pytest
import trimesh
from fixtures import assert_tradeoff_written

from sssbake.pipeline.cli import main
from sssbake.pipeline.core.materials import preset
from sssbake.pipeline.techniques.lpv.tradeoff import lpv_tradeoff

# A skin ball of radius 20 mm: 16-cell grids hold 5 to 30 of skin1's diffusion lengths per cell
# side only at the finer resolution.
MM = 4.0


@pytest.fixture(scope="module")
def ball(tmp_path_factory):
    path = tmp_path_factory.mktemp("lpv_tradeoff") / "ball.obj"
    trimesh.creation.icosphere(subdivisions=3, radius=5.0).export(path)
    return path


@pytest.fixture(scope="module")
def result(ball):
    return lpv_tradeoff(ball, MM, preset("skin1"), ball.parent / "out", resolutions=(8, 20), steps=(2, 6), lights=1,
                        size=64, frames=2)


def test_every_pair_is_measured(result):
    rows = result["rows"]
    assert [(r["resolution"], r["steps"]) for r in rows] == [(8, 2), (8, 6), (20, 2), (20, 6)]
    assert result["reference"] == "montecarlo" and result["field"] == "homogeneous"
    assert rows[0]["shape"] == [10, 10, 10] and rows[2]["shape"] == [22, 22, 22]
    assert rows[0]["bytes"] < rows[2]["bytes"] and all(r["bytes_per_vertex"] == 0.0 for r in rows)
    assert all(r["frame_ms"] > 0 and r["rmse_object"] >= r["rmse_image"] for r in rows)
    # cells of 2 mm resolve skin1's red and green diffusion; cells of 5 mm resolve none
    assert rows[3]["rmse_image"] < 0.5 * rows[1]["rmse_image"]
    assert_tradeoff_written(result, "ball.tradeoff.lpv.json")


def test_a_veined_medium_is_measured_against_its_finest_configuration(ball, tmp_path, capsys):
    assert main(["tradeoff", str(ball), "--technique", "lpv", "--material", "marble", "--scale-mm", "4",
                 "--lpv-resolutions", "8,12", "--lpv-steps", "3,6", "--lpv-field", "marble", "--lights", "1",
                 "--size", "48", "--out", str(tmp_path), "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert result["reference"] == "lpv 12 x 6 steps" and result["field"] == "marble"
    assert result["rows"][-1]["rmse_image"] == 0.0 and all(r["rmse_image"] > 0 for r in result["rows"][:-1])
