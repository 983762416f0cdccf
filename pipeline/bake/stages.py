"""Runs stages through the content-hash cache and records what each cost; the bake's stages with
their typed options and invariants.

Each ``<Stage>Params`` is what its stage's cache key is made of (`cache.stage_key`) and what the
stage function reads its options from (`StageRunner.run`); the stage's other inputs are named by
its upstream key. Each stage's invariants follow it (`invariants.invariants_of`): what a value
read from the cache must satisfy before the bake uses it.
"""

from __future__ import annotations

import resource
import time
import tracemalloc
from collections.abc import Callable
from contextlib import contextmanager
from dataclasses import dataclass, field

import numpy as np

from sssbake.pipeline.bake.cache import StageCache, stage_key
from sssbake.pipeline.bake.invariants import (
    all_finite,
    array,
    check_cached,
    count,
    indices,
    invariants_of,
    need,
    number,
    of_type,
    triple,
)
from sssbake.pipeline.bake.os_errors import os_error_line
from sssbake.pipeline.core.back_share import MIN_BEHIND, gathered_shares, object_gains
from sssbake.pipeline.core.materials import Material
from sssbake.pipeline.core.profile import profile_for
from sssbake.pipeline.core.surface import Surface
from sssbake.pipeline.mesh.atlas import Atlas, AtlasPart
from sssbake.pipeline.mesh.clean import CleanScene, clean_scene
from sssbake.pipeline.mesh.escape_gain import EscapeGain, escape_gain
from sssbake.pipeline.mesh.load import load_scene
from sssbake.pipeline.mesh.proxy_atlas import layout_atlas
from sssbake.pipeline.mesh.scene import Image, Mesh, Node, Primitive, Scene, SourceMaterial, Texture, TextureRef
from sssbake.pipeline.mesh.thickness import ThicknessResult, bake_thickness
from sssbake.pipeline.mesh.thickness_map import ThicknessMap, bake_thickness_map
from sssbake.pipeline.mesh.winding import edge_defects
from sssbake.pipeline.options import BakeOptions
from sssbake.pipeline.planning.pilot import Pilot, run_pilot
from sssbake.pipeline.techniques.technique import MESH, BakeTarget, Technique, TechniqueBake


@dataclass
class StageRecord:
    name: str
    seconds: float = 0.0
    runs: int = 0
    cached: int = 0
    corrupt: int = 0
    skipped: str | None = None
    beside_seconds: float = 0.0  # spent in a child beside the bake (`StageRunner.adopt`); `seconds` is the wait

    def to_json(self) -> dict:
        out = {"seconds": round(self.seconds, 4), "runs": self.runs, "cached": self.cached}
        if self.beside_seconds:
            out["beside_seconds"] = round(self.beside_seconds, 4)
        if self.corrupt:
            out["corrupt_cache_entries"] = self.corrupt
        if self.skipped:
            out["skipped"] = self.skipped
        return out


@dataclass(frozen=True)
class StageRun:
    """One stage as another process's runner made it (`StageRunner.detached`): its result and key,
    and what the runner recorded of it."""

    value: object
    key: str
    seconds: float
    cached: int
    corrupt: int
    warnings: tuple[str, ...]
    storing: bool
    peak_traced_mb: float | None


@dataclass
class StageRunner:
    """Runs `fn(*args)` for a stage unless the cache holds the result for the same key.

    Records per stage: seconds spent (cache loads included), how many runs were served from the
    cache, how many entries were found damaged, and the process's peak resident memory after the
    stage; in `warnings`, one line per damaged entry and one when the cache could not be written.

    A cache folder that cannot take an entry (full, read-only) does not fail the asset: the cache
    only saves time, the outputs go elsewhere, and a full disk under the cache need not be the
    outputs' disk. The bake warns once and stores nothing more.
    """

    cache: StageCache
    trace_memory: bool = False
    records: dict[str, StageRecord] = field(default_factory=dict)
    peak_rss_mb: dict[str, float] = field(default_factory=dict)
    peak_traced_mb: dict[str, float] = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)
    storing: bool = True  # False once a write failed

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
        files the stage read); a stale one is recomputed and replaced. A cached value that breaks the
        stage's invariants (`invariants.check_cached`) is a damaged entry: recomputed, counted, warned of.
        """
        key = stage_key(upstream, name, version, params)
        rec = self.records.setdefault(name, StageRecord(name))
        with self._measure(rec):
            value, damage = self.cache.lookup(key, lambda found: check_cached(fn, found, inputs, params))
            if damage is not None:
                rec.corrupt += 1
                self.warnings.append(f"stage cache: the {name} entry {self.cache.path(key)} {damage}; "
                                     "deleted and recomputed")
            if value is not None and fresh is not None and not fresh(value):
                value = None
            if value is None:
                value = fn(*inputs) if params is None else fn(*inputs, params)
                self._store(name, key, value)
            else:
                rec.cached += 1
        return value, key

    def detached(self, name: str, version: int, upstream: str, params, fn, *inputs) -> "StageRun":
        """`run` on a runner of its own over the same cache, as a child beside the bake makes a
        stage (`bake.beside`): the result with what that runner recorded, for `adopt`."""
        runner = StageRunner(self.cache, self.trace_memory, storing=self.storing)
        value, key = runner.run(name, version, upstream, params, fn, *inputs)
        rec = runner.records[name]
        return StageRun(value, key, rec.seconds, rec.cached, rec.corrupt, tuple(runner.warnings), runner.storing,
                        runner.peak_traced_mb.get(name))

    def adopt(self, name: str, take: Callable[[], "StageRun | None"]) -> tuple[object, str] | None:
        """The (result, key) of stage `name` that another process made (`detached`), as `take`
        hands it over, or None where it made none (the caller runs the stage). The stage's
        `seconds` are what this process waited for it, its ``beside_seconds`` the other's time."""
        t0 = time.perf_counter()
        got = take()
        if got is None:
            return None
        rec = self.records.setdefault(name, StageRecord(name))
        rec.seconds += time.perf_counter() - t0
        rec.beside_seconds += got.seconds
        rec.runs += 1
        rec.cached += got.cached
        rec.corrupt += got.corrupt
        self.warnings.extend(got.warnings)
        self.storing = self.storing and got.storing
        self.peak_rss_mb[name] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
        if got.peak_traced_mb is not None:
            self.peak_traced_mb[name] = max(self.peak_traced_mb.get(name, 0.0), got.peak_traced_mb)
        return got.value, got.key

    def _store(self, name: str, key: str, value) -> None:
        if not self.storing:
            return
        try:
            self.cache.put(key, value)
        except OSError as e:
            self.storing = False
            self.warnings.append(f"stage cache: {name} and the stages after it not stored: "
                                 f"{os_error_line(self.cache.folder, e, '--cache-dir')}")

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


@invariants_of(load_stage)
def _loaded(scene: Scene, path: str, params: LoadParams) -> None:
    """What `load.load_scene` guarantees of every reader's scene (`_scene_holds`)."""
    _scene_holds(scene, "scene", cleaned=False)


@invariants_of(clean_scene)
def _cleaned(clean: CleanScene, scene: Scene) -> None:
    """`_scene_holds` of the cleaned scene, with finite normals; the input's nodes and materials, no
    more meshes than it; per mesh its welded surface over its primitives' vertices and faces."""
    of_type(clean, CleanScene, "clean")
    _scene_holds(clean.scene, "clean.scene", cleaned=True)
    cleaned = clean.scene
    need(len(cleaned.nodes) == len(scene.nodes) and len(cleaned.materials) == len(scene.materials)
         and len(cleaned.meshes) <= len(scene.meshes), "clean.scene does not have the input's nodes and materials")
    need(isinstance(clean.surfaces, tuple) and len(clean.surfaces) == len(cleaned.meshes),
         "clean.surfaces is not one surface per mesh")
    for mi, (mesh, surface) in enumerate(zip(cleaned.meshes, clean.surfaces)):
        where = f"clean.surfaces[{mi}]"
        of_type(surface, Surface, where)
        w = len(array(surface.positions, f"{where}.positions", "float", (None, 3)))
        indices(surface.faces, f"{where}.faces", w, (sum(len(p.faces) for p in mesh.primitives), 3))
        array(surface.normals, f"{where}.normals", "float", (w, 3))
        need(np.all(array(surface.vertex_areas, f"{where}.vertex_areas", "float", (w,)) >= 0),
             f"{where}.vertex_areas holds a negative area")
        need(isinstance(surface.weld, tuple) and len(surface.weld) == len(mesh.primitives),
             f"{where}.weld is not one array per primitive")
        for pi, (weld, prim) in enumerate(zip(surface.weld, mesh.primitives)):
            indices(weld, f"{where}.weld[{pi}]", w, (len(prim.positions),))
    for i, line in enumerate(of_type(clean.warnings, tuple, "clean.warnings")):
        of_type(line, str, f"clean.warnings[{i}]")


def _scene_holds(scene: Scene, where: str, cleaned: bool) -> None:
    """What every stage reads of a `Scene`: its tables' cross-references in range, a node graph
    without cycles, per primitive its per-vertex arrays one row per vertex, finite positions, UVs,
    colours, transforms and material factors, face indices in range and at least one triangle. A
    `cleaned` scene also has normals (and its tangents) finite, and no primitive or mesh left empty."""
    of_type(scene, Scene, where)
    of_type(scene.source, str, f"{where}.source")
    for name in ("meshes", "nodes", "roots", "materials", "textures", "images", "warnings", "dependencies"):
        of_type(getattr(scene, name), tuple, f"{where}.{name}")
    need(scene.up_axis in ("Y", "Z"), f"{where}.up_axis is {scene.up_axis!r}")
    if scene.meters_per_unit is not None:
        number(scene.meters_per_unit, f"{where}.meters_per_unit")
    for i, image in enumerate(scene.images):
        of_type(of_type(image, Image, f"{where}.images[{i}]").data, bytes, f"{where}.images[{i}].data")
    for i, texture in enumerate(scene.textures):
        count(of_type(texture, Texture, f"{where}.textures[{i}]").image, f"{where}.textures[{i}].image",
              len(scene.images) - 1)
    for i, material in enumerate(scene.materials):
        _material_holds(material, f"{where}.materials[{i}]", len(scene.textures))
    for i, node in enumerate(scene.nodes):
        of_type(node, Node, f"{where}.nodes[{i}]")
        array(node.matrix, f"{where}.nodes[{i}].matrix", "float", (4, 4))
        if node.mesh is not None:
            count(node.mesh, f"{where}.nodes[{i}].mesh", len(scene.meshes) - 1)
        for c in of_type(node.children, tuple, f"{where}.nodes[{i}].children"):
            count(c, f"{where}.nodes[{i}].children", len(scene.nodes) - 1)
    for r in scene.roots:
        count(r, f"{where}.roots", len(scene.nodes) - 1)
    _acyclic(scene.nodes, where)
    for mi, mesh in enumerate(scene.meshes):
        at = f"{where}.meshes[{mi}]"
        of_type(mesh, Mesh, at)
        of_type(mesh.name, str, f"{at}.name")
        of_type(mesh.deforming, (bool, np.bool_), f"{at}.deforming")
        need(of_type(mesh.primitives, tuple, f"{at}.primitives") or not cleaned, f"{at} has no primitives")
        for pi, prim in enumerate(mesh.primitives):
            _primitive_holds(prim, f"{at}.primitives[{pi}]", len(scene.materials), cleaned)
    need(any(len(p.faces) for m in scene.meshes for p in m.primitives), f"{where} has no triangle")
    for i, line in enumerate(scene.warnings):
        of_type(line, str, f"{where}.warnings[{i}]")
    for i, pair in enumerate(scene.dependencies):
        need(isinstance(pair, tuple) and len(pair) == 2 and all(isinstance(x, str) for x in pair),
             f"{where}.dependencies[{i}] is not a (path, digest) pair")


def _acyclic(nodes: tuple, where: str) -> None:
    """Refuse a node graph with a cycle: walking it (`Scene.world_matrices`) would never end."""
    state = [0] * len(nodes)  # 0 unseen, 1 on the current path, 2 done
    for start in range(len(nodes)):
        if state[start]:
            continue
        state[start] = 1
        stack = [(start, iter(nodes[start].children))]
        while stack:
            node, children = stack[-1]
            child = next(children, None)
            if child is None:
                state[node] = 2
                stack.pop()
                continue
            need(state[child] != 1, f"{where}.nodes[{child}] is its own ancestor")
            if not state[child]:
                state[child] = 1
                stack.append((child, iter(nodes[child].children)))


def _material_holds(material: SourceMaterial, where: str, textures: int) -> None:
    """A source material's factors finite and its texture slots naming textures that exist."""
    of_type(material, SourceMaterial, where)
    of_type(material.name, str, f"{where}.name")
    for name in ("base_color_factor", "metallic_factor", "roughness_factor", "emissive_factor", "ior"):
        all_finite(getattr(material, name), f"{where}.{name}")
    for name in ("base_color_texture", "metallic_roughness_texture", "normal_texture", "occlusion_texture",
                 "emissive_texture"):
        ref = getattr(material, name)
        if ref is not None:
            of_type(ref, TextureRef, f"{where}.{name}")
            count(ref.texture, f"{where}.{name}.texture", textures - 1)
            count(ref.tex_coord, f"{where}.{name}.tex_coord")
            all_finite(ref.transform, f"{where}.{name}.transform")


def _primitive_holds(prim: Primitive, where: str, materials: int, cleaned: bool) -> None:
    """Per-vertex arrays one row per vertex, finite positions, UVs and colours, faces indexing the
    vertices; a `cleaned` primitive has faces, finite normals and finite tangents if any."""
    of_type(prim, Primitive, where)
    n = len(array(prim.positions, f"{where}.positions", "float", (None, 3)))
    faces = indices(prim.faces, f"{where}.faces", n, (None, 3))
    need(len(faces) or not cleaned, f"{where} has no faces")
    if prim.normals is not None or cleaned:
        array(prim.normals, f"{where}.normals", "float", (n, 3), finite=cleaned)
    for k, uv in enumerate(of_type(prim.uvs, tuple, f"{where}.uvs")):
        array(uv, f"{where}.uvs[{k}]", "float", (n, 2))
    if prim.colors is not None:
        array(prim.colors, f"{where}.colors", "float", (n, 4))
    if prim.tangents is not None:
        array(prim.tangents, f"{where}.tangents", "float", (n, 4), finite=cleaned)
    if prim.material is not None:
        count(prim.material, f"{where}.material", materials - 1)


@dataclass(frozen=True)
class AtlasParams:
    """A mesh's atlas: texels along its side, gutter texels around each chart, and whether the
    input's own UVs may serve (not where a technique needs gutters: `proxy_atlas`)."""

    resolution: int
    padding: int
    reuse_input: bool = True


def atlas_stage(parts: list, params: AtlasParams) -> Atlas:
    """`layout_atlas` of `parts`, per primitive its (positions, faces, uv sets): the input's UVs,
    a proxy's charts or xatlas charting."""
    return layout_atlas(parts, params.resolution, params.padding, reuse_input=params.reuse_input)


@invariants_of(atlas_stage)
def _atlas_holds(atlas: Atlas, parts: list, params: AtlasParams) -> None:
    """One atlas part per input part: its atlas vertices copying the part's vertices, its triangles
    the part's (as many) over the atlas vertices, finite UVs; a non-empty atlas."""
    of_type(atlas, Atlas, "atlas")
    need(isinstance(atlas.parts, tuple) and len(atlas.parts) == len(parts), "atlas.parts is not one per part")
    count(atlas.width, "atlas.width")
    count(atlas.height, "atlas.height")
    need(atlas.width >= 1 and atlas.height >= 1, "atlas has no texels")
    count(atlas.chart_count, "atlas.chart_count")
    of_type(atlas.jittered, (bool, np.bool_), "atlas.jittered")
    of_type(atlas.worker_peak_rss_mb, (float, np.floating), "atlas.worker_peak_rss_mb")  # NaN where the OS does not say
    of_type(atlas.source, str, "atlas.source")
    reused = atlas.source.startswith("TEXCOORD_") and atlas.source.removeprefix("TEXCOORD_").isdigit()
    need(atlas.source in ("proxy", "charted") or (reused and params.reuse_input
                                                  and atlas.input_uv_set < min(len(uvs) for _, _, uvs in parts)),
         f"atlas.source {atlas.source!r} is not an input UV set, 'proxy' or 'charted'")
    need(isinstance(atlas.notes, tuple) and all(isinstance(n, str) for n in atlas.notes), "atlas.notes are not strings")
    for i, (part, (positions, faces, _)) in enumerate(zip(atlas.parts, parts)):
        of_type(part, AtlasPart, f"atlas.parts[{i}]")
        k = len(indices(part.vmapping, f"atlas.parts[{i}].vmapping", len(positions), (None,)))
        indices(part.faces, f"atlas.parts[{i}].faces", k, (len(faces), 3))
        array(part.uvs, f"atlas.parts[{i}].uvs", "float", (k, 2))


@dataclass(frozen=True)
class ThicknessParams:
    rays: int


def thickness_stage(surface: Surface, normals: list, cap: float, params: ThicknessParams) -> ThicknessResult:
    """Per-vertex thickness of the welded `surface`, capped at `cap` (file units); `normals`: per
    primitive its render vertices' normals (n_p, 3), split where the author marked hard edges."""
    return bake_thickness(surface.positions, surface.faces, surface.normals,
                          split_normals=(np.concatenate(surface.weld), np.concatenate(normals)), cap=cap,
                          rays=params.rays)


# A thickness is a mean of ray lengths each capped at the cap: the mean of equal lengths may round an
# ulp or so above it (0.1, 0.1 and 0.1 average 0.10000000000000002)
_CAPPED = 1.0 + 1e-9


@invariants_of(thickness_stage)
def _thickness_holds(result: ThicknessResult, surface: Surface, normals: list, cap: float,
                     params: ThicknessParams) -> None:
    """Per welded vertex a thickness in [0, cap], a hit flag and a hit fraction in [0, 1]; counts."""
    of_type(result, ThicknessResult, "thickness")
    w = len(surface.positions)
    thickness = array(result.thickness, "thickness.thickness", "float", (w,))
    need(np.all((thickness >= 0) & (thickness <= _CAPPED * cap)), f"thickness.thickness leaves [0, {cap}]")
    array(result.hit, "thickness.hit", "bool", (w,))
    fraction = array(result.hit_fraction, "thickness.hit_fraction", "float", (w,))
    need(np.all((fraction >= 0) & (fraction <= 1)), "thickness.hit_fraction leaves [0, 1]")
    for name in ("rays", "opening", "flipped", "no_inside"):
        count(getattr(result, name), f"thickness.{name}")


@dataclass(frozen=True)
class ThicknessMapParams:
    atlas: AtlasParams
    rays: int


def thickness_map_stage(atlas: Atlas, primitives: list, surface: Surface, cap: float,
                        params: ThicknessMapParams) -> ThicknessMap:
    """`bake_thickness_map` in `atlas`; `primitives`: per primitive its (positions, normals)."""
    return bake_thickness_map(atlas, primitives, surface, cap, params.rays, params.atlas.padding)


@invariants_of(thickness_map_stage)
def _thickness_map_holds(tmap: ThicknessMap, atlas: Atlas, primitives: list, surface: Surface, cap: float,
                         params: ThicknessMapParams) -> None:
    """A thickness in [0, cap] and a coverage flag per texel of `atlas`; no more escaped texels than texels."""
    of_type(tmap, ThicknessMap, "thickness_map")
    image = array(tmap.image, "thickness_map.image", "float", (atlas.height, atlas.width))
    need(np.all((image >= 0) & (image <= _CAPPED * cap)), f"thickness_map.image leaves [0, {cap}]")
    array(tmap.mask, "thickness_map.mask", "bool", (atlas.height, atlas.width))
    count(tmap.escaped, "thickness_map.escaped", image.size)


@dataclass(frozen=True)
class EscapeGainParams:
    """A mesh's escape gain (`mesh.escape_gain`): its material (the half-space one) and millimetres
    per file unit."""

    material: Material
    mm_per_unit: float


def escape_gain_stage(surface: Surface, params: EscapeGainParams) -> tuple[EscapeGain, tuple, tuple]:
    """The walk's `EscapeGain` and the `Material.escape_gain` and `Material.back_gain` it implies
    (`core.back_share`). A mesh no light crosses (too few photons left behind anywhere) keeps one
    factor for all its light, the walk's gain, and skips the gather.

    The gather's near field is built after the walk, only where the gather runs: its disc table,
    which threads used to fill beside the walk, is filled by the gather as it reads it (`DiscMean`:
    46 % of it on the 50k dragon)."""
    mm = params.mm_per_unit
    walk = escape_gain(surface.positions, surface.faces, mm, params.material, closed=edge_defects(surface.faces).closed)
    if not walk.closed or max(walk.behind) < MIN_BEHIND:
        return walk, walk.gain, (1.0, 1.0, 1.0)
    front, back = gathered_shares(surface.positions * mm, surface.faces, surface.normals,
                                  surface.vertex_areas * mm * mm, profile_for(params.material))
    return (walk, *object_gains(walk.front, walk.back, walk.behind, front, back))


@invariants_of(escape_gain_stage)
def _escape_gain_holds(value: tuple, surface: Surface, params: EscapeGainParams) -> None:
    """The walk's finite shares and photon counts; the escape and back gains positive and finite
    (every technique's profile multiplies by them)."""
    need(isinstance(value, tuple) and len(value) == 3, "escape_gain is not (walk, gain, back gain)")
    walk, gain, back = value
    of_type(walk, EscapeGain, "escape_gain walk")
    for name in ("gain", "front", "back", "escape", "plane"):
        triple(getattr(walk, name), f"escape_gain walk.{name}")
    for name in ("photons", "behind"):
        need(isinstance(getattr(walk, name), tuple) and len(getattr(walk, name)) == 3,
             f"escape_gain walk.{name} is not three counts")
        for x in getattr(walk, name):
            count(x, f"escape_gain walk.{name}")
    of_type(walk.closed, (bool, np.bool_), "escape_gain walk.closed")
    for name, g in (("gain", gain), ("back gain", back)):
        need(all(x > 0 for x in triple(g, f"escape_gain {name}")), f"escape_gain {name} is not positive")


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


@invariants_of(technique_stage)
def _technique_holds(bake: TechniqueBake, technique: Technique, geometry: dict, params: TechniqueParams) -> None:
    """Every technique's: its data and tables finite (the files hold no NaN), its data's own
    ``check()`` where it has one, and for a mesh technique per-vertex data over each of the welded
    surface's vertices; then the technique's own (`Technique.check_bake`)."""
    name = technique.name
    of_type(bake, TechniqueBake, name)
    if bake.tables is not None:
        of_type(bake.tables, dict, f"{name}.tables")
    of_type(bake.report, dict, f"{name}.report")
    for i, line in enumerate(of_type(bake.warnings, tuple, f"{name}.warnings")):
        of_type(line, str, f"{name}.warnings[{i}]")
    all_finite(bake.data, f"{name}.data")
    all_finite(bake.tables, f"{name}.tables")
    if callable(getattr(bake.data, "check", None)):
        bake.data.check()
    if technique.scope == MESH:
        w = len(geometry["surface"].positions)
        for a in technique.vertex_attributes(bake, np.arange(w)):
            need(len(a.data) == w, f"{name}: attribute {a.key} has {len(a.data)} rows for {w} vertices")
            all_finite(a.data, f"{name}: attribute {a.key}")
    technique.check_bake(bake, BakeTarget(params.material, params.mm_per_unit, **geometry), params.options)


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


@invariants_of(pilot_stage)
def _pilot_holds(pilot: Pilot, surface: Surface, options: BakeOptions, budget: float, vertices: int,
                 params: PilotParams) -> None:
    """The candidates it was given; a row of finite, non-negative figures per measured candidate, in
    order; the chosen one among them."""
    of_type(pilot, Pilot, "pilot")
    need(pilot.candidates == params.candidates, "pilot.candidates are not the ones it was run with")
    rows = of_type(pilot.rows, tuple, "pilot.rows")
    need(1 <= len(rows) <= len(pilot.candidates), "pilot.rows is not a row per measured candidate")
    for i, (row, candidate) in enumerate(zip(rows, pilot.candidates)):
        of_type(row, dict, f"pilot.rows[{i}]")
        need(row.get("label") == candidate.label and row.get("technique") == candidate.technique,
             f"pilot.rows[{i}] is not its candidate's")
        for key in ("rmse_image", "rmse_object", "lambert_rmse_object", "seconds"):
            number(row.get(key), f"pilot.rows[{i}][{key!r}]", 0.0)
        for key in ("beats_lambert", "holds_bytes"):
            of_type(row.get(key), (bool, np.bool_), f"pilot.rows[{i}][{key!r}]")
    count(pilot.chosen, "pilot.chosen", len(rows) - 1)
    of_type(pilot.met, (bool, np.bool_), "pilot.met")
    count(pilot.vertices, "pilot.vertices")
    of_type(pilot.reference, str, "pilot.reference")
