"""The `sssbake` command line: bake, inspect, verify, presets."""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path

import numpy as np

from .config import EMPTY_CONFIG, ConfigError, load_config
from .options import BAKE_DEFAULTS
from .kernels_layout import KERNEL_BITS
from .kernels_precompute import BLENDS, SEAMS
from .prt_compress import MODES, TABLES, WEIGHT_BITS, WEIGHTS


def _bake(args) -> int:
    from .batch import run_batch

    try:
        config = load_config(args.config) if args.config else EMPTY_CONFIG
    except ConfigError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    overrides = {}
    if args.material is not None:
        overrides["material"] = args.material
    if args.scale_mm is not None:
        overrides["scale_mm"] = args.scale_mm
    if args.atlas_resolution is not None:
        overrides["atlas_resolution"] = args.atlas_resolution
    if args.no_validate:
        overrides["validate"] = False
    for name in ("techniques", "prt_directions", "prt_energy_dropped", "prt_mode", "prt_reference_fraction",
                 "prt_sh_order", "prt_weights", "prt_tables", "prt_refine",
                 "prt_weight_bits", "prt_byte_budget", "prt_reference_floor", "prt_detail_order",
                 "kernels_size", "kernels_threshold", "kernels_blend", "kernels_seams", "kernels_bits",
                 "kernels_global_vertices", "spectral_eigenpairs", "spectral_width_mm", "spectral_alpha",
                 "spectral_radius_mm", "spectral_variant", "spectral_basis", "screen_samples", "screen_uniform",
                 "screen_table_error", "lpv_resolution", "lpv_padding", "lpv_supersample", "lpv_field",
                 "lpv_vein_mm", "lpv_max_steps", "max_bytes_per_vertex", "budget_rmse", "allow_roots",
                 "asset_timeout_s", "asset_memory_gib"):
        if getattr(args, name) is not None:
            overrides[name] = getattr(args, name)
    out = Path(args.out)
    cache = None if args.no_cache else (args.cache_dir or str(out / ".sssbake-cache"))
    if args.dask is not None and args.jobs != 1:
        print("error: give --jobs or --dask, not both (--dask local:N runs N local worker processes)", file=sys.stderr)
        return 2
    from .batch import OutputError
    from .batch_dask import ClusterError  # distributed itself is imported only with --dask

    try:
        summary = run_batch(
            [Path(p) for p in args.paths], out, config, overrides, jobs=args.jobs, cache_dir=cache,
            progress=not args.quiet, dask=args.dask,
        )
    except OutputError as e:
        # the assets' own failures first (a full disk fails them too), then why there is no summary
        for r in (e.summary or {}).get("assets", []):
            if r["status"] == "failed":
                print(f"error: {r['error']}", file=sys.stderr)
        print(f"error: {e}", file=sys.stderr)
        return 2
    except (OSError, ConfigError, ClusterError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    for r in summary["assets"]:
        if r["status"] == "failed":
            print(f"error: {r['error']}", file=sys.stderr)
        elif not args.quiet:
            print(f"{r['status']:>10}  {r['asset']}  ({r['seconds']:.2f} s, {r.get('warnings', 0)} warnings)")
    print(
        f"{summary['ok']} baked, {summary['failed']} failed in {summary['seconds']:.1f} s; "
        f"summary in {out / 'batch.json'}",
        file=sys.stderr if args.quiet else sys.stdout,
    )
    if args.report:
        from .html_report import write_report

        page = write_report(out, summary, budget_rmse=args.budget_rmse)
        print(f"report in {page}", file=sys.stderr if args.quiet else sys.stdout)
    return 1 if summary["failed"] else 0


def _plan(args) -> int:
    import tempfile

    from .batch import find_assets
    from .load import AssetError
    from .materials import MaterialError
    from .plan import plan_asset

    try:
        config = load_config(args.config) if args.config else EMPTY_CONFIG
        # plan writes nothing: the output folder only names where a bake would write
        jobs = find_assets([Path(p) for p in args.paths], Path(tempfile.gettempdir()) / "sssbake-plan")
    except (ConfigError, FileNotFoundError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    overrides = {k: v for k, v in (("material", args.material), ("scale_mm", args.scale_mm),
                                   ("budget_rmse", args.budget_rmse), ("max_bytes_per_vertex", args.max_bytes_per_vertex),
                                   ("allow_roots", args.allow_roots))
                 if v is not None}
    entries, failed = [], 0
    for job in jobs:
        try:
            entries += plan_asset(job.path, config.options_for(job.rel, overrides))
        except (OSError, ValueError, AssetError, MaterialError) as e:
            print(f"error: {job.path}: {str(e).splitlines()[0] if str(e) else type(e).__name__}", file=sys.stderr)
            failed += 1
    if args.json:
        print(json.dumps([e.to_json() for e in entries]))
    else:
        for e in entries:
            print(f"{e.asset}  {e.mesh} / {e.material}: {', '.join(e.techniques) or 'no SSS data'}  "
                  f"({'; '.join(e.reasons)})")
    return 1 if failed else 0


def _vector(text: str, flag: str) -> tuple[float, float, float]:
    try:
        values = tuple(float(v) for v in text.split(","))
    except ValueError:
        values = ()
    if len(values) != 3:
        raise ValueError(f"{flag} takes three comma-separated numbers, got {text!r}")
    return values


def _verify(args) -> int:
    from ..exporters.read_prt import PrtReadError
    from .verify import DEFAULT_LIGHT, verify_file

    if Path(args.file).suffix.lower() != ".glb":
        print(f"error: {args.file}: verify reads the .glb files sssbake bake writes", file=sys.stderr)
        return 2
    try:
        light = DEFAULT_LIGHT if args.light_dir is None else _vector(args.light_dir, "--light-dir")
        position = None if args.light_pos is None else _vector(args.light_pos, "--light-pos")
        result = verify_file(args.file, args.technique, light, args.size, args.out, args.frames, position,
                             args.reference, args.lpv_steps, args.stock_viewer)
    except (OSError, ValueError, PrtReadError) as e:
        print(f"error: {args.file}: {str(e).splitlines()[0] if str(e) else type(e).__name__}", file=sys.stderr)
        return 1
    if args.json:
        print(json.dumps(result))
    else:
        where = (f"point light at {np.round(result['light_pos'], 3).tolist()}" if result["light_pos"] is not None
                 else f"light {np.round(result['light_dir'], 3).tolist()}")
        print(f"{args.file} ({result['technique']}, {where}): "
              f"RMSE image {result['rmse_image']:.4g}, object {result['rmse_object']:.4g} "
              f"(plain Lambert, best-fit scaled: {result['rmse_object_lambert']:.4g}); "
              f"frame {result['frame_ms_sss']:.2f} ms vs plain {result['frame_ms_plain']:.2f} ms; "
              f"images in {result['pngs']['comparison']} (reference | {result['technique']} | Lambert"
              f"{' | naive' if 'rmse_object_naive' in result else ''})")
        if args.stock_viewer:
            variant = (f"spectral normals variant {result['rmse_object_stock_variant']:.4g}"
                       if result["stock_variant"] is not None else
                       f"no {Path(args.file).with_suffix('.sss_normals.glb').name} (bake with --techniques spectral "
                       "--spectral-variant)")
            print(f"stock viewer (pyrender, unscaled): RMSE object fallback {result['rmse_object_stock']:.4g} "
                  f"(best-fit scale to the reference {np.round(result['stock_scale'], 3).tolist()}), {variant}; "
                  f"{result['stock_seconds']:.2f} s; images in {result['pngs']['stock']}")
    return 0


def _tradeoff(args) -> int:
    from .load import AssetError
    from .materials import MaterialError, material_from_spec

    path = Path(args.input)
    try:
        material = material_from_spec(args.material, args.material)
        if args.scale_mm is None:
            from .load import load_scene

            declared = load_scene(str(path)).meters_per_unit
            if declared is None:
                raise ValueError("no scale: this format carries no unit; pass --scale-mm")
            scale = 1000.0 * declared
        else:
            scale = args.scale_mm
        out = args.out or path.parent
        if args.technique == "prt":
            from .tradeoff import prt_tradeoff

            result = prt_tradeoff(path, scale, material, out, k=args.k, lights=args.lights, size=args.size)
        elif args.technique == "spectral":
            from .spectral_tradeoff import spectral_tradeoff

            result = spectral_tradeoff(path, scale, material, out, lights=args.lights, size=args.size)
        elif args.technique == "lpv":
            from .lpv_tradeoff import lpv_tradeoff

            result = lpv_tradeoff(path, scale, material, out, resolutions=args.lpv_resolutions, steps=args.lpv_steps,
                                  field=args.lpv_field, lights=args.lights, size=args.size)
        elif args.technique == "screen":
            from .screen_tradeoff import screen_tradeoff

            result = screen_tradeoff(path, scale, material, out, samples=args.samples, uniform=args.uniform,
                                     lights=args.lights, size=args.size,
                                     reference_subdivisions=args.reference_subdivisions)
        else:
            from .kernels_tradeoff import kernels_tradeoff

            result = kernels_tradeoff(path, scale, material, out, resolutions=args.resolutions, sizes=args.sizes,
                                      thresholds=args.thresholds, lights=args.lights, size=args.size,
                                      resolution=args.atlas_resolution)
    except (OSError, ValueError, AssetError, MaterialError) as e:
        print(f"error: {path}: {str(e).splitlines()[0] if str(e) else type(e).__name__}", file=sys.stderr)
        return 1
    if args.json:
        print(json.dumps(result))
    else:
        for r in result["rows"]:
            if args.technique == "prt":
                knobs = (f"{r['mode']:>8} K={r['k']:<4} n={r['sh_order']} refs={r['reference_fraction']:<7g} "
                         f"{r['weights']:<13}")
            elif args.technique == "spectral":
                knobs = (f"{r['normals']:>8} m={r['eigenpairs']:<4} width x{r['width_factor']:<5g} "
                         f"alpha={r['alpha']:<4g}")
            elif args.technique == "lpv":
                knobs = (f"grid={r['resolution']:<3} {'x'.join(map(str, r['shape'])):<11} cell {r['cell_mm']:6.2f} mm "
                         f"steps={r['steps']:<3} {r['frame_ms']:9.2f} ms/frame")
            elif args.technique == "screen":
                knobs = (f"N={r['samples']:<4} U={r['uniform']:<3} jacobian={r['jacobian']!s:<5} fill={r['fill']!s:<5} "
                         f"interleave={r['interleave']:<2} {r['frame_ms']:8.2f} ms/frame")
            else:
                knobs = (f"atlas={r['atlas_resolution']:<5} k={r['kernel_size']:<2} threshold={r['threshold']:<6g} "
                         f"{r['blend']:<9} seams={r['seams']:<6}")
            # screen stores nothing per vertex: its tables are per material
            size = (f"{r['bytes']:7d} B/material" if args.technique == "screen" else
                    f"{r['bytes']:9d} B/mesh" if args.technique == "lpv" else f"{r['bytes_per_vertex']:9.1f} B/vertex")
            print(f"{r['sweep']:>16} {knobs} {size} {r['seconds']:7.2f} s  RMSE {r['rmse_image']:.5f}")
        print(f"frame {result['frame_ms_sss']:.2f} ms with {args.technique}, {result['frame_ms_plain']:.2f} ms without "
              f"(ratio {result['frame_ratio']:.2f}); {result['outputs']['plot']}")
    return 0


def _numbers(kind: type):
    """An argparse type: comma-separated values of `kind`, as a tuple."""
    def parse(text: str) -> tuple:
        return tuple(kind(v) for v in text.split(","))

    parse.__name__ = f"comma-separated {kind.__name__}"  # argparse names the type in its error
    return parse


def _inspect(args) -> int:
    path = Path(args.file)
    suffix = path.suffix.lower()
    try:
        if suffix in (".glb", ".gltf"):
            from ..exporters.inspect_gltf import inspect_glb

            info = inspect_glb(path)
        elif suffix in (".usdc", ".usda", ".usd"):
            from ..exporters.inspect_usd import inspect_usdc

            info = inspect_usdc(path)
        else:
            print(f"error: {path}: inspect reads .glb/.gltf/.usd/.usda/.usdc files", file=sys.stderr)
            return 2
    except Exception as e:  # any unreadable file is one line, not a traceback
        print(f"error: {path}: cannot inspect: {str(e).splitlines()[0] if str(e) else type(e).__name__}", file=sys.stderr)
        return 1
    print(json.dumps(info, indent=1, default=str))
    return 0


def _presets(_args) -> int:
    from .dipole import DipoleParams, total_diffuse_reflectance
    from .materials import preset, preset_names

    print(f"{'preset':<11} {'eta':>4}  {'R_d (RGB)':<20} {'mfp mm (RGB)':<22} diffusion length mm (RGB)")
    for name in preset_names():
        m = preset(name)
        p = DipoleParams.from_material(m)
        rd = total_diffuse_reflectance(p.alpha_prime, p.eta)
        fmt = lambda v: " ".join(f"{x:6.3g}" for x in v)  # noqa: E731
        print(f"{name:<11} {m.eta:4.2f}  {fmt(rd):<20} {fmt(m.mean_free_path_mm):<22} {fmt(m.diffusion_length_mm)}")
    return 0


def _whole_number_at_least_1(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        value = 0
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be a whole number >= 1, got {text!r}")
    return value


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="sssbake", description=__doc__)
    sub = parser.add_subparsers(dest="command", required=True)

    b = sub.add_parser("bake", help="bake assets (files or folders, walked recursively) into glTF + USD")
    b.add_argument("paths", nargs="+", help="asset files or folders")
    b.add_argument("-o", "--out", required=True, help="output folder (mirrors the input tree)")
    b.add_argument("--material", help=f"preset name or 'opaque' for unmatched materials (default {BAKE_DEFAULTS.material})")
    b.add_argument("--config", help="TOML batch config (defaults, per-file rules, material rules)")
    b.add_argument("--scale-mm", type=float, help="millimetres per file unit (required for OBJ/PLY/STL)")
    b.add_argument("--atlas-resolution", type=int, help=f"atlas texels per side (default {BAKE_DEFAULTS.atlas_resolution})")
    b.add_argument("--techniques",
                   help="comma-separated techniques to bake besides the fallback: prt, kernels, spectral, screen, "
                        "lpv; auto: the planner chooses per mesh and material, with a reason in the report; none: "
                        f"the fallback only (default {','.join(BAKE_DEFAULTS.techniques) or 'none'})")
    b.add_argument("--prt-directions", type=int, help=f"prt: light directions K (default {BAKE_DEFAULTS.prt_directions})")
    b.add_argument("--prt-energy-dropped", type=float,
                   help=f"prt: fraction of R_d the gather radius may drop (default {BAKE_DEFAULTS.prt_energy_dropped})")
    b.add_argument("--prt-mode", choices=MODES, help=f"prt compression (default {BAKE_DEFAULTS.prt_mode})")
    b.add_argument("--prt-reference-fraction", type=float,
                   help=f"prt: reference points per vertex (default {BAKE_DEFAULTS.prt_reference_fraction})")
    b.add_argument("--prt-sh-order", type=int, help=f"prt: SH order of Δq (default {BAKE_DEFAULTS.prt_sh_order})")
    b.add_argument("--prt-weights", choices=WEIGHTS,
                   help=f"prt: reference weights (default {BAKE_DEFAULTS.prt_weights})")
    b.add_argument("--prt-tables", choices=TABLES,
                   help=f"prt: reference tables, one per channel or one shared by the channels "
                        f"(default {BAKE_DEFAULTS.prt_tables})")
    b.add_argument("--prt-refine", type=float,
                   help=f"prt: share of the reference points placed where the fit is worst "
                        f"(default {BAKE_DEFAULTS.prt_refine})")
    b.add_argument("--prt-weight-bits", type=int, choices=WEIGHT_BITS,
                   help=f"prt: bits per weight code; 8 packs them with the triangle in 4 bytes (default "
                        f"{BAKE_DEFAULTS.prt_weight_bits})")
    b.add_argument("--prt-reference-floor", type=int,
                   help=f"prt: at least this many reference points (all vertices of smaller meshes; default "
                        f"{BAKE_DEFAULTS.prt_reference_floor})")
    b.add_argument("--prt-detail-order", type=int,
                   help=f"prt: SH order of each reference point's detail term with shared tables, 0 for none "
                        f"(default {BAKE_DEFAULTS.prt_detail_order})")
    b.add_argument("--prt-byte-budget", type=float,
                   help="prt: bytes per vertex to spend; sets the reference count (default: from the fraction)")
    b.add_argument("--kernels-size", type=int,
                   help=f"kernels: k of the k x k local kernels (odd; default {BAKE_DEFAULTS.kernels_size})")
    b.add_argument("--kernels-threshold", type=float,
                   help=f"kernels: drop throughput entries below this (default {BAKE_DEFAULTS.kernels_threshold})")
    b.add_argument("--kernels-blend", choices=BLENDS,
                   help=f"kernels: how local and global responses are blended (default {BAKE_DEFAULTS.kernels_blend})")
    b.add_argument("--kernels-seams", choices=SEAMS,
                   help=f"kernels: unfold the surface across chart seams into the gutter, or not (default "
                        f"{BAKE_DEFAULTS.kernels_seams})")
    b.add_argument("--kernels-global-vertices", type=int,
                   help=f"kernels: surfaces with more vertices get their global response on a copy simplified to "
                        f"about this many, 0 for never (default {BAKE_DEFAULTS.kernels_global_vertices})")
    b.add_argument("--kernels-bits", type=int, choices=KERNEL_BITS,
                   help=f"kernels: bits per stored kernel weight (default {BAKE_DEFAULTS.kernels_bits})")
    b.add_argument("--spectral-eigenpairs", type=int,
                   help=f"spectral: harmonics the normals are filtered in (default "
                        f"{BAKE_DEFAULTS.spectral_eigenpairs})")
    b.add_argument("--spectral-width-mm", type=float,
                   help="spectral: the filter's spatial standard deviation (default: from the material)")
    b.add_argument("--spectral-alpha", type=float,
                   help=f"spectral: naive normals' weight of a vertex's own normal (default "
                        f"{BAKE_DEFAULTS.spectral_alpha})")
    b.add_argument("--spectral-radius-mm", type=float,
                   help="spectral: naive normals' neighbourhood radius (default: from the material)")
    # store_true with default None: an absent flag leaves the config's value alone
    b.add_argument("--spectral-variant", action="store_true", default=None,
                   help="spectral: also write STEM.sss_normals.glb, its NORMAL the spectral normal (for stock viewers)")
    b.add_argument("--spectral-basis", action="store_true", default=None,
                   help="spectral: also export the spectrum (coefficients, eigenvalues, residual, basis) to filter "
                        "again at runtime")
    for name, kind, what in (("samples", int, "importance-sampled offsets per material"),
                             ("uniform", int, "uniform offsets per material, 0 for none"),
                             ("table_error", float, "bound on the Rd table's relative interpolation error")):
        b.add_argument("--screen-" + name.replace("_", "-"), type=kind,
                       help=f"screen: {what} (default {getattr(BAKE_DEFAULTS, 'screen_' + name):g})")
    for name, kind, what in (("resolution", int, "grid cells along the object's longest side"),
                             ("padding", int, "empty cells around the object"),
                             ("supersample", int, "occupancy samples per cell side"),
                             ("vein_mm", float, "marble field: spacing of the veins, mm"),
                             ("max_steps", int, "propagation steps the rendering's scale is tabulated for")):
        b.add_argument("--lpv-" + name.replace("_", "-"), type=kind,
                       help=f"lpv: {what} (default {getattr(BAKE_DEFAULTS, 'lpv_' + name):g})")
    b.add_argument("--lpv-field", choices=["homogeneous", "marble"],
                   help=f"lpv: the medium, the material everywhere or marble veins through it "
                        f"(default {BAKE_DEFAULTS.lpv_field})")
    b.add_argument("--report", action="store_true",
                   help="also write OUT/report.html: each technique verified against the reference, with pictures")
    _budget_arguments(b)
    _allow_root_argument(b)
    b.add_argument("--jobs", type=_whole_number_at_least_1, default=1, help="assets baked in parallel (default 1)")
    b.add_argument("--asset-timeout", dest="asset_timeout_s", type=float, metavar="SECONDS",
                   help=f"wall time one asset's worker may take before it is killed and the asset fails, 0 for no "
                        f"limit (default {BAKE_DEFAULTS.asset_timeout_s:g})")
    b.add_argument("--asset-memory", dest="asset_memory_gib", type=float, metavar="GIB",
                   help=f"resident memory one asset's worker and its children may hold before they are killed and "
                        f"the asset fails, 0 for no limit (default {BAKE_DEFAULTS.asset_memory_gib:g})")
    b.add_argument("--dask", metavar="SCHEDULER",
                   help="bake each asset as a task on a Dask cluster: its scheduler's address (tcp://host:8786; "
                        "inputs, OUT and the cache folder must be shared with the workers), or local:N for N "
                        "worker processes here")
    b.add_argument("--cache-dir", help="stage cache folder (default OUT/.sssbake-cache)")
    b.add_argument("--no-cache", action="store_true", help="recompute every stage")
    b.add_argument("--no-validate", action="store_true", help="skip the glTF and USD validators")
    b.add_argument("-q", "--quiet", action="store_true", help="no progress bar, only errors")
    b.set_defaults(func=_bake)

    i = sub.add_parser("inspect", help="show the sssbake data a .glb or .usdc holds, with bytes per vertex")
    i.add_argument("file")
    i.set_defaults(func=_inspect)

    v = sub.add_parser("verify", help="render an export with the shipped GLSL and the offline reference; image RMSE")
    v.add_argument("file", help="a .glb written by sssbake bake")
    v.add_argument("--technique", default="prt", choices=["prt", "kernels", "spectral", "screen", "lpv"])
    v.add_argument("--lpv-steps", type=int, default=16, help="lpv: propagation steps per frame (default 16)")
    v.add_argument("--light-dir", help="x,y,z world direction towards a directional light (default 0.4,0.8,0.45)")
    v.add_argument("--light-pos", help="x,y,z world position of a point light instead (unit irradiance at the "
                                       "objects' centre)")
    v.add_argument("--reference", default="exact", choices=["exact", "clustered"],
                   help="offline reference: every vertex pair (default), or far sources through float64 "
                        "clusters (~1e-3 of q; for 100k+ vertices)")
    v.add_argument("--size", type=int, default=512, help="image width and height (default 512)")
    v.add_argument("--out", help="folder for the PNGs (default: next to the file)")
    v.add_argument("--frames", type=int, default=20, help="frames timed per shader (default 20)")
    v.add_argument("--stock-viewer", action="store_true",
                   help="also render the fallback material, and STEM.sss_normals.glb if the bake wrote it, as a stock "
                        "glTF viewer does (pyrender), and give their RMSE against the same reference")
    v.add_argument("--json", action="store_true", help="print one JSON object")
    v.set_defaults(func=_verify)

    # the kernels and screen tradeoffs' defaults, for the help; the sweeps run only on `tradeoff`
    from .kernels_tradeoff import DEFAULT_RESOLUTION, RESOLUTIONS, SIZES, THRESHOLDS
    from .lpv_tradeoff import RESOLUTIONS as LPV_RESOLUTIONS, STEPS as LPV_STEPS
    from .screen_tradeoff import SAMPLES, UNIFORM

    t = sub.add_parser("tradeoff", help="sweep a technique's knobs: image RMSE vs bytes per vertex and seconds")
    t.add_argument("input", help="a mesh file (the largest mesh is used)")
    t.add_argument("--technique", default="prt", choices=["prt", "kernels", "spectral", "screen", "lpv"])
    t.add_argument("--material", default=BAKE_DEFAULTS.material, help="preset name (default marble)")
    t.add_argument("--scale-mm", type=float, help="millimetres per file unit (required for OBJ/PLY/STL)")
    t.add_argument("--k", type=int, default=BAKE_DEFAULTS.prt_directions,
                   help="prt: directions for the compression sweeps")
    t.add_argument("--atlas-resolution", type=int, default=DEFAULT_RESOLUTION,
                   help=f"kernels: atlas resolution of the default configuration (default {DEFAULT_RESOLUTION})")
    for flag, kind, default, what in (("--resolutions", int, RESOLUTIONS, "kernels: atlas resolutions swept"),
                                      ("--sizes", int, SIZES, "kernels: kernel sizes swept"),
                                      ("--thresholds", float, THRESHOLDS, "kernels: F thresholds swept"),
                                      ("--samples", int, SAMPLES, "screen: importance samples N swept"),
                                      ("--uniform", int, UNIFORM, "screen: uniform samples U swept"),
                                      ("--lpv-resolutions", int, LPV_RESOLUTIONS, "lpv: grid resolutions swept"),
                                      ("--lpv-steps", int, LPV_STEPS, "lpv: propagation steps swept")):
        t.add_argument(flag, type=_numbers(kind), default=default,
                       help=f"{what} (default {','.join(map(str, default))})")
    t.add_argument("--lpv-field", choices=["homogeneous", "marble"], default="homogeneous",
                   help="lpv: the medium; marble veins are compared with the finest configuration")
    t.add_argument("--reference-subdivisions", type=int, default=0,
                   help="screen: midpoint subdivisions of the surface the per-vertex reference is computed on "
                        "(the technique shades per pixel; default 0)")
    t.add_argument("--lights", type=int, default=3, help="random test lights; the worst RMSE counts (default 3)")
    t.add_argument("--size", type=int, default=256, help="image size (default 256)")
    t.add_argument("--out", help="folder for the JSON, CSV and plot (default: next to the input)")
    t.add_argument("--json", action="store_true", help="print one JSON object")
    t.set_defaults(func=_tradeoff)

    pl = sub.add_parser("plan", help="which technique each object and material needs, with reasons (bakes nothing)")
    pl.add_argument("paths", nargs="+", help="files or folders, as for bake")
    pl.add_argument("--config", help="TOML batch config (defaults, per-file rules, material rules)")
    pl.add_argument("--material", help="preset name or 'opaque' for unmatched materials")
    pl.add_argument("--scale-mm", type=float, help="millimetres per file unit (required for OBJ/PLY/STL)")
    pl.add_argument("--json", action="store_true", help="print a JSON list: asset, mesh, material, techniques, "
                                                        "params, reasons, measures (and pilot)")
    _budget_arguments(pl)
    _allow_root_argument(pl)
    pl.set_defaults(func=_plan)

    p = sub.add_parser("presets", help="list the measured material presets (Jensen et al. 2001)")
    p.set_defaults(func=_presets)
    return parser


def _budget_arguments(parser) -> None:
    parser.add_argument("--budget-rmse", type=float,
                        help="the image RMSE (verify's, on the full asset) each technique should stay under: the bake "
                             "checks it, and with --techniques auto a pilot on a subsample chooses the parameters")
    parser.add_argument("--max-bytes-per-vertex", type=float,
                        help="with --techniques auto: the most bytes per vertex the planner may spend")


def _allow_root_argument(parser) -> None:
    parser.add_argument("--allow-root", dest="allow_roots", metavar="FOLDER", action="append", type=_folder,
                        help="a folder besides each asset's own that the files it references (glTF buffers and "
                             "images, USD layers and textures, OBJ materials) may lie in; repeat for more")


def _folder(text: str) -> str:
    if not os.path.isdir(text):
        raise argparse.ArgumentTypeError(f"{text!r} is not a folder")
    return os.path.abspath(text)


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    return args.func(args)


if __name__ == "__main__":
    sys.exit(main())
