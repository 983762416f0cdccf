"""How the screen technique's sample tables (Mertens et al. 2003) are laid out in the exported files.

Per translucent material, under ``extras.sssbake.screen`` of the glTF material (tables as float32
accessors) and as ``sss:screen:*`` attributes of the USD Material prim (tables as float[] with
their shape in customData, parameters in the prim's ``sss:extras`` JSON), see `screen_tables`:
the tangent-plane offsets and weights a screen-space pass gathers with, and the Rd profile table
it weights them by. No mesh data: the tables depend on the material alone (`screen_samples`).
"""

from __future__ import annotations

import numpy as np

from sssbake.pipeline.techniques.screen.data import ScreenSamples
from sssbake.pipeline.techniques.screen.samples import ScreenSamplesOptions

#: The float32 tables of the block, in file order.
TABLES = ("offsets", "weights", "rdTable")


def screen_tables(samples: ScreenSamples, options: ScreenSamplesOptions) -> dict:
    """The per-material tables and parameters, JSON-able with numpy arrays for the binary tables.

    Parameters
    ----------
    samples : ScreenSamples
        K = N + U offsets, a (3, T) Rd table.
    options : ScreenSamplesOptions
        What made them (N, U).

    Returns
    -------
    dict
        Parameters ``technique`` ("screen"), ``samples`` (N), ``uniform`` (U), ``driver`` (the
        channel 0..2 that sets the uniform disc), ``uniformRadiusMm``, ``tableReachMm`` (r_max),
        ``tableError`` (measured), ``units``; tables (float32) ``offsets`` (K, 2) mm,
        ``weights`` (K,) mm², ``rdTable`` (T, 3) Rd in 1/mm² at r = r_max (i / (T - 1))².
    """
    return {
        "technique": "screen",
        "samples": int(options.samples),
        "uniform": int(options.uniform),
        "driver": int(samples.driver),
        "uniformRadiusMm": float(samples.uniform_radius_mm),
        "tableReachMm": float(samples.table_reach_mm),
        "tableError": float(samples.table_error),
        "units": "offsets: mm (tangent plane); weights: mm^2; rdTable: 1/mm^2 at r = tableReachMm * (i / (T - 1))^2",
        "offsets": samples.offsets.astype(np.float32),
        "weights": samples.weights.astype(np.float32),
        "rdTable": np.ascontiguousarray(samples.table.T).astype(np.float32),
    }


def screen_bytes(tables: dict) -> dict:
    """Bytes each table of `screen_tables` spends in the glTF binary (float32; USD the same), and
    ``total``."""
    out = {name: int(tables[name].nbytes) for name in TABLES}
    out["total"] = sum(out.values())
    return out


def screen_samples_from_tables(tables: dict) -> ScreenSamples:
    """The inverse of `screen_tables`: `ScreenSamples` (float64) from a block's parameters and its
    tables as read back (float32), checked."""
    try:
        samples = ScreenSamples(
            offsets=np.asarray(tables["offsets"], dtype=np.float64).reshape(-1, 2),
            weights=np.asarray(tables["weights"], dtype=np.float64).reshape(-1),
            driver=int(tables["driver"]), uniform_radius_mm=float(tables["uniformRadiusMm"]),
            table=np.ascontiguousarray(np.asarray(tables["rdTable"], dtype=np.float64).reshape(-1, 3).T),
            table_reach_mm=float(tables["tableReachMm"]), table_error=float(tables["tableError"]))
    except (KeyError, TypeError, ValueError) as error:
        raise ValueError(f"screen: malformed screen block ({error})") from None
    samples.check()
    return samples
