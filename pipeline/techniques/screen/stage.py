"""The screen stage of a bake: one material's sample tables, laid out, with their report."""

from __future__ import annotations

import numpy as np

from sssbake.pipeline.core.materials import Material
from sssbake.pipeline.mesh.baked import VertexAttribute
from sssbake.pipeline.techniques.screen.layout import screen_bytes, screen_samples_from_tables, screen_tables
from sssbake.pipeline.techniques.screen.options import ScreenOptions
from sssbake.pipeline.techniques.screen.samples import ScreenSamplesOptions, screen_samples
from sssbake.pipeline.techniques.technique import BakeTarget, TechniqueBake, same_tables


def bake_screen(material: Material, options: ScreenSamplesOptions) -> TechniqueBake:
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
    return TechniqueBake(None, tables, report)


class ScreenStage:
    """screen's bake hooks (`technique.Technique`): per material, nothing per vertex."""

    def bake(self, target: BakeTarget, options: ScreenOptions) -> TechniqueBake:
        return bake_screen(target.material, options.samples_options())

    def vertex_attributes(self, result: TechniqueBake, welded: np.ndarray) -> tuple[VertexAttribute, ...]:
        return ()

    def check_bake(self, result: TechniqueBake, target: BakeTarget, options: ScreenOptions) -> None:
        samples = screen_samples_from_tables(result.tables)  # checked: shapes, finite, non-negative
        made = options.samples_options()
        if len(samples.offsets) != made.samples + made.uniform:
            raise ValueError(f"screen: {len(samples.offsets)} offsets, not {made.samples} + {made.uniform}")
        if result.data is not None or not same_tables(result.tables, screen_tables(samples, made)):
            raise ValueError("screen: tables are not as its bake lays them out")
