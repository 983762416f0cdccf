"""Bakes one asset: load → clean → assign materials → atlas → thickness → export → validate.

Only the stages a scene needs run: a scene whose materials are all opaque gets no atlas and no
thickness; simplification runs only for techniques that need reference points (none yet).
"""

from __future__ import annotations

import io
import json
import os
import time
from dataclasses import dataclass, replace
from importlib.metadata import version
from pathlib import Path

import numpy as np
from PIL import Image as PILImage

from ..exporters.atomic import atomic_path
from ..exporters.gltf import write_glb
from ..exporters.usd import write_usdc
from .assign import assign_materials
from .atlas import compute_atlas
from .baked import SCHEMA_VERSION, BakedAsset, ScatteringMaterial, VertexAttribute
from .cache import StageCache, file_digest, stage_key
from .clean import CleanScene, clean_scene
from .confine import Confinement
from .fallback import make_fallback
from .load import AssetError, load_scene
from .materials import Material
from .options import BakeOptions
from .kernels_layout import kernels_tables, kernels_vertex_attributes
from .kernels_stage import bake_kernels
from .prt_layout import prt_tables, prt_vertex_attributes
from .prt_stage import bake_prt
from .screen_stage import bake_screen
from .lpv_stage import LPV_COARSE, bake_lpv
from .scene import Image, Mesh, Scene, SourceMaterial, Texture, TextureRef
from .spectral_layout import normals_variant, spectral_vertex_attributes
from .spectral_stage import bake_spectral
from .stages import StageRunner
from .thickness import bake_thickness
from .thickness_map import bake_thickness_map

# Bump a stage's version when its output for the same input changes.
STAGE_VERSIONS = {"load": 4, "clean": 3, "atlas": 3, "thickness": 1, "thickness_map": 1, "prt": 3, "kernels": 3,
                  "spectral": 1, "screen": 1, "lpv": 2, "pilot": 3}

LINEAR, LINEAR_MIPMAP_LINEAR, CLAMP_TO_EDGE = 9729, 9987, 33071


@dataclass(frozen=True)
class BakeResult:
    """What `bake_asset` produced: the report (also written next to the outputs) and the paths."""

    report: dict
    outputs: tuple[Path, ...]
    up_to_date: bool = False


def resolve_scale_mm(scene: Scene, options: BakeOptions) -> tuple[float, str]:
    """Millimetres per file unit and where that number came from; refuses to guess."""
    if options.scale_mm is not None:
        return float(options.scale_mm), "given"
    if scene.meters_per_unit is not None:
        return 1000.0 * scene.meters_per_unit, "declared by the file"
    raise AssetError(
        scene.source,
        "no scale: this format carries no unit; pass --scale-mm (millimetres per file unit) or set scale_mm in the config",
    )


def _instance_scale(scene: Scene, mesh_index: int, warnings: list[str]) -> float:
    """Uniform world scale of the nodes instancing a mesh (1 when it is not instanced)."""
    worlds = scene.mesh_instances().get(mesh_index, [])
    scales = [abs(float(np.linalg.det(w[:3, :3]))) ** (1.0 / 3.0) for w in worlds]
    if not scales:
        return 1.0
    if max(scales) > min(scales) * (1 + 1e-6):
        warnings.append(
            f"mesh {scene.meshes[mesh_index].name!r} is instanced at scales {min(scales):.4g}..{max(scales):.4g}; "
            "baked with the first instance's scale"
        )
    return scales[0]


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
    img.save(buf, format="PNG", optimize=True)
    return buf.getvalue()


def job_key(digest: str, options: BakeOptions, picks: dict | None = None) -> str:
    """What a bake's outputs are up to date with: the file's `digest`, the options, the stage
    versions, sssbake's version and, from the budget check, its `picks`."""
    return stage_key(digest, "bake", 1, {"options": options.to_json(), "stages": STAGE_VERSIONS,
                                         "sssbake": version("sssbake"), **({"picks": picks} if picks is not None else {})})


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


def bake_asset(
    path: Path, options: BakeOptions, out_base: Path, cache: StageCache, *, trace_memory: bool = False,
    picks: dict[str, int] | None = None,
) -> BakeResult:
    """Bake the asset at `path` into ``out_base.glb``, ``.usdc`` and ``.report.json`` (and
    ``.sss_normals.glb`` with `BakeOptions.spectral_variant`).

    `trace_memory` records each stage's peak traced allocation (slower; for benchmarks).
    `picks` (the budget check's, `plan_check`): per plan entry (`plan.PlanEntry.key`), the pilot's
    candidate to bake instead of the pilot's own choice.

    The outputs are up to date when the old report's `job_key` matches and every file the asset
    references (its ``dependencies``) still has its recorded digest; a cached scene is served
    likewise only while its files do, and the stages after it are keyed on their digests too.

    Raises
    ------
    AssetError, MaterialError, ValueError
        With a one-line message; nothing is left at the output paths.
    """
    t_start = time.perf_counter()
    path = Path(path)
    outputs = (out_base.with_suffix(".glb"), out_base.with_suffix(".usdc"), out_base.with_suffix(".report.json"))
    if options.spectral_variant:
        outputs += (out_base.with_suffix(".sss_normals.glb"),)
    digest = file_digest(path)
    key = job_key(digest, options, picks)
    if all(p.exists() for p in outputs):
        try:
            old = json.loads(outputs[2].read_text())
        except (OSError, ValueError):
            old = {}
        if old.get("job_key") == key and report_dependencies_hold(old, path, options):
            return BakeResult(old, outputs, up_to_date=True)

    runner = StageRunner(cache, trace_memory)
    warnings: list[str] = []
    confinement = Confinement.for_asset(path, options.allow_roots)
    # The allowed roots are in the key: a scene read under a wider allowance must not serve a narrower one.
    scene, k_load = runner.run("load", STAGE_VERSIONS["load"], digest, {"allow_roots": list(options.allow_roots)},
                               load_scene, str(path), options.allow_roots,
                               fresh=lambda cached: dependencies_hold(cached.dependencies, confinement))
    dependencies = dict(scene.dependencies)
    # The asset's digest alone does not name the scene: a changed buffer, texture or layer changes every later key.
    k_load = stage_key(k_load, "dependencies", 0, dependencies)
    clean, k_clean = runner.run("clean", STAGE_VERSIONS["clean"], k_load, {}, clean_scene, scene)
    clean: CleanScene
    warnings.extend(scene.warnings)
    warnings.extend(clean.warnings)
    mm_per_unit, scale_source = resolve_scale_mm(clean.scene, options)
    assignment = assign_materials(clean.scene, options, mm_per_unit)
    translucent = {i for i, m in assignment.materials.items() if m is not None}
    scene, origin = _split_shared_materials(assignment.scene, translucent)
    material_of = {i: assignment.materials.get(o) for i, o in enumerate(origin)}
    auto = "auto" in options.techniques
    plan: list = []  # the planner's entries (--techniques auto)
    screen_options: dict[int, BakeOptions] = {}  # per material, the plan's
    used: set[str] = set()  # techniques some mesh or material ran
    mesh_extras: dict[int, dict] = {}
    prt_reports: dict[str, dict] = {}
    kernels_reports: dict[str, dict] = {}
    spectral_reports: dict[str, dict] = {}
    lpv_reports: dict[str, dict] = {}

    meshes = list(scene.meshes)
    instances = scene.mesh_instances()
    images, textures = list(scene.images), list(scene.textures)
    attributes: dict[tuple[int, int], tuple[VertexAttribute, ...]] = {}
    scattering: dict[int, ScatteringMaterial] = {}
    scale_mm: dict[int, float] = {}
    sizes: dict[str, list] = {}
    atlases: dict[str, dict] = {}
    for mi, mesh in enumerate(scene.meshes):
        mesh_mm = mm_per_unit * _instance_scale(scene, mi, warnings)
        scale_mm[mi] = mesh_mm
        surface = clean.surfaces[mi]
        diag_mm = float(np.linalg.norm(np.ptp(surface.positions, axis=0))) * mesh_mm
        mats = sorted({p.material for p in mesh.primitives if material_of.get(p.material) is not None})
        sizes[mesh.name] = [_size_report(mesh.name, diag_mm, material_of[m], warnings) for m in mats]
        if not mats:
            continue
        mesh_key = stage_key(k_clean, "mesh", 0, {"mesh": mi})
        parts = [(p.positions, p.faces) for p in mesh.primitives]
        atlas, k_atlas = runner.run(
            "atlas", STAGE_VERSIONS["atlas"], mesh_key,
            {"resolution": options.atlas_resolution, "padding": options.atlas_padding},
            compute_atlas, parts, options.atlas_resolution, options.atlas_padding,
        )
        atlases[mesh.name] = {
            "width": atlas.width, "height": atlas.height, "charts": atlas.chart_count, "jittered": atlas.jittered,
            # The child's own peak (a cached atlas reports the run that made it): the parent's RSS misses it.
            "xatlas_peak_rss_mb": round(atlas.worker_peak_rss_mb, 1) if np.isfinite(atlas.worker_peak_rss_mb) else None,
        }
        cap = float(np.linalg.norm(np.ptp(surface.positions, axis=0)))
        thick, _ = runner.run(
            "thickness", STAGE_VERSIONS["thickness"], mesh_key, {"rays": options.thickness_rays},
            lambda: bake_thickness(surface.positions, surface.faces, surface.normals, cap=cap, rays=options.thickness_rays),
        )
        if not thick.hit.all():
            warnings.append(
                f"mesh {mesh.name!r}: {int((~thick.hit).sum())} of {len(thick.hit)} thickness rays left the "
                f"mesh (open surface); they were capped at the bounding-box diagonal ({cap * mesh_mm:.4g} mm)"
            )
        tmap, _ = runner.run(
            "thickness_map", STAGE_VERSIONS["thickness_map"], mesh_key,
            {"resolution": options.atlas_resolution, "padding": options.atlas_padding, "rays": options.thickness_rays},
            bake_thickness_map, atlas, [(p.positions, p.normals) for p in mesh.primitives], surface, cap,
            options.thickness_rays, options.atlas_padding,
        )
        if auto:
            from .plan import decide, with_pilot  # plan reads the bake's helpers: imported here, not at the top
            from .plan_pilot import run_pilot

            world = np.asarray((instances.get(mi) or [np.eye(4)])[0])  # the pilot sees the mesh as verify does

            def cached_pilot(found, surface, mm, material, *rest):  # `run_pilot` as a cached stage
                return runner.run("pilot", STAGE_VERSIONS["pilot"], mesh_key,
                                  {"material": material.to_json(), "mm": mm, "options": options.to_json(),
                                   "candidates": [c.__dict__ for c in found], "world": world.tolist()},
                                  run_pilot, found, surface, mm, material, *rest)[0]

            entries = []
            for m in mats:
                e = decide(str(path), mesh.name, scene.materials[m].name, material_of[m], mesh.deforming, options,
                           surface, thick.thickness, mesh_mm)
                entries.append(with_pilot(e, surface, mesh_mm, material_of[m], mesh.deforming, options, world,
                                          (picks or {}).get(e.key), cached_pilot))
            plan += entries
            techniques = {t for e in entries for t in e.techniques}
            mesh_options = options.merged({k: v for e in entries for k, v in e.params.items()})
            # screen is baked per material, after the meshes: each material keeps its entry's options
            screen_options.update({m: options.merged(e.params) for m, e in zip(mats, entries)})
        else:
            techniques, mesh_options = set(options.techniques), options
        used |= techniques
        prt = None
        if "prt" in techniques:
            _one_material("prt", mesh, mats, scene, warnings)
            compress = mesh_options.prt_compress()
            baked, _ = runner.run(
                "prt", STAGE_VERSIONS["prt"], mesh_key,
                {"material": material_of[mats[0]].to_json(), "mm": mesh_mm, "k": mesh_options.prt_directions,
                 "energy": mesh_options.prt_energy_dropped, "compress": compress.__dict__},
                bake_prt, surface, mesh_mm, material_of[mats[0]], mesh_options.prt_directions,
                mesh_options.prt_energy_dropped, compress,
            )
            prt = baked.prt
            total = baked.report["bytesPerVertex"]["total"]
            if compress.byte_budget is not None and total > compress.byte_budget:
                warnings.append(f"mesh {mesh.name!r}: prt takes {total:.1f} B/vertex, over its {compress.byte_budget:g} "
                                f"B/vertex budget: simplification stopped at {baked.report['referencePoints']} reference "
                                "points (edge collapses on thin slabs would flip faces)")
            mesh_extras.setdefault(mi, {})["prt"] = prt_tables(prt)
            prt_reports[mesh.name] = baked.report
        kernels = None
        if "kernels" in techniques:
            _one_material("kernels", mesh, mats, scene, warnings)
            if options.atlas_padding < (mesh_options.kernels_size + 1) // 2:
                warnings.append(f"mesh {mesh.name!r}: atlas_padding {options.atlas_padding} is below the "
                                f"{(mesh_options.kernels_size + 1) // 2} texels a {mesh_options.kernels_size}-texel kernel "
                                "reaches; kernels near chart edges see less of their neighbourhood")
            baked_k, _ = runner.run(
                "kernels", STAGE_VERSIONS["kernels"], k_atlas,
                {"material": material_of[mats[0]].to_json(), "mm": mesh_mm, "options": mesh_options.kernels().__dict__,
                 "bits": mesh_options.kernels_bits},
                bake_kernels, surface, atlas, [(p.positions, p.normals) for p in mesh.primitives], mesh_mm,
                material_of[mats[0]], mesh_options.kernels(), mesh_options.kernels_bits,
            )
            kernels = baked_k.kernels
            mesh_extras.setdefault(mi, {})["kernels"] = kernels_tables(kernels, mesh_options.kernels_bits)
            kernels_reports[mesh.name] = baked_k.report
        spectral = None
        if "spectral" in techniques:
            _one_material("spectral", mesh, mats, scene, warnings)
            # Keyed on the mesh, not the atlas: the normals live on the welded surface's vertices.
            spectral, _ = runner.run(
                "spectral", STAGE_VERSIONS["spectral"], mesh_key,
                {"material": material_of[mats[0]].to_json(), "mm": mesh_mm, "options": mesh_options.spectral().__dict__,
                 "basis": mesh_options.spectral_basis},
                bake_spectral, surface, mesh_mm, material_of[mats[0]], mesh_options.spectral(), mesh_options.spectral_basis,
            )
            if spectral.tables is not None:
                mesh_extras.setdefault(mi, {})["spectral"] = spectral.tables
            spectral_reports[mesh.name] = spectral.report
        if "lpv" in techniques:
            _one_material("lpv", mesh, mats, scene, warnings)
            # Keyed on the mesh: the grid depends on the welded surface, not on the atlas.
            baked_l, _ = runner.run(
                "lpv", STAGE_VERSIONS["lpv"], mesh_key,
                {"material": material_of[mats[0]].to_json(), "mm": mesh_mm, "grid": mesh_options.lpv_grid().__dict__,
                 "field": mesh_options.lpv_field, "marble": mesh_options.lpv_marble().__dict__,
                 "steps": mesh_options.lpv_max_steps},
                bake_lpv, surface, mesh_mm, material_of[mats[0]], mesh_options.lpv_grid(), mesh_options.lpv_field,
                mesh_options.lpv_marble(), mesh_options.lpv_max_steps,
            )
            mesh_extras.setdefault(mi, {})["lpv"] = baked_l.tables
            lpv_reports[mesh.name] = baked_l.report
            coarse = max(baked_l.report["decayPerCell"])
            if coarse > LPV_COARSE:
                # light then barely leaves its cell: the calibrated radiance amplifies the error
                need = int(np.ceil(mesh_options.lpv_resolution * coarse / LPV_COARSE))
                warnings.append(f"mesh {mesh.name!r}: lpv cells of {baked_l.report['cellMm']:.3g} mm are wider than "
                                f"the material's diffusion length (sigma_tr * cell = {coarse:.2g}); pass "
                                f"--lpv-resolution {need} or more")
        tmax = max(float(tmap.image.max()), float(thick.thickness.max()), 1e-30)
        images.append(Image(f"{mesh.name}_thickness", "image/png", _png_gray(tmap.image / tmax)))
        textures.append(Texture(len(images) - 1, LINEAR, LINEAR_MIPMAP_LINEAR, CLAMP_TO_EDGE, CLAMP_TO_EDGE))
        uv_set = max(len(p.uvs) for p in mesh.primitives)
        prims = []
        for pi, (p, part) in enumerate(zip(mesh.primitives, atlas.parts)):
            vm = part.vmapping
            uvs = tuple(uv[vm] for uv in p.uvs)
            uvs = uvs + (np.zeros((len(vm), 2)),) * (uv_set - len(uvs)) + (part.uvs,)
            prims.append(replace(
                p, positions=p.positions[vm], faces=part.faces, normals=p.normals[vm], uvs=uvs,
                tangents=p.tangents[vm] if p.tangents is not None else None,
                colors=p.colors[vm] if p.colors is not None else None,
            ))
            if material_of.get(p.material) is not None:
                t_mm = thick.thickness[surface.weld[pi]][vm] * mesh_mm
                attributes[(mi, pi)] = (
                    VertexAttribute("thickness", t_mm, "mm", "float32",
                                    "distance through the object along the inward normal"),
                )
                if prt is not None:
                    attributes[(mi, pi)] += prt_vertex_attributes(prt, surface.weld[pi][vm])
                if kernels is not None:
                    attributes[(mi, pi)] += kernels_vertex_attributes(kernels, surface.weld[pi][vm])
                if spectral is not None:
                    attributes[(mi, pi)] += spectral_vertex_attributes(spectral.normals, surface.weld[pi][vm],
                                                                       spectral.tables is not None)
        meshes[mi] = Mesh(mesh.name, tuple(prims))
        ref = TextureRef(len(textures) - 1, uv_set)
        for m in mats:
            fb = make_fallback(material_of[m], mesh_mm, thick.thickness * mesh_mm, ref, tmax)
            src: SourceMaterial = scene.materials[m]
            scattering[m] = ScatteringMaterial(material_of[m], fb, src.name)

    material_extras: dict[int, dict] = {}
    screen_reports: dict[str, dict] = {}
    # auto: screen for the materials the plan gave it
    screened = ({m for m in scattering if any(e.material == scene.materials[m].name and "screen" in e.techniques
                                              for e in plan)} if auto else
                set(scattering) if "screen" in options.techniques else set())
    if screened:
        used.add("screen")
        for m, s in sorted((m, s) for m, s in scattering.items() if m in screened):
            own = screen_options.get(m, options)
            # Per material, no mesh data: keyed on the material and the options alone.
            baked_s, _ = runner.run("screen", STAGE_VERSIONS["screen"], "material",
                                    {"material": s.material.to_json(), "options": own.screen().__dict__},
                                    bake_screen, s.material, own.screen())
            material_extras[m] = {"screen": baked_s.tables}
            name = scene.materials[m].name
            screen_reports[name if name not in screen_reports else f"{name}#{m}"] = baked_s.report

    for t in ("prt", "kernels", "spectral", "screen", "lpv"):
        if t not in used:
            if t == "prt":
                runner.skip("simplify", "no technique that needs reference points ran")
            runner.skip(t, "the plan chose it for no object (--techniques auto)" if auto
                        else f"not requested (--techniques {t})")
    warnings.extend(f"stage cache: {rec.corrupt} damaged {rec.name} entr{'y' if rec.corrupt == 1 else 'ies'} "
                    "(checksum mismatch or refused contents) deleted and recomputed" for rec in runner.records.values() if rec.corrupt)
    baked_scene = replace(scene, meshes=tuple(meshes), images=tuple(images), textures=tuple(textures))
    extras = {
        "scaleMmPerUnit": mm_per_unit,
        "scaleSource": scale_source,
        "thickness": {"unit": "mm", "raysPerSample": options.thickness_rays, "missCap": "bounding-box diagonal"},
    }
    asset = BakedAsset(baked_scene, attributes, scattering, scale_mm, extras, mesh_extras, material_extras)
    written: list[Path] = []
    try:
        summaries = {}
        with runner.timed("export_gltf"):
            summaries["glb"] = write_glb(asset, outputs[0])
        written.append(outputs[0])
        with runner.timed("export_usd"):
            summaries["usdc"] = write_usdc(asset, outputs[1])
        written.append(outputs[1])
        if options.spectral_variant:
            with runner.timed("export_sss_normals"):
                summaries["sss_normals_glb"] = write_glb(normals_variant(asset), outputs[3])
            written.append(outputs[3])
        validation = _validate(runner, outputs, options, warnings, path, len(scene.images))
        report = {
            "asset": str(path),
            "job_key": key,
            "dependencies": dependencies,
            "schema_version": SCHEMA_VERSION,
            "sssbake": version("sssbake"),
            "outputs": [str(p) for p in outputs],
            "scale_mm_per_unit": mm_per_unit,
            "scale_source": scale_source,
            "vertices": sum(len(p.positions) for m in baked_scene.meshes for p in m.primitives),
            "faces": sum(len(p.faces) for m in baked_scene.meshes for p in m.primitives),
            "materials": {
                scene.materials[i].name: (
                    {"scattering": m.to_json() if m is not None else None, "reason": assignment.reasons.get(origin[i], "")}
                )
                for i, m in material_of.items()
                if i in {p.material for mesh in scene.meshes for p in mesh.primitives}
            },
            "sizes": sizes,
            "atlas": atlases,
            "prt": prt_reports,
            "kernels": kernels_reports,
            "spectral": spectral_reports,
            "screen": screen_reports,
            "lpv": lpv_reports,
            "plan": [e.to_json() for e in plan],
            "bytes": {fmt: {k: v for k, v in summary.items() if k != "path"} for fmt, summary in summaries.items()},
            "validation": validation,
            "stages": runner.to_json(),
            "seconds": round(time.perf_counter() - t_start, 4),
            "warnings": warnings,
        }
        with atomic_path(outputs[2]) as tmp:
            Path(tmp).write_text(json.dumps(report, indent=1, default=json_default))
    except BaseException:
        for p in written:
            p.unlink(missing_ok=True)
        raise
    return BakeResult(report, outputs)


def _validate(runner: StageRunner, outputs, options: BakeOptions, warnings: list[str], source: Path | None = None,
              copied_images: int = 0) -> dict:
    """Validate the outputs; a glTF/GLB `source` is validated too, in the same node process.

    An output message is ``"inherited": true`` when the source's report has its code, or when it is
    about the data of one of the first `copied_images` images (the source's, copied byte for byte:
    an OBJ's PNG is not validated as input). Per glTF output: ``errors``/``warnings`` count sssbake's
    own, ``inherited_errors``/``inherited_warnings`` the inherited ones, ``input`` the source's counts.
    """
    # glTF-Validator's codes about an image's bytes (not about the JSON that describes it)
    image_data_codes = {"IMAGE_DATA_INVALID", "IMAGE_FEATURES_UNSUPPORTED", "IMAGE_MIME_TYPE_INVALID",
                        "IMAGE_UNEXPECTED_EOS", "IMAGE_UNRECOGNIZED_FORMAT"}
    if not options.validate:
        runner.skip("validate", "turned off (--no-validate)")
        return {}
    from ..exporters.gltf_validator import ValidatorUnavailable, validate_many
    from ..exporters.usd_validator import validate_usd

    out = {}
    with runner.timed("validate"):
        # outputs[3], when written, is the normals variant; one validator run for the input and both files
        glbs = {"gltf": outputs[0], **({"gltf_sss_normals": outputs[3]} if len(outputs) > 3 else {})}
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
        except ValidatorUnavailable as e:
            warnings.append(f"glTF validation skipped: {e}")
        u = validate_usd(outputs[1])
        out["usd"] = {"errors": len(u.errors), "warnings": len(u.warnings), "messages": list(u.errors)}
    return out


def json_default(o):
    """JSON for the numpy values a report holds (`json.dumps`' default)."""
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, (np.floating, np.integer)):
        return o.item()
    raise TypeError(f"not JSON-serialisable: {type(o).__name__}")
