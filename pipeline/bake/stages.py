"""Runs stages through the content-hash cache and records what each cost; the bake's stages with
their typed options.

Each ``<Stage>Params`` is what its stage's cache key is made of (`cache.stage_key`) and what the
stage function reads its options from (`StageRunner.run`); the stage's other inputs are named by
its upstream key.
"""

from __future__ import annotations

import resource
import time
import tracemalloc
from contextlib import contextmanager
from dataclasses import dataclass, field

import numpy as np

from sssbake.pipeline.bake.cache import StageCache, stage_key
from sssbake.pipeline.core.back_share import MIN_BEHIND, gathered_shares, object_gains
from sssbake.pipeline.core.materials import Material
from sssbake.pipeline.core.profile import profile_for
from sssbake.pipeline.core.surface import Surface
from sssbake.pipeline.mesh.atlas import Atlas, compute_atlas
from sssbake.pipeline.mesh.escape_gain import EscapeGain, escape_gain
from sssbake.pipeline.mesh.load import load_scene
from sssbake.pipeline.mesh.scene import Scene
from sssbake.pipeline.mesh.thickness import ThicknessResult, bake_thickness
from sssbake.pipeline.mesh.thickness_map import ThicknessMap, bake_thickness_map
from sssbake.pipeline.options import BakeOptions
from sssbake.pipeline.planning.pilot import Pilot, run_pilot
from sssbake.pipeline.techniques.technique import BakeTarget, Technique, TechniqueBake


@dataclass
class StageRecord:
    name: str
    seconds: float = 0.0
    runs: int = 0
    cached: int = 0
    corrupt: int = 0
    skipped: str | None = None

    def to_json(self) -> dict:
        out = {"seconds": round(self.seconds, 4), "runs": self.runs, "cached": self.cached}
        if self.corrupt:
            out["corrupt_cache_entries"] = self.corrupt
        if self.skipped:
            out["skipped"] = self.skipped
        return out


@dataclass
class StageRunner:
    """Runs `fn(*args)` for a stage unless the cache holds the result for the same key.

    Records per stage: seconds spent (cache loads included), how many runs were served from the
    cache, and the process's peak resident memory after the stage.
    """

    cache: StageCache
    trace_memory: bool = False
    records: dict[str, StageRecord] = field(default_factory=dict)
    peak_rss_mb: dict[str, float] = field(default_factory=dict)
    peak_traced_mb: dict[str, float] = field(default_factory=dict)

    @contextmanager
    def _measure(self, rec: StageRecord):
        # tracemalloc sees numpy's allocations, so its peak is the stage's own working set;
        # ru_maxrss is the process's high-water mark so far (C++ libraries included).
        if self.trace_memory:
            if not tracemalloc.is_tracing():
                tracemalloc.start()
            tracemalloc.reset_peak()
            base = tracemalloc.get_traced_memory()[0]
        t0 = time.perf_counter()
        yield
        rec.seconds += time.perf_counter() - t0
        rec.runs += 1
        if self.trace_memory:
            peak = (tracemalloc.get_traced_memory()[1] - base) / 2**20
            self.peak_traced_mb[rec.name] = max(self.peak_traced_mb.get(rec.name, 0.0), peak)
        self.peak_rss_mb[rec.name] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0

    def run(self, name: str, version: int, upstream: str, params, fn, *inputs, fresh=None):
        """``fn(*inputs, params)`` (``fn(*inputs)`` when `params` is None) unless the cache holds it.

        Returns (result, key); `key` is the upstream key of the stages that consume the result.
        `params` is the stage's typed options (a frozen dataclass): the key is made from it
        (`cache.stage_key`) and the same object is what `fn` gets, so the two cannot drift. `inputs`
        are what `upstream` names (the scene, a surface...), never keyed again. `fresh(value)`, when
        given, says whether a cached value still holds (it depends on more than its key, e.g. on
        files the stage read); a stale one is recomputed and replaced.
        """
        key = stage_key(upstream, name, version, params)
        rec = self.records.setdefault(name, StageRecord(name))
        with self._measure(rec):
            damaged = len(self.cache.corrupt)
            value = self.cache.get(key)
            rec.corrupt += len(self.cache.corrupt) - damaged
            if value is not None and fresh is not None and not fresh(value):
                value = None
            if value is None:
                value = fn(*inputs) if params is None else fn(*inputs, params)
                self.cache.put(key, value)
            else:
                rec.cached += 1
        return value, key

    @contextmanager
    def timed(self, name: str):
        """Time an uncached step (exports, validation) under `name`."""
        with self._measure(self.records.setdefault(name, StageRecord(name))):
            yield

    def skip(self, name: str, reason: str) -> None:
        self.records.setdefault(name, StageRecord(name)).skipped = reason

    def to_json(self) -> dict:
        out = {}
        for name, rec in self.records.items():
            out[name] = {**rec.to_json(), "peak_rss_mb": round(self.peak_rss_mb.get(name, 0.0), 1)}
            if name in self.peak_traced_mb:
                out[name]["peak_traced_mb"] = round(self.peak_traced_mb[name], 1)
        return out


@dataclass(frozen=True)
class LoadParams:
    """The load stage's options (the file is its upstream key, its digest). The allowed roots are
    keyed: a scene read under a wider allowance must not serve a narrower one."""

    allow_roots: tuple[str, ...]


def load_stage(path: str, params: LoadParams) -> Scene:
    return load_scene(path, params.allow_roots)


@dataclass(frozen=True)
class AtlasParams:
    """A mesh's atlas: texels along its side and gutter texels around each chart."""

    resolution: int
    padding: int


def atlas_stage(parts: list, params: AtlasParams) -> Atlas:
    """`compute_atlas` of `parts`, per primitive its (positions, faces)."""
    return compute_atlas(parts, params.resolution, params.padding)


@dataclass(frozen=True)
class ThicknessParams:
    rays: int


def thickness_stage(surface: Surface, normals: list, cap: float, params: ThicknessParams) -> ThicknessResult:
    """Per-vertex thickness of the welded `surface`, capped at `cap` (file units); `normals`: per
    primitive its render vertices' normals (n_p, 3), split where the author marked hard edges."""
    return bake_thickness(surface.positions, surface.faces, surface.normals,
                          split_normals=(np.concatenate(surface.weld), np.concatenate(normals)), cap=cap,
                          rays=params.rays)


@dataclass(frozen=True)
class ThicknessMapParams:
    atlas: AtlasParams
    rays: int


def thickness_map_stage(atlas: Atlas, primitives: list, surface: Surface, cap: float,
                        params: ThicknessMapParams) -> ThicknessMap:
    """`bake_thickness_map` in `atlas`; `primitives`: per primitive its (positions, normals)."""
    return bake_thickness_map(atlas, primitives, surface, cap, params.rays, params.atlas.padding)


@dataclass(frozen=True)
class EscapeGainParams:
    """A mesh's escape gain (`mesh.escape_gain`): its material (the half-space one) and millimetres
    per file unit."""

    material: Material
    mm_per_unit: float


def escape_gain_stage(surface: Surface, params: EscapeGainParams) -> tuple[EscapeGain, tuple, tuple]:
    """The walk's `EscapeGain` and the `Material.escape_gain` and `Material.back_gain` it implies
    (`core.back_share`). A mesh no light crosses (too few photons left behind anywhere) keeps one
    factor for all its light, the walk's gain, and skips the gather."""
    walk = escape_gain(surface.positions, surface.faces, params.mm_per_unit, params.material)
    if not walk.closed or max(walk.behind) < MIN_BEHIND:
        return walk, walk.gain, (1.0, 1.0, 1.0)
    mm = params.mm_per_unit
    front, back = gathered_shares(surface.positions * mm, surface.faces, surface.normals,
                                  surface.vertex_areas * mm * mm, profile_for(params.material))
    return (walk, *object_gains(walk.front, walk.back, walk.behind, front, back))


@dataclass(frozen=True)
class TechniqueParams:
    """A technique's bake of one mesh or material: the material, the mesh's millimetres per file
    unit (1 for a material) and the technique's options (its `Technique.options_type`)."""

    material: Material
    mm_per_unit: float
    options: object


def technique_stage(technique: Technique, geometry: dict, params: TechniqueParams) -> TechniqueBake:
    """`technique.bake` of the `BakeTarget` made of `geometry` (its mesh fields) and `params`."""
    return technique.bake(BakeTarget(params.material, params.mm_per_unit, **geometry), params.options)


@dataclass(frozen=True, eq=False)
class PilotParams:
    """The planner's pilot on one mesh (`planning.pilot.run_pilot`).

    Attributes
    ----------
    material : Material
    mm_per_unit : float
    options : dict
        What it reads of the options it runs under (`asset._cached_pilot`).
    candidates : tuple of Candidate
    world : (4, 4) float64
        The mesh's first instance's world matrix.
    """

    material: Material
    mm_per_unit: float
    options: dict
    candidates: tuple
    world: np.ndarray


def pilot_stage(surface: Surface, options: BakeOptions, budget: float, vertices: int, params: PilotParams) -> Pilot:
    """`run_pilot` of `params`' candidates on `surface` under `options` (keyed as ``params.options``)."""
    return run_pilot(list(params.candidates), surface, params.mm_per_unit, params.material, options, budget, vertices,
                     params.world)
