"""How the lpv technique's data (Børlum et al. 2011) is laid out in the exported files.

Per mesh, under ``extras.sssbake.lpv`` (glTF: tables as accessors; USD: the Mesh prim's
``sss:extras`` JSON with ``sss:tables:t<i>`` attributes), see `lpv_tables`: the material grid (one
value per cell, x fastest, then y, then z, as a GL 3-D texture's texels), the grid's frame in the
mesh's file units, the six propagation matrices and the rendering's scale per step count. No
per-vertex data: the runtime voxelises nothing and the mesh may deform inside its grid.
"""

from __future__ import annotations

import numpy as np

from .lpv_data import LpvGrid
from .lpv_matrices import DIRECTIONS

#: The tables of the block, in file order.
TABLES = ("occupancy", "sigmaT", "albedo", "g", "matrices", "renderScale")
BASIS = ("two real SH bands without the Condon-Shortley phase, c = (c00, c1-1, c10, c11): "
         "1/sqrt(4 pi), sqrt(3/(4 pi)) (y, z, x)")


def lpv_tables(grid: LpvGrid, matrices: np.ndarray, scales: np.ndarray, field: str) -> dict:
    """The per-mesh block, JSON-able with numpy arrays for the binary tables.

    Parameters
    ----------
    grid : LpvGrid
        nx × ny × nz cells.
    matrices : (6, 4, 4) float64
        `lpv_matrices.propagation_matrices`, c_d += M[k] c_s for s = d - directions[k].
    scales : (S, 3) float64
        `lpv_calibrate.render_scales`: row s - 1 for s steps.
    field : str
        Where the coefficients came from (``"homogeneous"``, ``"marble"``).

    Returns
    -------
    dict
        Parameters ``technique`` ("lpv"), ``shape`` [nx, ny, nz], ``origin`` (3,) and ``cell``
        (file units), ``cellMm``, ``eta``, ``field``, ``maxSteps`` (S), ``directions`` (6, 3),
        ``basis``, ``layout``, ``units``; tables (float32) ``occupancy`` (N,), ``sigmaT`` (N, 3)
        1/mm, ``albedo`` (N, 3), ``g`` (N, 3), N = nx ny nz, ``matrices`` (6, 4, 4),
        ``renderScale`` (S, 3).
    """
    n = grid.occupancy.size
    return {
        "technique": "lpv",
        "shape": list(grid.shape),
        "origin": [float(v) for v in grid.origin],
        "cell": float(grid.cell),
        "cellMm": grid.cell_mm,
        "eta": float(grid.eta),
        "field": field,
        "maxSteps": int(len(scales)),
        "directions": DIRECTIONS.tolist(),
        "basis": BASIS,
        "layout": "cell (i, j, k) is entry (k * ny + j) * nx + i; it spans origin + cell * [i, i + 1] x [j, j + 1] "
                  "x [k, k + 1] in the mesh's frame",
        "units": "origin, cell: file units; sigmaT: 1/mm (reduced extinction); albedo, g, occupancy: 1; "
                 "renderScale: row s - 1 scales the radiance after s steps",
        "occupancy": grid.occupancy.reshape(n).astype(np.float32),
        "sigmaT": grid.sigma_t.reshape(n, 3).astype(np.float32),
        "albedo": grid.albedo.reshape(n, 3).astype(np.float32),
        "g": grid.g.reshape(n, 3).astype(np.float32),
        "matrices": np.asarray(matrices, dtype=np.float32),
        "renderScale": np.asarray(scales, dtype=np.float32),
    }


def lpv_grid_from_tables(tables: dict, mm_per_unit: float) -> tuple[LpvGrid, np.ndarray, np.ndarray]:
    """The inverse of `lpv_tables`: the grid (float32 values as stored), the matrices (6, 4, 4)
    and the scales (S, 3), checked."""
    try:
        nx, ny, nz = (int(v) for v in tables["shape"])
        grid = LpvGrid(origin=np.asarray(tables["origin"], dtype=np.float64), cell=float(tables["cell"]),
                       mm_per_unit=float(mm_per_unit),
                       occupancy=np.asarray(tables["occupancy"], np.float32).reshape(nz, ny, nx),
                       sigma_t=np.asarray(tables["sigmaT"], np.float32).reshape(nz, ny, nx, 3),
                       albedo=np.asarray(tables["albedo"], np.float32).reshape(nz, ny, nx, 3),
                       g=np.asarray(tables["g"], np.float32).reshape(nz, ny, nx, 3), eta=float(tables["eta"]))
        matrices = np.asarray(tables["matrices"], dtype=np.float64).reshape(6, 4, 4)
        scales = np.asarray(tables["renderScale"], dtype=np.float64).reshape(-1, 3)
    except (KeyError, TypeError, ValueError) as error:
        raise ValueError(f"lpv: malformed lpv block ({error})") from None
    grid.check()
    if not (len(scales) >= 1 and np.all(np.isfinite(scales)) and np.all(scales > 0)):
        raise ValueError("lpv: renderScale must hold positive finite rows")
    return grid, matrices, scales


def lpv_bytes(tables: dict) -> dict:
    """Bytes each table of `lpv_tables` spends in the glTF binary (float32), and ``total``."""
    out = {name: int(tables[name].nbytes) for name in TABLES}
    out["total"] = sum(out.values())
    return out
