"""The screen stage of a bake: one material's sample tables, laid out, with their report."""

from __future__ import annotations

from dataclasses import dataclass

from .materials import Material
from .screen_layout import screen_bytes, screen_tables
from .screen_samples import ScreenOptions, screen_samples


@dataclass(frozen=True, eq=False)
class BakedScreen:
    """What the screen stage makes for one material: the `screen_tables` and the report."""

    tables: dict
    report: dict


def bake_screen(material: Material, options: ScreenOptions) -> BakedScreen:
    """The screen stage: `screen_samples` of `material`, laid out, with its report (options,
    counts, driver, uniformRadiusMm, tableReachMm, tableError, tableSize, bytes per block)."""
    samples = screen_samples(material, options)
    tables = screen_tables(samples, options)
    report = {
        "options": dict(options.__dict__),
        "samples": options.samples,
        "uniform": options.uniform,
        "offsets": len(samples.offsets),
        "driver": tables["driver"],
        "uniformRadiusMm": tables["uniformRadiusMm"],
        "tableReachMm": tables["tableReachMm"],
        "tableError": tables["tableError"],
        "tableSize": int(samples.table.shape[1]),
        "bytes": screen_bytes(tables),
    }
    return BakedScreen(tables, report)
