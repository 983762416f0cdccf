"""Bakes one asset: load → clean → assign materials → atlas → thickness → techniques → export → validate.

Only the stages a scene needs run: a scene whose materials are all opaque gets no atlas and no
thickness. The techniques come from `registry.TECHNIQUES`: mesh-scope ones per mesh, on its
welded surface (and atlas), material-scope ones per scattering material after the meshes.
"""

from __future__ import annotations

import io
import json
import os
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from importlib.metadata import version
from pathlib import Path

import numpy as np
import psutil
from PIL import Image as PILImage

from sssbake.exporters.atomic import atomic_path
from sssbake.exporters.gltf import write_glb
from sssbake.exporters.materials_json import khr_volume_scatter, write_materials_json
from sssbake.exporters.mtlx import write_mtlx
from sssbake.exporters.usd import materialx_file, write_usdc
from sssbake.pipeline.bake.cache import StageCache, stage_key
from sssbake.pipeline.bake.fallback import make_fallback
from sssbake.pipeline.bake.stages import (
    EscapeGainParams,
    LoadParams,
    PilotParams,
    StageRunner,
    TechniqueParams,
    escape_gain_stage,
    load_stage,
    pilot_stage,
    technique_stage,
)
from sssbake.pipeline.bake.staging import commit, staging
from sssbake.pipeline.bake.texel_stages import TexelStages, miss_cap
from sssbake.pipeline.core.errors import AssetError
from sssbake.pipeline.core.materials import Material
from sssbake.pipeline.core.surface import Surface
from sssbake.pipeline.mesh.atlas import Atlas
from sssbake.pipeline.mesh.baked import SCHEMA_VERSION, BakedAsset, ScatteringMaterial, VertexAttribute, padded
from sssbake.pipeline.mesh.clean import CleanScene, clean_scene
from sssbake.pipeline.mesh.confine import Confinement
from sssbake.pipeline.mesh.digest import file_digest
from sssbake.pipeline.mesh.scale import instance_scale, resolve_scale_mm
from sssbake.pipeline.mesh.scene import Image, Mesh, Scene, SourceMaterial, Texture, TextureRef
from sssbake.pipeline.mesh.thickness import ThicknessResult, miss_warnings
from sssbake.pipeline.mesh.thickness_map import ThicknessMap
from sssbake.pipeline.options import BakeOptions
from sssbake.pipeline.planning.assign import Assignment, assign_materials
from sssbake.pipeline.planning.plan import PlanEntry, decide, requested_checks, with_pilot
from sssbake.pipeline.techniques.registry import TECHNIQUES
from sssbake.pipeline.techniques.technique import MATERIAL, MESH, Budget, TechniqueBake

# Bump a stage's version when its output for the same input changes (a technique's: its `stage_version`).
STAGE_VERSIONS = {"load": 5, "clean": 3, "atlas": 6, "thickness": 2, "thickness_map": 4, "escape_gain": 3,
                  **{t.name: t.stage_version for t in TECHNIQUES}, "pilot": 5}

LINEAR, CLAMP_TO_EDGE = 9729, 33071


@dataclass(frozen=True)
class BakeResult:
    """What `bake_asset` produced: the report (also written next to the outputs) and the paths."""

    report: dict
    outputs: tuple[Path, ...]
    up_to_date: bool = False


def _size_report(name: str, diag_mm: float, material: Material, warnings: list[str]) -> dict:
    mfp = diag_mm / material.mean_free_path_mm
    diff = diag_mm * material.sigma_tr
    if mfp.min() < 1.0:
        warnings.append(
            f"mesh {name!r} with {material.name!r} spans only {mfp.min():.3g} mean free paths: "
            "the diffusion model does not hold; is scale_mm right?"
        )
    if diff.min() > 1e4:
        warnings.append(
            f"mesh {name!r} with {material.name!r} spans {diff.min():.3g} diffusion lengths: "
            "scattering will be invisible; is scale_mm right?"
        )
    return {
        "material": material.name,
        "bbox_diagonal_mm": diag_mm,
        "size_in_mean_free_paths": mfp.tolist(),
        "size_in_diffusion_lengths": diff.tolist(),
    }


def _split_shared_materials(scene: Scene, translucent: set[int]) -> tuple[Scene, list[int]]:
    """Give every mesh its own copy of each scattering material it uses.

    A material's thickness texture lives in its mesh's atlas, so two meshes cannot share one.
    Returns the new scene and, per material, the index of the material it copies.
    """
    materials = list(scene.materials)
    origin = list(range(len(materials)))
    owner: dict[int, int] = {}
    meshes = []
    for mi, mesh in enumerate(scene.meshes):
        local: dict[int, int] = {}
        prims = []
        for p in mesh.primitives:
            m = p.material
            if m in translucent:
                if owner.setdefault(m, mi) != mi:
                    if m not in local:
                        local[m] = len(materials)
                        origin.append(m)
                        materials.append(replace(scene.materials[m], name=f"{scene.materials[m].name}.{mesh.name}"))
                    m = local[m]
            prims.append(replace(p, material=m) if m != p.material else p)
        meshes.append(Mesh(mesh.name, tuple(prims), mesh.deforming))
    return replace(scene, meshes=tuple(meshes), materials=tuple(materials)), origin


def _one_material(technique: str, mesh: Mesh, mats: list[int], scene: Scene, warnings: list[str]) -> None:
    """Warn that `technique` bakes a mesh of several scattering materials with the first one's."""
    if len(mats) > 1:
        warnings.append(f"mesh {mesh.name!r}: {technique} needs one scattering material per mesh, it has "
                        f"{len(mats)}; baked with {scene.materials[mats[0]].name!r}'s")


def _png_gray(values: np.ndarray) -> bytes:
    """8-bit greyscale PNG of `values` in [0, 1] (H, W): G reads the grey level in every sampler."""
    img = PILImage.fromarray(np.round(np.clip(values, 0.0, 1.0) * 255.0).astype(np.uint8), mode="L")
    buf = io.BytesIO()
    # zlib's default level: ``optimize`` (level 9) took 0.30 s of the 50k dragon's bake for a 2 % smaller file.
    img.save(buf, format="PNG", compress_level=6)
    return buf.getvalue()


def job_key(digest: str, options: BakeOptions, picks: dict | None = None) -> str:
    """What a bake's outputs are up to date with: the file's `digest`, the options, the stage
    versions, sssbake's version, the file schema's and, from the budget check, its `picks`."""
    return stage_key(digest, "bake", 1, {"options": options.to_json(), "stages": STAGE_VERSIONS,
                                         "sssbake": version("sssbake"), "schema": SCHEMA_VERSION,
                                         **({"picks": picks} if picks is not None else {})})


def dependencies_hold(dependencies, confinement: Confinement) -> bool:
    """Whether each (path, SHA-256) pair of `dependencies` (`Scene.dependencies`) still holds.

    A report or a shared cache entry names the files, so neither is trusted: a file that is
    missing, unreadable, not a regular file or outside `confinement` does not hold (and is not read).
    A digest ``""`` (missing when read) holds while nothing is at that path.
    """
    for file, digest in dependencies:
        try:
            if not digest:
                if os.path.lexists(file):
                    return False
            elif file_digest(confinement.check(file, f"dependency '{file}'")) != digest:
                return False
        except (AssetError, OSError, TypeError, ValueError):  # TypeError, ValueError: a garbled report's path
            return False
    return True


def report_dependencies_hold(report: dict, path: Path, options: BakeOptions) -> bool:
    """Whether the files the bake of `report` read besides the asset at `path` (its
    ``dependencies``, path -> SHA-256) are unchanged; a report without them does not hold."""
    recorded = report.get("dependencies")
    return isinstance(recorded, dict) and dependencies_hold(recorded.items(),
                                                            Confinement.for_asset(path, options.allow_roots))


@dataclass(eq=False)
class _Baking:
    """What the bake of one asset gathers, mesh by mesh: the `BakedAsset`'s parts and the report's blocks."""

    runner: StageRunner
    options: BakeOptions
    scene: Scene  # the materials split per mesh (`_split_shared_materials`)
    material_of: dict[int, Material | None]  # per material of `scene`, its scattering material (None: opaque)
    mm_per_unit: float
    warnings: list[str]
    meshes: list[Mesh] = field(init=False)
    images: list[Image] = field(init=False)
    textures: list[Texture] = field(init=False)
    attributes: dict[tuple[int, int], tuple[VertexAttribute, ...]] = field(default_factory=dict)
    scattering: dict[int, ScatteringMaterial] = field(default_factory=dict)
    scale_mm: dict[int, float] = field(default_factory=dict)
    mesh_extras: dict[int, dict] = field(default_factory=dict)
    material_extras: dict[int, dict] = field(default_factory=dict)
    sizes: dict[str, list] = field(default_factory=dict)
    atlases: dict[str, dict] = field(default_factory=dict)
    blocks: dict[str, dict] = field(default_factory=lambda: {t.name: {} for t in TECHNIQUES})  # report[t.name]
    plan: list[PlanEntry] = field(default_factory=list)  # the planner's entries (--techniques auto)
    material_options: dict[int, BakeOptions] = field(default_factory=dict)  # per material, its plan entry's
    used: set[str] = field(default_factory=set)  # techniques some mesh or material ran
    lambert_checks: list[dict] = field(default_factory=list)  # the pilot against best-fit Lambert (`lambert_record`)
    started: float = field(default_factory=time.monotonic)  # against asset_timeout_s (`_budget`)
    texels: TexelStages | None = None  # the meshes' thickness, atlas and thickness map (`texel_stages`)

    def __post_init__(self) -> None:
        self.meshes, self.images, self.textures = (list(self.scene.meshes), list(self.scene.images),
                                                   list(self.scene.textures))

    @property
    def auto(self) -> bool:
        return "auto" in self.options.techniques


@dataclass(frozen=True, eq=False)
class _MeshStages:
    """A scattering mesh's general stages: its atlas (and the atlas's key), thickness and thickness map."""

    atlas: Atlas
    atlas_key: str
    thickness: ThicknessResult
    thickness_map: ThicknessMap


def bake_asset(
    path: Path, options: BakeOptions, out_base: Path, cache: StageCache, *, trace_memory: bool = False,
    picks: dict[str, int] | None = None,
) -> BakeResult:
    """Bake the asset at `path` into ``out_base.glb``, ``.usdc`` and ``.report.json`` (and
    ``out_base.<name>.glb`` for each of the techniques' `Technique.extra_outputs`).

    `trace_memory` records each stage's peak traced allocation (slower; for benchmarks).
    `picks` (the budget check's, `plan_check`): per plan entry (`plan.PlanEntry.key`), the pilot's
    candidate to bake instead of the pilot's own choice.

    The outputs are up to date when the old report's `job_key` matches and every file the asset
    references (its ``dependencies``) still has its recorded digest; a cached scene is served
    likewise only while its files do, and the stages after it are keyed on their digests too.

    The outputs are written all or nothing (`staging`): when this raises, the output paths hold what
    they held before. Exported files with validation errors of their own fail the bake.

    Raises
    ------
    AssetError, MaterialError, ValueError
        With a one-line message.
    """
    t_start = time.perf_counter()
    path = Path(path)
    extra = _extra_outputs(options)
    outputs = _outputs(out_base, extra)
    digest = file_digest(path)
    key = job_key(digest, options, picks)
    old = _up_to_date(outputs, key, path, options)
    if old is not None:
        return BakeResult(old, outputs.paths, up_to_date=True)

    runner = StageRunner(cache, trace_memory)
    scene, clean, k_clean = _load(runner, path, digest, options)
    warnings = [*scene.warnings, *clean.warnings]
    clean, mesh_origin = _without_flat_nodes(clean, warnings)
    mm_per_unit, scale_source = resolve_scale_mm(clean.scene, options.scale_mm)
    assignment = assign_materials(clean.scene, options, mm_per_unit)
    translucent = {i for i, m in assignment.materials.items() if m is not None}
    split, origin = _split_shared_materials(assignment.scene, translucent)
    b = _Baking(runner, options, split, {i: assignment.materials.get(o) for i, o in enumerate(origin)}, mm_per_unit,
                warnings)
    keys = [stage_key(k_clean, "mesh", 0, {"mesh": mesh_origin[mi]}) for mi in range(len(split.meshes))]
    b.texels = TexelStages.start(runner, options, STAGE_VERSIONS, {
        mi: (split.meshes[mi], clean.surfaces[mi], keys[mi]) for mi in range(len(split.meshes))
        if _scattering_materials(b, mi)})
    try:
        for mi in range(len(split.meshes)):
            _bake_mesh(b, mi, clean.surfaces[mi], keys[mi], path, picks)
    finally:
        b.texels.close()
    _bake_materials(b)
    for t in TECHNIQUES:
        if t.name not in b.used:
            for stage, reason in t.dependent_stages.items():
                runner.skip(stage, reason)
            runner.skip(t.name, "the plan chose it for no object (--techniques auto)" if b.auto
                        else f"not requested (--techniques {t.name})")
    warnings.extend(runner.warnings)  # the stage cache's: damaged entries, a folder that took no entry
    # the unit the bake read the file in, also where --scale-mm overrode the file's own (the .usdc's
    # metersPerUnit and the engine materials' lengths follow it, as the fallback's do)
    baked_scene = replace(split, meshes=tuple(b.meshes), images=tuple(b.images), textures=tuple(b.textures),
                          materials=exported_materials(split.materials, outputs.usdc.stem),
                          meters_per_unit=mm_per_unit / 1000.0)
    extras = {
        "scaleMmPerUnit": mm_per_unit,
        "scaleSource": scale_source,
        "thickness": {"unit": "mm", "raysPerSample": options.thickness_rays,
                      "missCap": "bounding-box diagonal; a ray that meets no surface ends where the winding "
                                 "number falls to 1/2"},
    }
    asset = BakedAsset(baked_scene, b.attributes, b.scattering, b.scale_mm, extras, b.mesh_extras, b.material_extras)
    head = {
        "asset": str(path),
        "job_key": key,
        "dependencies": dict(scene.dependencies),
        "schema_version": SCHEMA_VERSION,
        "sssbake": version("sssbake"),
        "outputs": [str(p) for p in outputs.paths],
        "scale_mm_per_unit": mm_per_unit,
        "scale_source": scale_source,
        "vertices": sum(len(p.positions) for m in baked_scene.meshes for p in m.primitives),
        "faces": sum(len(p.faces) for m in baked_scene.meshes for p in m.primitives),
        "materials": _materials_block(b, assignment, origin),
        "sizes": b.sizes,
        "atlas": b.atlases,
        **b.blocks,
        "plan": [e.to_json() for e in b.plan],
        "lambert_checks": b.lambert_checks,
    }
    return BakeResult(_write(b, asset, outputs, extra, head, path, t_start), outputs.paths)


def up_to_date_result(path: Path, options: BakeOptions, out_base: Path) -> BakeResult | None:
    """What `bake_asset` returns at once when the outputs of `path` under `options` (no budget
    picks) are up to date, else None: a batch checks it before it starts a worker."""
    outputs = _outputs(out_base, _extra_outputs(options))
    if not all(p.exists() for p in outputs.paths):
        return None
    old = _up_to_date(outputs, job_key(file_digest(path), options), Path(path), options)
    return BakeResult(old, outputs.paths, up_to_date=True) if old is not None else None


@dataclass(frozen=True)
class _Outputs:
    """The files one asset's bake writes, each by what it is.

    Attributes
    ----------
    glb, usdc, report : Path
        ``<base>.glb``, ``<base>.usdc``, ``<base>.report.json``.
    mtlx : Path
        The .usdc's OpenPBR MaterialX document (`materialx_file`).
    variants : dict of str to Path
        ``<base>.<name>.glb`` per extra output of the techniques (`_extra_outputs`), in its order.
    materials : Path
        ``<base>.materials.json``, the engine-native materials (`write_materials_json`).
    """

    glb: Path
    usdc: Path
    report: Path
    mtlx: Path
    variants: dict[str, Path]
    materials: Path

    @property
    def paths(self) -> tuple[Path, ...]:
        """Every output, in the order the reports list them."""
        return (self.glb, self.usdc, self.report, self.mtlx, *self.variants.values(), self.materials)


def _outputs(out_base: Path, extra: dict) -> _Outputs:
    """The outputs of a bake to `out_base` with the techniques' `extra` variants."""
    usdc = out_base.with_suffix(".usdc")
    return _Outputs(glb=out_base.with_suffix(".glb"), usdc=usdc, report=out_base.with_suffix(".report.json"),
                    mtlx=usdc.with_name(materialx_file(usdc.stem)),
                    variants={name: out_base.with_suffix(f".{name}.glb") for name in extra},
                    materials=out_base.with_suffix(".materials.json"))


def exported_materials(materials: tuple[SourceMaterial, ...], stem: str) -> tuple[SourceMaterial, ...]:
    """`materials` as the outputs name them: ``<stem>_<name>``, `stem` the outputs' file stem.

    Engines that share materials by name (Godot's import, a USD stage composing several assets) would
    otherwise merge two assets' materials of one name (every ``sssbake_default``, two sources' ``Skin``),
    and one asset would show the other's colour. Only the written names change: the config's rules,
    the plan and the report use the source names.
    """
    return tuple(replace(m, name=f"{stem}_{m.name}") for m in materials)


def _extra_outputs(options: BakeOptions) -> dict[str, Callable[[BakedAsset], BakedAsset]]:
    """The techniques' extra files under `options` (`Technique.extra_outputs`), in registry order."""
    return {name: make for t in TECHNIQUES for name, make in t.extra_outputs(options.technique_options(t.name)).items()}


def _up_to_date(outputs: _Outputs, key: str, path: Path, options: BakeOptions) -> dict | None:
    """The old report when every output exists (the .usdc's thickness textures too), its `job_key` is
    `key`, its dependencies hold and its outputs have no validation errors of their own (a bake
    never leaves such outputs, `_write`; an older one did), nor skipped a validator that is there now."""
    if not all(p.exists() for p in outputs.paths):
        return None
    try:
        old = json.loads(outputs.report.read_text())
        # by name beside the .usdc, as it references them: the folder may have moved
        textures = [outputs.usdc.parent / Path(t).name for t in old["bytes"]["usdc"].get("textures", [])]
        if _invalid(old.get("validation", {})) or _validator_installed_since(old["validation"]):
            return None
    except (OSError, ValueError, KeyError, TypeError, AttributeError):
        return None
    if not all(t.is_file() for t in textures):
        return None
    return old if old.get("job_key") == key and report_dependencies_hold(old, path, options) else None


def _load(runner: StageRunner, path: Path, digest: str, options: BakeOptions) -> tuple[Scene, CleanScene, str]:
    """The scene as read, cleaned, and the key the stages after them build on."""
    confinement = Confinement.for_asset(path, options.allow_roots)
    scene, k_load = runner.run("load", STAGE_VERSIONS["load"], digest, LoadParams(options.allow_roots), load_stage,
                               str(path), fresh=lambda cached: dependencies_hold(cached.dependencies, confinement))
    # The asset's digest alone does not name the scene: a changed buffer, texture or layer changes every later key.
    # Nor do the allowed roots, which only decide whether it may be read: keyed on what was read.
    k_load = stage_key(digest, "dependencies", STAGE_VERSIONS["load"], dict(scene.dependencies))
    clean, k_clean = runner.run("clean", STAGE_VERSIONS["clean"], k_load, None, clean_scene, scene)
    return scene, clean, k_clean


def _without_flat_nodes(clean: CleanScene, warnings: list[str]) -> tuple[CleanScene, list[int]]:
    """`clean` without the nodes whose world transform is singular (a scale of 0 along some axis),
    those below them, and the meshes only they place; a warning names each node and mesh left out.

    What such a node places has no volume for light to scatter in: its mesh's millimetres per unit
    (`scale.instance_scale`) would be 0, and glTF cannot hold its matrix (not decomposable to TRS).
    Also returns, per mesh left, its index in `clean`, which its stages are keyed on.

    Raises
    ------
    AssetError
        When nodes of scale 0 place every mesh.
    """
    scene = clean.scene
    flat = {i for i, world in scene.world_matrices().items() if np.linalg.det(world[:3, :3]) == 0.0}
    if not flat:
        return clean, list(range(len(scene.meshes)))
    parent = {c: i for i, node in enumerate(scene.nodes) for c in node.children}
    for i in sorted(flat):
        if parent.get(i) not in flat:  # the topmost: every node below it is flat too
            below, stack = -1, [i]
            while stack:
                below += 1
                stack.extend(scene.nodes[stack.pop()].children)
            warnings.append(f"node {scene.nodes[i].name!r} has scale 0 (a singular transform): what it places has no "
                            f"volume; left out{f' with the {below} nodes below it' if below else ''}")
    kept = [i for i in range(len(scene.nodes)) if i not in flat]
    placed = {scene.nodes[i].mesh for i in kept} - {None}
    gone = {n.mesh for n in scene.nodes} - {None} - placed
    meshes = [m for m in range(len(scene.meshes)) if m not in gone]
    if not meshes:
        raise AssetError(scene.source, "every mesh is placed by a node of scale 0 (a singular transform): nothing has "
                                       "volume to bake")
    warnings.extend(f"mesh {scene.meshes[m].name!r} is placed only by nodes of scale 0; left out" for m in sorted(gone))
    node_index = {old: new for new, old in enumerate(kept)}
    mesh_index = {old: new for new, old in enumerate(meshes)}
    nodes = tuple(replace(scene.nodes[i], mesh=mesh_index.get(scene.nodes[i].mesh),
                          children=tuple(node_index[c] for c in scene.nodes[i].children if c not in flat))
                  for i in kept)
    scene = replace(scene, meshes=tuple(scene.meshes[m] for m in meshes), nodes=nodes,
                    roots=tuple(node_index[r] for r in scene.roots if r not in flat))
    return replace(clean, scene=scene, surfaces=tuple(clean.surfaces[m] for m in meshes)), meshes


def _bake_mesh(b: _Baking, mi: int, surface: Surface, mesh_key: str, path: Path, picks: dict | None) -> None:
    """Mesh `mi`: its sizes and, when it scatters, its general stages, the techniques chosen for it and
    its baked primitives, thickness texture and scattering materials.

    The thickness, atlas and thickness map come from a child that made them beside the escape gain
    and the plan where the worker could fork one (`texel_stages`), else they are made here, in turn.
    """
    mesh = b.scene.meshes[mi]
    mesh_mm = b.mm_per_unit * instance_scale(b.scene, mi, b.warnings)
    b.scale_mm[mi] = mesh_mm
    diag_mm = miss_cap(surface) * mesh_mm
    mats = _scattering_materials(b, mi)
    for m in mats:  # each mesh has its own copy of its materials (`_split_shared_materials`)
        b.material_of[m] = _with_escape_gain(b, surface, mesh_key, b.material_of[m], mesh_mm)
    b.sizes[mesh.name] = [_size_report(mesh.name, diag_mm, b.material_of[m], b.warnings) for m in mats]
    if not mats:
        return
    thick = _thickness(b, mi, surface)
    if b.auto:
        chosen, mesh_options = _plan_mesh(b, mi, mats, surface, thick, mesh_mm, mesh_key, path, picks)
    else:
        chosen, mesh_options = set(b.options.techniques), b.options
        for m in mats:  # baked as asked, but measured against best-fit Lambert all the same
            b.lambert_checks += requested_checks(mesh.name, b.scene.materials[m].name, b.options.techniques,
                                                 surface, mesh_mm, b.material_of[m], b.options, _world(b, mi),
                                                 _cached_pilot(b, mesh_key))
    b.used |= chosen
    results = _bake_mesh_techniques(b, mi, mats, surface, None, mesh_mm, mesh_key, chosen, mesh_options)
    # after the plan: the input's UVs may serve unless kernels, which need gutters, were chosen
    atlas, k_atlas = _atlas(b, mi, "kernels" not in chosen)
    stages = _MeshStages(atlas, k_atlas, thick, b.texels.thickness_map(mi, atlas))
    results |= _bake_mesh_techniques(b, mi, mats, surface, stages, mesh_mm, mesh_key, chosen, mesh_options)
    _baked_mesh(b, mi, mats, surface, stages, mesh_mm, results)


def _scattering_materials(b: _Baking, mi: int) -> list[int]:
    """The scattering materials of mesh `mi`'s primitives."""
    return sorted({p.material for p in b.scene.meshes[mi].primitives if b.material_of.get(p.material) is not None})


def _atlas(b: _Baking, mi: int, reuse_input: bool) -> tuple[Atlas, str]:
    """Mesh `mi`'s atlas (the input's UVs when `reuse_input` and they pass) and its key, recorded
    in the report's ``atlas`` block: which UVs (``uvs``: TEXCOORD_n, proxy or charted) and why
    the others were refused."""
    mesh = b.scene.meshes[mi]
    atlas, k_atlas = b.texels.atlas(mi, reuse_input)
    b.atlases[mesh.name] = {
        "uvs": atlas.source, "refused": list(atlas.notes),
        "width": atlas.width, "height": atlas.height, "charts": atlas.chart_count, "jittered": atlas.jittered,
        # The child's own peak (a cached atlas reports the run that made it): the parent's RSS misses it.
        "xatlas_peak_rss_mb": round(atlas.worker_peak_rss_mb, 1) if np.isfinite(atlas.worker_peak_rss_mb) else None,
    }
    return atlas, k_atlas


def _with_escape_gain(b: _Baking, surface: Surface, mesh_key: str, material: Material, mesh_mm: float) -> Material:
    """`material` with the escape gain of the mesh's closed `surface` (a cached stage), which every
    technique's profile then carries: the ``montecarlo`` profile is matched to physics; the
    classical dipole stays the papers' half-space model."""
    if material.profile != "montecarlo":
        return material
    half_space = material.half_space
    (_, gain, back), _ = b.runner.run("escape_gain", STAGE_VERSIONS["escape_gain"], mesh_key,
                                      EscapeGainParams(half_space, mesh_mm), escape_gain_stage, surface)
    return replace(material, escape_gain=tuple(float(x) for x in gain), back_gain=tuple(float(x) for x in back))


def _thickness(b: _Baking, mi: int, surface: Surface) -> ThicknessResult:
    """Per-vertex thickness of mesh `mi`'s welded `surface` (warnings naming the rays that met no
    surface, started outside or found no inside, and the surface's defects)."""
    thick = b.texels.thickness(mi)
    b.warnings.extend(f"mesh {b.scene.meshes[mi].name!r} {line}" for line in miss_warnings(thick, surface.faces))
    return thick


def _plan_mesh(b: _Baking, mi: int, mats: list[int], surface: Surface, thickness: ThicknessResult, mesh_mm: float,
               mesh_key: str, path: Path, picks: dict | None) -> tuple[set[str], BakeOptions]:
    """The planner's entries for mesh `mi`'s materials (``--techniques auto``; the pilot a cached
    stage): the techniques they choose and the options they set."""
    mesh = b.scene.meshes[mi]
    entries = []
    for m in mats:
        e = decide(str(path), mesh.name, b.scene.materials[m].name, b.material_of[m], mesh.deforming, b.options,
                   surface, thickness.thickness, mesh_mm)
        entries.append(with_pilot(e, surface, mesh_mm, b.material_of[m], mesh.deforming, b.options, _world(b, mi),
                                  (picks or {}).get(e.key), _cached_pilot(b, mesh_key)))
    b.plan += entries
    b.lambert_checks += [e.lambert_check for e in entries if e.lambert_check]
    # material-scope techniques are baked after the meshes: each material keeps its entry's options
    b.material_options.update({m: b.options.merged(e.params) for m, e in zip(mats, entries)})
    return {t for e in entries for t in e.techniques}, b.options.merged({k: v for e in entries for k, v in e.params.items()})


def _world(b: _Baking, mi: int) -> np.ndarray:
    """(4, 4) world matrix of mesh `mi`'s first instance: the pilot sees the mesh as verify does."""
    return np.asarray((b.scene.mesh_instances().get(mi) or [np.eye(4)])[0])


def _cached_pilot(b: _Baking, mesh_key: str):
    """`pilot.run_pilot` for a mesh keyed `mesh_key`, as a cached stage (it takes the same arguments),
    keyed on what it reads: its candidates, their techniques' options as their bakes key them, the
    budget and the margin over best-fit Lambert; an option none of them reads reruns nothing."""

    def cached_pilot(found, surface, mm, material, options, budget, vertices, world):
        read = {"budget_rmse": budget, "lambert_margin": options.lambert_margin,
                **{t.name: t.stage_options(options.technique_options(t.name)) for t in TECHNIQUES
                   if any(c.technique == t.name for c in found)}}
        params = PilotParams(material, mm, read, tuple(found), np.asarray(world))
        return b.runner.run("pilot", STAGE_VERSIONS["pilot"], mesh_key, params, pilot_stage, surface, options, budget,
                            vertices)[0]

    return cached_pilot


def _bake_mesh_techniques(b: _Baking, mi: int, mats: list[int], surface: Surface, stages: _MeshStages | None,
                          mesh_mm: float, mesh_key: str, chosen: set[str], options: BakeOptions) -> dict[str, TechniqueBake]:
    """The `chosen` mesh-scope techniques on mesh `mi` under `options`, with its first scattering
    material: those that read the atlas when `stages` is given, else the others."""
    mesh = b.scene.meshes[mi]
    primitives = tuple((p.positions, p.normals) for p in mesh.primitives)
    results = {}
    for t in TECHNIQUES:
        if t.scope != MESH or t.name not in chosen or t.needs_atlas != (stages is not None):
            continue
        _one_material(t.name, mesh, mats, b.scene, b.warnings)
        geometry = {"surface": surface, "primitives": primitives, "budget": _budget(b)}
        if t.needs_atlas:
            geometry.update(atlas=stages.atlas, atlas_padding=b.options.atlas_padding)
        # Keyed on the atlas when the technique reads it, else on the mesh: the welded surface.
        result, _ = b.runner.run(t.name, t.stage_version, stages.atlas_key if t.needs_atlas else mesh_key,
                                 TechniqueParams(b.material_of[mats[0]], mesh_mm,
                                                 t.stage_options(options.technique_options(t.name))),
                                 technique_stage, t, geometry)
        b.warnings.extend(f"mesh {mesh.name!r}: {w}" for w in result.warnings)
        if result.tables is not None:
            b.mesh_extras.setdefault(mi, {})[t.name] = result.tables
        b.blocks[t.name][mesh.name] = result.report
        results[t.name] = result
    return results


def _budget(b: _Baking) -> Budget:
    """What the asset may still spend as a technique starts: its worker's limits (`asset_memory_gib`,
    `asset_timeout_s`, 0 for none) less this process's resident memory and the time since the bake began."""
    memory, seconds = b.options.asset_memory_gib, b.options.asset_timeout_s
    return Budget(memory * 2.0**30 - psutil.Process().memory_info().rss if memory else None,
                  seconds - (time.monotonic() - b.started) if seconds else None)


def _baked_mesh(b: _Baking, mi: int, mats: list[int], surface: Surface, stages: _MeshStages, mesh_mm: float,
                results: dict[str, TechniqueBake]) -> None:
    """Mesh `mi` as written: its primitives on the atlas with their vertex attributes, its
    thickness texture and its materials' fallbacks."""
    mesh = b.scene.meshes[mi]
    thick = stages.thickness.thickness
    tmax = max(float(stages.thickness_map.image.max()), float(thick.max()), 1e-30)
    b.images.append(Image(f"{mesh.name}_thickness", "image/png", _png_gray(stages.thickness_map.image / tmax)))
    # No mipmaps: below the gutter's width a mip level blends neighbouring charts' thicknesses.
    b.textures.append(Texture(len(b.images) - 1, LINEAR, LINEAR, CLAMP_TO_EDGE, CLAMP_TO_EDGE))
    # the thickness texture reads the input's own UV set when the atlas is it, else a new last set
    reused = stages.atlas.input_uv_set
    uv_set = max(len(p.uvs) for p in mesh.primitives) if reused is None else reused
    prims = []
    for pi, (p, part) in enumerate(zip(mesh.primitives, stages.atlas.parts)):
        vm = part.vmapping
        uvs = tuple(uv[vm] for uv in p.uvs)
        if reused is None:
            uvs = uvs + (np.zeros((len(vm), 2)),) * (uv_set - len(uvs)) + (part.uvs,)
        prims.append(replace(
            p, positions=p.positions[vm], faces=part.faces, normals=p.normals[vm], uvs=uvs,
            tangents=p.tangents[vm] if p.tangents is not None else None,
            colors=p.colors[vm] if p.colors is not None else None,
        ))
        if b.material_of.get(p.material) is not None:
            welded = surface.weld[pi][vm]
            b.attributes[(mi, pi)] = (
                VertexAttribute("thickness", padded(thick[welded] * mesh_mm), "mm", "float32",
                                "distance through the object along the inward normal; components 1, 2 are 0"),
                *(a for t in TECHNIQUES if t.name in results for a in t.vertex_attributes(results[t.name], welded)),
            )
    b.meshes[mi] = Mesh(mesh.name, tuple(prims))
    if mi in b.mesh_extras:  # in registry order, however the stages ran
        b.mesh_extras[mi] = {t.name: b.mesh_extras[mi][t.name] for t in TECHNIQUES if t.name in b.mesh_extras[mi]}
    ref = TextureRef(len(b.textures) - 1, uv_set)
    for m in mats:
        # a Lambert-like look: the half-space albedo (docs/fidelity.md: the escape gain fits light spread by diffusion)
        fallback = make_fallback(b.material_of[m].half_space, mesh_mm, thick * mesh_mm, ref, tmax)
        b.scattering[m] = ScatteringMaterial(b.material_of[m], fallback, b.scene.materials[m].name)


def _bake_materials(b: _Baking) -> None:
    """The material-scope techniques, per scattering material: those the plan gave it (auto), else
    every requested one. Keyed on the material and the options alone: no mesh data."""
    for t in TECHNIQUES:
        if t.scope != MATERIAL:
            continue
        chosen = ({m for m in b.scattering if any(e.material == b.scene.materials[m].name and t.name in e.techniques
                                                  for e in b.plan)} if b.auto
                  else set(b.scattering) if t.name in b.options.techniques else set())
        if chosen:
            b.used.add(t.name)
        for m in sorted(chosen):
            options = t.stage_options(b.material_options.get(m, b.options).technique_options(t.name))
            result, _ = b.runner.run(t.name, t.stage_version, "material",
                                     TechniqueParams(b.scattering[m].material, 1.0, options), technique_stage, t, {})
            name = b.scene.materials[m].name
            b.warnings.extend(f"material {name!r}: {w}" for w in result.warnings)
            if result.tables is not None:
                b.material_extras.setdefault(m, {})[t.name] = result.tables
            b.blocks[t.name][name if name not in b.blocks[t.name] else f"{name}#{m}"] = result.report


def _materials_block(b: _Baking, assignment: Assignment, origin: list[int]) -> dict:
    """The report's ``materials``: per material a primitive uses, its scattering material and why."""
    used = {p.material for mesh in b.scene.meshes for p in mesh.primitives}
    return {
        b.scene.materials[i].name: {"scattering": m.to_json() if m is not None else None,
                                    "reason": assignment.reasons.get(origin[i], "")}
        for i, m in b.material_of.items() if i in used
    }


def _write(b: _Baking, asset: BakedAsset, outputs: _Outputs, extra: dict, head: dict, path: Path,
           t_start: float) -> dict:
    """Export `asset` to `outputs` (`extra`'s variants after the report), validate them and write the
    report (`head`, then bytes, validation, stages, seconds and warnings), all in a staging folder
    (`staging`): moved into place, the report last, only once every file is written and none has
    validation errors of its own; when this raises, the output paths hold what they held before."""
    folder = outputs.glb.parent
    with staging(folder) as staged:
        at = {p: staged / p.name for p in outputs.paths}
        summaries = {}
        # the draft extension's numbers are the .materials.json's, computed the same way
        scatter = khr_volume_scatter(asset) if b.options.khr_materials_volume_scatter else None
        with b.runner.timed("export_gltf"):
            summaries["glb"] = write_glb(asset, at[outputs.glb], scatter)
        with b.runner.timed("export_mtlx"):
            summaries["mtlx"] = write_mtlx(asset, at[outputs.mtlx])
        with b.runner.timed("export_usd"):  # after the .mtlx its Material prims name: USD's validation resolves it
            summaries["usdc"] = write_usdc(asset, at[outputs.usdc], outputs.mtlx.name)
        textures = [Path(t).name for t in summaries["usdc"]["textures"]]
        summaries["usdc"]["textures"] = [str(folder / t) for t in textures]  # where they are moved
        with b.runner.timed("export_materials_json"):
            summaries["materials_json"] = write_materials_json(asset, at[outputs.materials], outputs.glb.stem)
        for name, make in extra.items():
            with b.runner.timed(f"export_{name}"):
                summaries[f"{name}_glb"] = write_glb(make(asset), at[outputs.variants[name]], scatter)
        glbs = {"gltf": at[outputs.glb], **{f"gltf_{name}": at[out] for name, out in outputs.variants.items()}}
        validation = _validate(b.runner, glbs, at[outputs.usdc], b.options, b.warnings, path, len(b.scene.images))
        invalid = _invalid(validation)
        if invalid:
            raise AssetError(path, f"exported files are invalid ({invalid.replace(str(staged), str(folder))})")
        report = {
            **head,
            "bytes": {fmt: {k: v for k, v in summary.items() if k != "path"} for fmt, summary in summaries.items()},
            "validation": validation,
            "stages": b.runner.to_json(),
            "seconds": round(time.perf_counter() - t_start, 4),
            "warnings": b.warnings,
        }
        with atomic_path(at[outputs.report]) as tmp:
            Path(tmp).write_text(json.dumps(report, indent=1, default=json_default))
        # the .usdc after the textures and the .mtlx it references, the report (what says the set is up to date) last
        commit(staged, [p.name for p in (outputs.glb, *outputs.variants.values(), outputs.materials)] + textures
               + [outputs.mtlx.name, outputs.usdc.name, outputs.report.name], folder)
    return report


def _validator_installed_since(validation: dict) -> bool:
    """Whether outputs written unvalidated for want of node or gltf-validator could be validated now."""
    if not any(v.get("validator_missing") for v in validation.values()):
        return False  # the common case: nothing to look for, no lookup
    from sssbake.exporters.gltf_validator import validator_available

    return validator_available()


def _invalid(validation: dict) -> str:
    """What `_validate`'s `validation` finds wrong with the outputs themselves, inherited problems and
    warnings aside: per format with errors, their count and the first; ``""`` when none has any."""
    found = []
    for fmt, v in validation.items():
        if v.get("errors"):
            own = [m if isinstance(m, str) else f"{m['code']} at {m['pointer']}: {m['message']}"  # USD's are lines
                   for m in v["messages"] if isinstance(m, str) or (m["severity"] == "Error" and not m["inherited"])]
            found.append(f"{fmt}: {v['errors']} error(s)" + (f", first {own[0]}" if own else ""))
    return "; ".join(found)


def _validate(runner: StageRunner, glbs: dict[str, Path], usdc: Path, options: BakeOptions, warnings: list[str],
              source: Path | None = None, copied_images: int = 0) -> dict:
    """Validate the outputs (`glbs`, by their ``validation`` key, and `usdc`); a glTF/GLB `source`
    is validated too, in the same node process.

    An output message is ``"inherited": true`` when the source's report has its code, or when it is
    about the data of one of the first `copied_images` images (the source's, copied byte for byte:
    an OBJ's PNG is not validated as input). Per glTF output: ``errors``/``warnings`` count sssbake's
    own, ``inherited_errors``/``inherited_warnings`` the inherited ones, ``input`` the source's counts;
    or, where the validator could not run (`ValidatorUnavailable`), only ``skipped``, the one-line
    reason, and ``validator_missing``: true for no node or no gltf-validator, false for a hierarchy
    past the depth it checks.
    """
    # glTF-Validator's codes about an image's bytes (not about the JSON that describes it)
    image_data_codes = {"IMAGE_DATA_INVALID", "IMAGE_FEATURES_UNSUPPORTED", "IMAGE_MIME_TYPE_INVALID",
                        "IMAGE_UNEXPECTED_EOS", "IMAGE_UNRECOGNIZED_FORMAT"}
    if not options.validate:
        runner.skip("validate", "turned off (--no-validate)")
        return {}
    from sssbake.exporters.gltf_validator import ValidatorLimit, ValidatorUnavailable, validate_many
    from sssbake.exporters.usd_validator import validate_usd

    out = {}
    with runner.timed("validate"):
        # one validator run for the input and every glb
        gltf_source = source is not None and Path(source).suffix.lower() in (".gltf", ".glb")
        try:
            try:
                reports = validate_many(([source] if gltf_source else []) + list(glbs.values()))
            except RuntimeError as e:  # the validator cannot read the input at all: the outputs alone
                if not gltf_source:
                    raise
                warnings.append(f"the input was not validated: {str(e).splitlines()[0]}")
                gltf_source, reports = False, validate_many(list(glbs.values()))
            source_report = reports.pop(0) if gltf_source else None
            source_codes = ({m.code for m in source_report.messages if m.severity in ("Error", "Warning")}
                            if source_report is not None else set())

            def inherited(m) -> bool:
                parts = m.pointer.split("/")
                copied = (m.code in image_data_codes and len(parts) == 3 and parts[1] == "images"
                          and parts[2].isdigit() and int(parts[2]) < copied_images)
                return m.code in source_codes or copied

            for name, g in zip(glbs, reports):
                shown = [m for m in g.messages if m.severity in ("Error", "Warning")]
                flags = [inherited(m) for m in shown]
                inherited_errors = sum(f for m, f in zip(shown, flags) if m.severity == "Error")
                inherited_warnings = sum(f for m, f in zip(shown, flags) if m.severity == "Warning")
                out[name] = {"errors": g.num_errors - inherited_errors, "warnings": g.num_warnings - inherited_warnings,
                             "inherited_errors": inherited_errors, "inherited_warnings": inherited_warnings,
                             "infos": g.num_infos,
                             "messages": [{**m.to_json(), "inherited": f} for m, f in zip(shown, flags)]}
                if source_report is not None:
                    out[name]["input"] = {"errors": source_report.num_errors, "warnings": source_report.num_warnings,
                                          "infos": source_report.num_infos}
        except ValidatorUnavailable as e:  # no node or no validator: the files are written unchecked, and say so
            warnings.append(f"glTF validation skipped: {e}")
            # `_up_to_date` bakes them again once a validator is installed; a hierarchy too deep stays too deep
            missing = not isinstance(e, ValidatorLimit)
            out.update({name: {"skipped": str(e), "validator_missing": missing} for name in glbs})
        u = validate_usd(usdc)
        out["usd"] = {"errors": len(u.errors), "warnings": len(u.warnings), "messages": list(u.errors)}
    return out


def json_default(o):
    """JSON for the numpy values a report holds (`json.dumps`' default)."""
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, (np.floating, np.integer)):
        return o.item()
    raise TypeError(f"not JSON-serialisable: {type(o).__name__}")
