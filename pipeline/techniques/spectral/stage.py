"""The spectral stage of a bake: subsurface normals for one mesh's welded surface, with its report."""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, replace

import numpy as np

from sssbake.pipeline.core.materials import Material
from sssbake.pipeline.core.surface import Surface
from sssbake.pipeline.mesh.baked import BakedAsset, VertexAttribute
from sssbake.pipeline.techniques.spectral.layout import (
    normals_variant,
    spectral_bytes,
    spectral_tables,
    spectral_vertex_attributes,
)
from sssbake.pipeline.techniques.spectral.options import SpectralOptions
from sssbake.pipeline.techniques.spectral.precompute import SpectralPrecomputeOptions, precompute_spectral
from sssbake.pipeline.techniques.technique import BakeTarget, TechniqueBake


@dataclass(frozen=True, eq=False)
class SpectralBake:
    """The normals of one mesh and what they cost.

    Attributes
    ----------
    normals : (n, 3) float64
        Unit spectral subsurface normals of the welded surface vertices.
    tables : dict or None
        `spectral_layout.spectral_tables` when the basis is exported, else None (the basis, n × m,
        is then not kept).
    report : dict
        Options, the precompute's stats (filter width, γ, frequencies, mean tilt), seconds per step and bytes per block as stored.
    """

    normals: np.ndarray
    tables: dict | None = None
    report: dict = field(default_factory=dict)


def bake_spectral(surface: Surface, mm_per_unit: float, material: Material, options: SpectralPrecomputeOptions,
                  with_basis: bool = False) -> SpectralBake:
    """Run the spectral precompute on one welded surface (`spectral_precompute.precompute_spectral`).

    Parameters
    ----------
    surface : Surface
    mm_per_unit : float
    material : Material
    options : SpectralPrecomputeOptions
    with_basis : bool
        Keep the spectrum as export tables (coefficients, eigenvalues, residual, basis).
    """
    t = time.perf_counter()
    pre = precompute_spectral(surface, mm_per_unit, material, options)
    seconds = {k: round(float(v), 4) for k, v in pre.seconds.items()} | {"total": round(time.perf_counter() - t, 4)}
    # The report is JSON: Python numbers, not numpy scalars.
    stats = {k: v.item() if isinstance(v, np.generic) else v for k, v in pre.stats.items()}
    n, m = pre.spectrum.basis.shape
    report = {**asdict(options), "basis": with_basis, **stats, "seconds": seconds,
              "bytes": spectral_bytes(n, m, with_basis)}
    tables = spectral_tables(pre.spectrum, pre.width_mm, pre.gamma) if with_basis else None
    return SpectralBake(pre.normals, tables, report)


class SpectralStage:
    """spectral's bake hooks (`technique.Technique`)."""

    def bake(self, target: BakeTarget, options: SpectralOptions) -> TechniqueBake:
        baked = bake_spectral(target.surface, target.mm_per_unit, target.material, options.precompute(),
                              options.basis)
        return TechniqueBake(baked.normals, baked.tables, baked.report)

    def vertex_attributes(self, result: TechniqueBake, welded: np.ndarray) -> tuple[VertexAttribute, ...]:
        return spectral_vertex_attributes(result.data, welded, result.tables is not None)

    def check_bake(self, result: TechniqueBake, target: BakeTarget, options: SpectralOptions) -> None:
        n = len(target.surface.positions)
        normals, tables = result.data, result.tables
        if not (isinstance(normals, np.ndarray) and normals.shape == (n, 3)):
            raise ValueError(f"spectral: normals are not ({n}, 3)")
        if (tables is not None) != options.basis:
            raise ValueError("spectral: tables where the options export none, or none where they do")
        if tables is not None:
            m = tables.get("eigenpairs")
            shapes = {"values": (m,), "coefficients": (m, 3), "residual": (n, 3), "basis": (n * m,)}
            if tables.get("vertexCount") != n or not isinstance(m, int) or any(
                    not isinstance(tables.get(k), np.ndarray) or tables[k].shape != s for k, s in shapes.items()):
                raise ValueError(f"spectral: tables are not over the surface's {n} vertices and their eigenpairs")

    def stage_options(self, options: SpectralOptions) -> SpectralOptions:
        return replace(options, variant=False)  # an extra file made from the normals, not a part of them

    def extra_outputs(self, options: SpectralOptions) -> dict[str, Callable[[BakedAsset], BakedAsset]]:
        return {"sss_normals": normals_variant} if options.variant else {}
