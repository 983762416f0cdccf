"""How the lpv grids are laid out in the files, and the stage that makes them."""

import numpy as np
import pytest
import trimesh

from sssbake.pipeline.core.materials import preset
from sssbake.pipeline.mesh.clean import weld_surface
from sssbake.pipeline.mesh.scene import Primitive
from sssbake.pipeline.techniques.lpv.grid import LpvGridOptions
from sssbake.pipeline.techniques.lpv.layout import TABLES, lpv_bytes, lpv_grid_from_tables
from sssbake.pipeline.techniques.lpv.marble_field import MARBLE_DEFAULTS
from sssbake.pipeline.techniques.lpv.matrices import DIRECTIONS, propagation_matrices
from sssbake.pipeline.techniques.lpv.stage import bake_lpv


@pytest.fixture(scope="module")
def ball():
    mesh = trimesh.creation.icosphere(subdivisions=2, radius=3.0)
    return weld_surface([Primitive(positions=np.asarray(mesh.vertices, float), faces=np.asarray(mesh.faces))], 1e-9)


def test_tables_round_trip_and_hold_x_fastest_cells(ball):
    baked = bake_lpv(ball, 2.0, preset("skin1"), LpvGridOptions(resolution=8), "marble", MARBLE_DEFAULTS, 12)
    tables = baked.tables
    nx, ny, nz = tables["shape"]
    assert tables["technique"] == "lpv" and tables["maxSteps"] == 12 and tables["field"] == "marble"
    assert tables["directions"] == DIRECTIONS.tolist()
    assert all(tables[name].dtype == np.float32 for name in TABLES)
    assert tables["occupancy"].shape == (nx * ny * nz,) and tables["sigmaT"].shape == (nx * ny * nz, 3)
    grid, matrices, scales = lpv_grid_from_tables(tables, 2.0)
    np.testing.assert_array_equal(matrices, propagation_matrices().astype(np.float32))
    assert scales.shape == (12, 3) and grid.shape == (nx, ny, nz) and grid.mm_per_unit == 2.0
    # entry (k ny + j) nx + i is cell (i, j, k): the centre of the ball's cell is occupied, a corner is not
    i, j, k = nx // 2, ny // 2, nz // 2
    assert tables["occupancy"][(k * ny + j) * nx + i] == 1.0 and tables["occupancy"][0] == 0.0
    assert grid.occupancy[k, j, i] == 1.0
    # marble: veins make the absorption vary over the grid; homogeneous: one value
    medium = tables["occupancy"] > 0
    assert np.ptp(tables["sigmaT"][medium, 0]) > 0
    plain = bake_lpv(ball, 2.0, preset("skin1"), LpvGridOptions(resolution=8), "homogeneous", MARBLE_DEFAULTS, 4)
    assert np.ptp(plain.tables["sigmaT"][plain.tables["occupancy"] > 0], axis=0).max() == 0.0
    assert lpv_bytes(tables)["total"] == sum(tables[name].nbytes for name in TABLES)
    report = baked.report
    assert report["shape"] == [nx, ny, nz] and report["cellsWithMedium"] == int(medium.sum())
    assert report["bytes"] == lpv_bytes(tables) and len(report["decayPerCell"]) == 3


@pytest.mark.parametrize("change, needle", [
    ({"shape": [2, 2]}, "malformed"),
    ({"renderScale": np.zeros((3, 3), np.float32)}, "renderScale"),
    ({"albedo": None}, "malformed"),
])
def test_malformed_blocks_are_refused(ball, change, needle):
    tables = bake_lpv(ball, 2.0, preset("marble"), LpvGridOptions(resolution=4), "homogeneous", MARBLE_DEFAULTS,
                      2).tables
    with pytest.raises(ValueError, match=needle):
        lpv_grid_from_tables({**tables, **change}, 2.0)
    with pytest.raises(ValueError, match="field"):
        bake_lpv(ball, 2.0, preset("marble"), LpvGridOptions(resolution=4), "wood", MARBLE_DEFAULTS, 2)
