"""How the lpv technique's data (Børlum et al. 2011) is laid out in the exported files.

Per mesh, under ``extras.sssbake.lpv`` (glTF: tables as accessors; USD: the Mesh prim's
``sss:extras`` JSON with ``sss:lpv:<key>`` attributes), see `lpv_tables`: the material grid (one
value per cell, x fastest, then y, then z, as a GL 3-D texture's texels), the grid's frame in the
mesh's file units, the six propagation matrices and the rendering's scale per step count, and
(since schema 1.8.0) what the grid was voxelised from, ``source``: the voxelisation's options and
the field's parameters (`lpv_source`), enough to rebuild the same field at another resolution
(``sssbake verify`` does, for a self-convergence reference of a heterogeneous medium). No
per-vertex data: the runtime voxelises nothing and the mesh may deform inside its grid.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sssbake.pipeline.core.materials import Material
from sssbake.pipeline.techniques.lpv.data import LpvGrid
from sssbake.pipeline.techniques.lpv.grid import LpvGridOptions, MaterialField, homogeneous
from sssbake.pipeline.techniques.lpv.marble_field import MarbleOptions, marble_field, materials
from sssbake.pipeline.techniques.lpv.matrices import DIRECTIONS

#: The tables of the block, in file order.
TABLES = ("occupancy", "sigmaT", "albedo", "g", "matrices", "renderScale")
BASIS = ("two real SH bands without the Condon-Shortley phase, c = (c00, c1-1, c10, c11): "
         "1/sqrt(4 pi), sqrt(3/(4 pi)) (y, z, x)")


def lpv_tables(grid: LpvGrid, matrices: np.ndarray, scales: np.ndarray, field: str,
               source: dict | None = None) -> dict:
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
    source : dict, optional
        `lpv_source`'s record of the voxelisation and the field (recorded as ``source``; omitted
        when None, as for grids that are never written).

    Returns
    -------
    dict
        Parameters ``technique`` ("lpv"), ``shape`` [nx, ny, nz], ``origin`` (3,) and ``cell``
        (file units), ``cellMm``, ``eta``, ``field``, ``source`` (when given), ``maxSteps`` (S),
        ``directions`` (6, 3), ``basis``, ``layout``, ``units``; tables (float32) ``occupancy`` (N,), ``sigmaT`` (N, 3)
        1/mm, ``albedo`` (N, 3), ``g`` (N, 3), N = nx ny nz, ``matrices`` (6, 4, 4),
        ``renderScale`` (S, 3).
    """
    n = grid.occupancy.size
    return {
        "technique": "lpv",
        **({"source": source} if source is not None else {}),
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


# a value float32 cannot hold (inline JSON in place of a table) becomes inf, which `LpvGrid.check` refuses: no warning
@np.errstate(over="ignore")
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


@dataclass(frozen=True)
class LpvSource:
    """What an exported grid was voxelised from, read back by `lpv_source_from_tables`.

    Attributes
    ----------
    field : str
        ``"homogeneous"`` or ``"marble"``.
    mm_per_unit : float
        Millimetres per file unit the field was evaluated at.
    grid : LpvGridOptions
        The voxelisation's resolution, padding and supersampling.
    material : Material
        The whole medium (homogeneous) or the marble's body.
    marble : MarbleOptions or None
        The veins (``base`` and ``vein_material`` resolved to Materials); None when homogeneous.
    """

    field: str
    mm_per_unit: float
    grid: LpvGridOptions
    material: Material
    marble: MarbleOptions | None = None

    def material_field(self) -> MaterialField:
        """The field itself (`lpv_grid.MaterialField`), as the bake evaluated it."""
        if self.marble is None:
            return homogeneous(self.material)
        return marble_field(self.mm_per_unit, self.marble)


def lpv_source(field: str, mm_per_unit: float, grid_options: LpvGridOptions, material: Material,
               marble: MarbleOptions | None = None) -> dict:
    """The ``source`` record of `lpv_tables`, JSON-able.

    Returns
    -------
    dict
        ``mmPerUnit``; ``grid`` {``resolution``, ``padding``, ``supersample``}; ``material`` (the
        medium, or the marble's body: ``name``, ``sigma_s_prime``, ``sigma_a`` 1/mm, ``eta``);
        for ``"marble"`` also ``marble`` {``veinMm``, ``turbulence``, ``octaves``, ``sharpness``,
        ``axis``, ``seed``, ``vein`` (the veins' material, resolved)}: with
        `marble_field.marble_field` they give the same coefficients at any point.
    """
    out = {"mmPerUnit": float(mm_per_unit),
           "grid": {"resolution": int(grid_options.resolution), "padding": int(grid_options.padding),
                    "supersample": int(grid_options.supersample)},
           "material": material.to_json()}
    if field == "marble":
        if marble is None:
            raise ValueError("lpv: a marble source needs its MarbleOptions")
        base, vein = materials(marble)
        out["material"] = base.to_json()
        out["marble"] = {"veinMm": float(marble.vein_mm), "turbulence": float(marble.turbulence),
                         "octaves": int(marble.octaves), "sharpness": float(marble.sharpness),
                         "axis": [float(v) for v in marble.axis], "seed": int(marble.seed), "vein": vein.to_json()}
    return out


def lpv_source_from_tables(tables: dict) -> LpvSource | None:
    """The inverse of `lpv_source` from an lpv block; None when the block records no ``source``
    (files of schema 1.7.x)."""
    record = tables.get("source")
    if record is None:
        return None

    try:
        field = str(tables["field"])
        grid = LpvGridOptions(**{k: int(record["grid"][k]) for k in ("resolution", "padding", "supersample")})
        body = Material.from_json(record["material"])
        marble = None
        if field == "marble":
            m = record["marble"]
            marble = MarbleOptions(vein_mm=float(m["veinMm"]), turbulence=float(m["turbulence"]),
                                   octaves=int(m["octaves"]), sharpness=float(m["sharpness"]),
                                   axis=tuple(float(v) for v in m["axis"]), seed=int(m["seed"]), base=body,
                                   vein_material=Material.from_json(m["vein"]))
        elif field != "homogeneous":
            raise ValueError(f"unknown field {field!r}")
        source = LpvSource(field, float(record["mmPerUnit"]), grid, body, marble)
        grid.check()
        if marble is not None:
            marble.check()
    except (KeyError, TypeError, ValueError) as error:
        raise ValueError(f"lpv: malformed lpv source ({error})") from None
    if not (np.isfinite(source.mm_per_unit) and source.mm_per_unit > 0):
        raise ValueError(f"lpv: malformed lpv source (mmPerUnit {source.mm_per_unit!r})")
    return source


def lpv_bytes(tables: dict) -> dict:
    """Bytes each table of `lpv_tables` spends in the glTF binary (float32), and ``total``."""
    out = {name: int(tables[name].nbytes) for name in TABLES}
    out["total"] = sum(out.values())
    return out
