"""The `sssbake` command line: bake, inspect, verify, presets."""

from __future__ import annotations

import argparse
import json
import os
import signal
import sys
from dataclasses import fields
from pathlib import Path

from sssbake.pipeline.core.errors import AssetError, SssbakeError, TradeoffError, VerifyError

# The pipeline's modules are imported where a command needs them, not here: the options import every
# registered technique (~1 s), and `main` starts a bake's fork server before that (`_early_fork_server`).

#: argparse types of the option fields' declared kinds.
_FLAG_TYPES = {"int": int, "float": float, "str": str}


def _overrides(args) -> dict:
    """The options the command's flags set: those of `BakeOptions`' fields given (not None)."""
    from sssbake.pipeline.options import BakeOptions

    overrides = {f.name: getattr(args, f.name) for f in fields(BakeOptions) if getattr(args, f.name, None) is not None}
    if getattr(args, "no_validate", False):
        overrides["validate"] = False
    return overrides


def _one_line(text: str) -> str:
    """`text` printable on one line: a character that is not printable (a newline, a control
    character) as Python writes it in a string (``\\n``), a byte of a file name that is not UTF-8
    (os.fsdecode's surrogate escape) as ``\\xNN``: a POSIX file name may hold any of them."""
    if text.isprintable():
        return text
    return "".join(c if c.isprintable() else f"\\x{ord(c) - 0xDC00:02x}" if "\udc80" <= c <= "\udcff"
                   else repr(c)[1:-1] for c in text)


def _bake(args) -> int:
    from sssbake.pipeline.bake.asset_process import Interrupted, stop_on_signals
    from sssbake.pipeline.bake.batch import OutputError, run_batch
    from sssbake.pipeline.config import EMPTY_CONFIG, load_config
    from sssbake.pipeline.planning.plan import lambert_line

    config = load_config(args.config) if args.config else EMPTY_CONFIG
    # a flag, or a rule with the flags, that no asset could bake with refuses the batch: nothing is written
    config.check(_overrides(args), args.flags)
    out = Path(args.out)
    cache = None if args.no_cache else (args.cache_dir or str(out / ".sssbake-cache"))
    if args.dask is not None and args.jobs != 1:
        print("error: give --jobs or --dask, not both (--dask local:N runs N local worker processes)", file=sys.stderr)
        return 2
    try:
        with stop_on_signals():  # Ctrl-C, kill, a closed terminal: one line, not a traceback
            summary = run_batch(
                [Path(p) for p in args.paths], out, config, _overrides(args), jobs=args.jobs, cache_dir=cache,
                progress=not args.quiet, dask=args.dask,
            )
    except Interrupted as e:
        for r in e.records or []:
            if r is not None and r["status"] == "failed":
                print(f"error: {_one_line(r['error'])}", file=sys.stderr)
        print(f"error: {_one_line(str(e))}", file=sys.stderr)
        return 128 + e.signum  # the shell's code for a command ended by that signal
    except OutputError as e:
        # the assets' own failures first (a full disk fails them too), then `main` says why there is no summary
        for r in (e.summary or {}).get("assets", []):
            if r["status"] == "failed":
                print(f"error: {_one_line(r['error'])}", file=sys.stderr)
        raise
    except OSError as e:  # an input path that cannot be read
        print(f"error: {_one_line(str(e))}", file=sys.stderr)
        return 2
    for r in summary["assets"]:
        if r["status"] == "failed":
            print(f"error: {_one_line(r['error'])}", file=sys.stderr)
        elif r["status"] == "same-file" and not args.quiet:
            print(f"{r['status']:>10}  {_one_line(r['asset'])}  (another name of {_one_line(r['same_as'])}, "
                  "baked once under that name)")
        elif not args.quiet:
            print(f"{r['status']:>10}  {_one_line(r['asset'])}  ({r['seconds']:.2f} s, "
                  f"{r.get('warnings', 0)} warnings)")
    print(
        f"{summary['ok']} baked, {summary['failed']} failed in {summary['seconds']:.1f} s; "
        f"summary in {_one_line(str(out / 'batch.json'))}",
        file=sys.stderr if args.quiet else sys.stdout,
    )
    unvalidated = [r for r in summary["assets"] if r.get("validation_skipped")]
    if unvalidated:  # one line for the batch: the reason (and its fix) is the same for every asset
        print(_one_line(f"warning: glTF validation skipped for {len(unvalidated)} of {len(summary['assets'])} "
                        f"asset(s), first {unvalidated[0]['asset']}: {unvalidated[0]['validation_skipped']}"),
              file=sys.stderr)
    worse = lambert_line(summary["worse_than_lambert"], "on the pilot's subsample")
    if worse:
        print(_one_line(worse), file=sys.stderr if args.quiet else sys.stdout)
    if args.report:
        from sssbake.pipeline.verify.html_report import write_report

        page = write_report(out, summary, budget_rmse=args.budget_rmse)
        print(f"report in {_one_line(str(page))}", file=sys.stderr if args.quiet else sys.stdout)
    return 1 if summary["failed"] else 0


def _plan(args) -> int:
    import tempfile

    from sssbake.pipeline.bake.batch import find_assets
    from sssbake.pipeline.config import EMPTY_CONFIG, load_config
    from sssbake.pipeline.planning.plan import plan_asset

    config = load_config(args.config) if args.config else EMPTY_CONFIG
    try:
        # plan writes nothing: the output folder only names where a bake would write
        jobs = find_assets([Path(p) for p in args.paths], Path(tempfile.gettempdir()) / "sssbake-plan")
    except FileNotFoundError as e:
        print(f"error: {_one_line(str(e))}", file=sys.stderr)
        return 2
    overrides = _overrides(args)
    entries, failed = [], 0
    for job in jobs:
        if job.problem is not None:  # found unbakeable (a FIFO, a dangling symlink): never opened
            print(f"error: {_one_line(job.problem)}", file=sys.stderr)
            failed += 1
            continue
        if job.same_as is not None:
            print(f"note: {_one_line(str(job.path))}: another name of {_one_line(str(job.same_as))}, planned once "
                  "under that name", file=sys.stderr)
            continue
        try:
            entries += plan_asset(job.path, config.options_for(job.rel, overrides))
        except (OSError, ValueError, SssbakeError) as e:
            # without the path an AssetError starts with: it is named once, and may hold a line break
            message = str(e).removeprefix(f"{job.path}: ")
            print(f"error: {_one_line(f'{job.path}: {message.splitlines()[0] if message else type(e).__name__}')}",
                  file=sys.stderr)
            failed += 1
    if args.json:
        print(json.dumps([e.to_json() for e in entries]))
    else:
        for e in entries:
            print(_one_line(f"{e.asset}  {e.mesh} / {e.material}: {', '.join(e.techniques) or 'no SSS data'}  "
                            f"({'; '.join(e.reasons)})"))
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
    from sssbake.pipeline.verify.verify import DEFAULT_LIGHT, held_techniques, verify_file

    if Path(args.file).suffix.lower() != ".glb":
        print(f"error: {args.file}: verify reads the .glb files sssbake bake writes", file=sys.stderr)
        return 2
    if args.reference == "volpath":  # Mitsuba's absence, with how to install it, before anything is read
        from sssbake.pipeline.verify.volpath import load_mitsuba

        load_mitsuba()
    failed, references = False, {}  # the dipole references, shared by the file's techniques
    try:
        techniques = [args.technique] if args.technique else held_techniques(args.file)
    except (OSError, ValueError, AssetError) as e:
        techniques, failed = [], _verify_error(args.file, e)
    for technique in techniques:
        try:
            light = DEFAULT_LIGHT if args.light_dir is None else _vector(args.light_dir, "--light-dir")
            position = None if args.light_pos is None else _vector(args.light_pos, "--light-pos")
            if args.reference == "volpath":
                from sssbake.pipeline.verify.volpath import VOLPATH_SIZE, verify_volpath

                if position is not None:
                    raise VerifyError("--reference volpath lights the truth with a lobe around --light-dir, not a "
                                      "point light")
                result = verify_volpath(args.file, technique, light, args.size or VOLPATH_SIZE, args.spp, args.out,
                                        args.cache_dir, args.lpv_steps)
            else:
                result = verify_file(args.file, technique, light, args.size or 512, args.out, args.frames, position,
                                     args.reference, args.lpv_steps, args.stock_viewer, references=references)
        except (OSError, ValueError, AssetError) as e:  # the readers' and verify's, most naming the file
            failed = _verify_error(args.file, e)
            continue
        _verify_lines(args, result)
    return 1 if failed else 0


def _verify_error(file: str, e: Exception) -> bool:
    """Print `e` as one line naming `file` once (the readers and verify name it in most messages, as
    they were given it or as a `Path` wrote it); True."""
    message = str(e).splitlines()[0] if str(e) else type(e).__name__
    named = file in message or str(Path(file)) in message
    print(f"error: {_one_line(message if named else f'{file}: {message}')}", file=sys.stderr)
    return True


def _verify_lines(args, result: dict) -> None:
    """One technique's `verify_file` (or `verify_volpath`) result: one JSON object a line with
    ``--json``, else lines of text."""
    import numpy as np

    if args.json:
        print(json.dumps(result))
    elif args.reference == "volpath":
        print(_volpath_line(args.file, result))
    else:
        where = (f"point light at {np.round(result['light_pos'], 3).tolist()}" if result["light_pos"] is not None
                 else f"light {np.round(result['light_dir'], 3).tolist()}")
        print(f"{args.file} ({result['technique']}, {where}): "
              f"RMSE image {result['rmse_image']:.4g}, object {result['rmse_object']:.4g} "
              f"(plain Lambert, best-fit scaled: {result['rmse_object_lambert']:.4g}); "
              f"frame {result['frame_ms_sss']:.2f} ms vs plain {result['frame_ms_plain']:.2f} ms; "
              f"images in {result['pngs']['comparison']} (reference | {result['technique']} | Lambert"
              f"{' | naive' if 'rmse_object_naive' in result else ''})")
        if "reference_check" in result:
            check = result["reference_check"]
            print(f"reference check: the RMSE figures are within {check['rms']:.2g} of the exact reference's (95 % CI "
                  f"{check['rms_ci95'][0]:.2g}-{check['rms_ci95'][1]:.2g}; exact sums at {check['vertices']} of "
                  f"{check['of']} vertices, energy scales of {check['sources']} sources)")
        if args.stock_viewer:
            variant = (f"spectral normals variant {result['rmse_object_stock_variant']:.4g}"
                       if result["stock_variant"] is not None else
                       f"no {Path(args.file).with_suffix('.sss_normals.glb').name} (bake with --techniques spectral "
                       "--spectral-variant)")
            print(f"stock viewer (pyrender, unscaled): RMSE object fallback {result['rmse_object_stock']:.4g} "
                  f"(best-fit scale to the reference {np.round(result['stock_scale'], 3).tolist()}), {variant}; "
                  f"{result['stock_seconds']:.2f} s; images in {result['pngs']['stock']}")


def _volpath_line(file: str, r: dict) -> str:
    """`verify_volpath`'s result as one line of text; each relative RMSE with, in brackets, what is
    left of it beyond the truth's noise floor."""
    import numpy as np

    def error(key: str) -> str:
        return f"{r[key]:.3g} ({r['rmse_relative_denoised'][key]:.3g})"

    truth = "from the cache" if r["truth_cached"] else f"rendered in {r['truth_seconds']:.0f} s"
    labels = {"rmse_relative": r["technique"], "rmse_relative_lambert_fitted": "best-fit Lambert",
              "rmse_relative_fallback": "fallback"}
    readings = "; ".join(
        f"per {'8x8 block' if name == 'block' else 'visible vertex'} (noise floor {m['noise_floor']:.3g}, "
        f"beyond it): " + ", ".join(f"{label} {m['rmse_relative_denoised'][key]:.3g}" for key, label in labels.items()
                                    if key in m["rmse_relative_denoised"])
        for name, m in r["measures"].items())
    return (f"{file} ({r['technique']} vs Mitsuba {r['mitsuba']} volpath, cos^{r['lobe_exponent']} lobe around "
            f"{np.round(r['light_dir'], 3).tolist()}, {r['spp']} spp, noise floor {r['noise_floor']:.3g}): relative "
            f"RMSE (beyond the noise) {error('rmse_relative')}, best-fit scaled {error('rmse_relative_fitted')} "
            f"(truth = {np.round(r['technique_scale'], 3).tolist()} x {r['technique']}); plain Lambert of the "
            f"profile's total reflectance {error('rmse_relative_lambert')}, best-fit Lambert "
            f"{error('rmse_relative_lambert_fitted')}; mirror reflection subtracted from the truth "
            f"({r['specular_share']:.1%} of its light); {readings}; truth {truth}; images in "
            f"{r['pngs']['comparison']} (volpath | {r['technique']} | Lambert | best-fit Lambert)")


def _tradeoff(args) -> int:
    from sssbake.pipeline.core.materials import material_from_spec
    from sssbake.pipeline.core.ranges import SCALE_MM
    from sssbake.pipeline.techniques import registry

    path = Path(args.input)
    technique = registry.technique(args.technique)
    try:
        material = material_from_spec(args.material, args.material, args.profile)
        if args.scale_mm is None:
            from sssbake.pipeline.mesh.load import load_scene

            declared = load_scene(str(path)).meters_per_unit
            if declared is None:
                raise TradeoffError("no scale: this format carries no unit; pass --scale-mm")
            scale = 1000.0 * declared
        else:
            scale = args.scale_mm
            SCALE_MM.check("--scale-mm", scale)
        result = technique.run_tradeoff(path, scale, material, args.out or path.parent, args)
    except (OSError, ValueError, SssbakeError) as e:
        print(f"error: {path}: {str(e).splitlines()[0] if str(e) else type(e).__name__}", file=sys.stderr)
        return 1
    if args.json:
        print(json.dumps(result))
    else:
        for r in result["rows"]:
            print(f"{r['sweep']:>16} {technique.tradeoff_row(r)} {r['seconds']:7.2f} s  RMSE {r['rmse_image']:.5f}")
        print(f"frame {result['frame_ms_sss']:.2f} ms with {args.technique}, {result['frame_ms_plain']:.2f} ms without "
              f"(ratio {result['frame_ratio']:.2f}); {result['outputs']['plot']}")
    return 0


def _inspect(args) -> int:
    path = Path(args.file)
    suffix = path.suffix.lower()
    try:
        # required: a file without sssbake data is refused as verify and the readers refuse it
        if suffix in (".glb", ".gltf"):
            from sssbake.exporters.inspect_gltf import inspect_glb

            info = inspect_glb(path, required=True)
        elif suffix in (".usdc", ".usda", ".usd"):
            from sssbake.exporters.inspect_usd import inspect_usdc

            info = inspect_usdc(path, required=True)
        else:
            print(f"error: {path}: inspect reads .glb/.gltf/.usd/.usda/.usdc files", file=sys.stderr)
            return 2
    except AssetError as e:  # already "<path>: <problem>"
        print(f"error: {_one_line(str(e))}", file=sys.stderr)
        return 1
    except Exception as e:  # any unreadable file is one line, not a traceback
        print(f"error: {path}: cannot inspect: {str(e).splitlines()[0] if str(e) else type(e).__name__}", file=sys.stderr)
        return 1
    from sssbake.exporters.inspect_summary import summary_lines
    from sssbake.pipeline.techniques.footprint import footprint

    used = footprint(info)
    if args.json:
        print(json.dumps({**info, "footprint": used}, indent=1, default=str))
    else:
        print("\n".join(_one_line(line) for line in summary_lines(info, used)))
    return 0


def _view(args) -> int:
    import threading
    import webbrowser

    from sssbake.exporters.inspect_gltf import inspect_glb
    from sssbake.pipeline.view.serve import ViewServer, check_glb

    check_glb(args.file)
    inspect_glb(args.file)  # resolves every table and attribute: stale data is refused here, not drawn
    server = ViewServer(args.file, args.port)
    try:  # from the URL line on: a Ctrl-C as soon as it is printed still closes the server
        print(f"viewing {args.file} at {server.url} (Ctrl-C to stop)", flush=True)
        if not args.no_open:
            webbrowser.open(server.url)
        threading.Event().wait()  # the server runs in its own thread until Ctrl-C
    except KeyboardInterrupt:
        pass
    finally:
        server.close()
    return 0


def _doctor(args) -> int:
    from sssbake.pipeline.doctor import install_validator, run_checks

    if args.install_validator:
        print(install_validator(), flush=True)  # then the checks, the validator's among them, as after any run
    checks = run_checks()
    for check in checks:
        print(_one_line(check.line()))
    missing = [c.part for c in checks if c.required and not c.ok]
    print(f"{len(missing)} required part(s) missing: {', '.join(missing)}" if missing else "all required parts are ok")
    return 1 if missing else 0


def _port(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        value = -1
    if not 0 <= value <= 65535:
        raise argparse.ArgumentTypeError(f"must be a port number 0-65535 (0: a free one), got {text!r}")
    return value


def _presets(args) -> int:
    from sssbake.pipeline.core.materials import preset, preset_names
    from sssbake.pipeline.core.profile import profile_for, total_reflectance

    print(f"{'preset':<11} {'eta':>4}  {'R_d (RGB)':<20} {'mfp mm (RGB)':<22} diffusion length mm (RGB)")
    for name in preset_names():
        m = preset(name, args.profile)
        rd = total_reflectance(profile_for(m))
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


#: The commands, each with its help (`build_parser`).
COMMANDS = {
    "bake": "bake assets (files or folders, walked recursively) into glTF + USD",
    "inspect": "show the sssbake data a .glb or .usdc holds, with bytes per vertex",
    "verify": "render an export with the shipped GLSL and the offline reference; image RMSE",
    "tradeoff": "sweep a technique's knobs: image RMSE vs bytes per vertex and seconds",
    "plan": "which technique each object and material needs, with reasons (bakes nothing)",
    "view": "show a baked .glb in the browser with the three.js runtime (127.0.0.1 only)",
    "doctor": "check the run-time parts outside Python (Node.js, the glTF validator, three.js, EGL, Chromium, "
              "Mitsuba): ok or missing, with the fix",
    "presets": "list the measured material presets (Jensen et al. 2001)",
}


def build_parser(arguments: bool = True) -> argparse.ArgumentParser:
    """The command line's parser; `arguments` False: the commands alone, each with its help but none of
    its arguments, which is all ``sssbake --help`` shows: their defaults and choices import every
    technique (`pipeline.options`), and it then imports none."""
    parser = argparse.ArgumentParser(prog="sssbake", description=__doc__)
    sub = parser.add_subparsers(dest="command", required=True)
    commands = {name: sub.add_parser(name, help=text) for name, text in COMMANDS.items()}
    if not arguments:
        return parser
    from sssbake.pipeline.options import BAKE_DEFAULTS
    from sssbake.pipeline.techniques import registry

    b = commands["bake"]
    b.add_argument("paths", nargs="+", help="asset files or folders")
    b.add_argument("-o", "--out", required=True, help="output folder (mirrors the input tree)")
    b.add_argument("--material", help=f"preset name or 'opaque' for unmatched materials (default {BAKE_DEFAULTS.material})")
    b.add_argument("--config", help="TOML batch config (defaults, per-file rules, material rules)")
    b.add_argument("--scale-mm", type=float,
                   help=f"millimetres per file unit (required for OBJ/PLY/STL{_within('scale_mm')})")
    b.add_argument("--atlas-resolution", type=int,
                   help=f"atlas texels per side (default {BAKE_DEFAULTS.atlas_resolution}{_within('atlas_resolution')})")
    b.add_argument("--techniques",
                   help=f"comma-separated techniques to bake besides the fallback: {', '.join(registry.NAMES)}; "
                        "auto: the planner chooses per mesh and material, with a reason in the report; none: "
                        f"the fallback only (default {','.join(BAKE_DEFAULTS.techniques) or 'none'})")
    _profile_argument(b)
    # store_true with default None: an absent flag leaves the config's value alone
    b.add_argument("--khr-materials-volume-scatter", action="store_true", default=None,
                   help="also write KHR_materials_volume_scatter, a Khronos draft extension, on each translucent "
                        "material of the .glb, with the volume attenuation as the extinction it defines "
                        "(docs/engines.md); off by default")
    _technique_arguments(b)
    b.add_argument("--report", action="store_true",
                   help="also write OUT/report.html: each technique verified against the reference, with pictures")
    _budget_arguments(b)
    _allow_root_argument(b)
    b.add_argument("--jobs", type=_whole_number_at_least_1, default=1, help="assets baked in parallel (default 1)")
    b.add_argument("--asset-timeout", dest="asset_timeout_s", type=float, metavar="SECONDS",
                   help=f"wall time one asset's worker may take before it is killed and the asset fails, 0 for no "
                        f"limit (default {BAKE_DEFAULTS.asset_timeout_s:g}{_within('asset_timeout_s')})")
    b.add_argument("--asset-memory", dest="asset_memory_gib", type=float, metavar="GIB",
                   help=f"resident memory one asset's worker and its children may hold before they are killed and "
                        f"the asset fails, 0 for no limit (default {BAKE_DEFAULTS.asset_memory_gib:g}"
                        f"{_within('asset_memory_gib')})")
    b.add_argument("--dask", metavar="SCHEDULER",
                   help="bake each asset as a task on a Dask cluster: its scheduler's address (tcp://host:8786; "
                        "inputs, OUT and the cache folder must be shared with the workers), or local:N for N "
                        "worker processes here")
    b.add_argument("--cache-dir", help="stage cache folder (default OUT/.sssbake-cache)")
    b.add_argument("--no-cache", action="store_true", help="recompute every stage")
    b.add_argument("--no-validate", action="store_true", help="skip the glTF and USD validators")
    b.add_argument("-q", "--quiet", action="store_true", help="no progress bar, only errors")
    b.set_defaults(func=_bake, flags=_flags(b))

    i = commands["inspect"]
    i.add_argument("file")
    i.add_argument("--json", action="store_true", help="print the whole summary as JSON, with the bytes per vertex "
                                                       "of each technique and mesh (footprint)")
    i.set_defaults(func=_inspect)

    v = commands["verify"]
    v.add_argument("file", help="a .glb written by sssbake bake")
    v.add_argument("--technique", choices=registry.NAMES,
                   help="the technique to verify (default: each one the file holds, in turn)")
    v.add_argument("--lpv-steps", type=int, default=16, help="lpv: propagation steps per frame (default 16)")
    v.add_argument("--light-dir", help="x,y,z world direction towards a directional light (default 0.4,0.8,0.45)")
    v.add_argument("--light-pos", help="x,y,z world position of a point light instead (unit irradiance at the "
                                       "objects' centre)")
    v.add_argument("--reference", default="exact", choices=["exact", "clustered", "checked", "volpath"],
                   help="offline reference: every vertex pair (default), or far sources through float64 "
                        "clusters (~1e-3 of q; for 100k+ vertices), or checked: clustered, and the exact sum at "
                        "a random sample of vertices says how far that moves the RMSE (what --report uses), or "
                        "volpath: physics (Mitsuba 3's volumetric "
                        "path tracer; pip install 'sssbake[physics]'; docs/verify_volpath.md)")
    v.add_argument("--size", type=int, help="image width and height (default 512; 128 with --reference volpath)")
    v.add_argument("--spp", type=int, default=256,
                   help="volpath: the truth's samples per pixel and channel, two halves together (default 256)")
    v.add_argument("--cache-dir", help="volpath: the truth's cache folder (default: .sssbake-cache next to FILE)")
    v.add_argument("--out", help="folder for the PNGs (default: next to the file)")
    v.add_argument("--frames", type=int, default=20, help="frames timed per shader (default 20)")
    v.add_argument("--stock-viewer", action="store_true",
                   help="also render the fallback material, and STEM.sss_normals.glb if the bake wrote it, as a stock "
                        "glTF viewer does (pyrender), and give their RMSE against the same reference")
    v.add_argument("--json", action="store_true", help="print one JSON object")
    v.set_defaults(func=_verify)

    t = commands["tradeoff"]
    t.add_argument("input", help="a mesh file (the largest mesh is used)")
    t.add_argument("--technique", default="prt", choices=registry.NAMES)
    t.add_argument("--material", default=BAKE_DEFAULTS.material, help="preset name (default marble)")
    t.add_argument("--scale-mm", type=float,
                   help=f"millimetres per file unit (required for OBJ/PLY/STL{_within('scale_mm')})")
    _profile_argument(t, BAKE_DEFAULTS.profile)
    for entry in registry.ENTRIES:
        entry.add_tradeoff_arguments(t)
    t.add_argument("--lights", type=int, default=3, help="random test lights; the worst RMSE counts (default 3)")
    t.add_argument("--size", type=int, default=256, help="image size (default 256)")
    t.add_argument("--out", help="folder for the JSON, CSV and plot (default: next to the input)")
    t.add_argument("--json", action="store_true", help="print one JSON object")
    t.set_defaults(func=_tradeoff)

    pl = commands["plan"]
    pl.add_argument("paths", nargs="+", help="files or folders, as for bake")
    pl.add_argument("--config", help="TOML batch config (defaults, per-file rules, material rules)")
    pl.add_argument("--material", help="preset name or 'opaque' for unmatched materials")
    pl.add_argument("--scale-mm", type=float,
                    help=f"millimetres per file unit (required for OBJ/PLY/STL{_within('scale_mm')})")
    _profile_argument(pl)
    pl.add_argument("--json", action="store_true", help="print a JSON list: asset, mesh, material, techniques, "
                                                        "params, reasons, measures (and pilot)")
    _budget_arguments(pl)
    _allow_root_argument(pl)
    pl.set_defaults(func=_plan)

    w = commands["view"]
    w.add_argument("file", help="a .glb written by sssbake bake")
    w.add_argument("--port", type=_port, default=0, help="loopback port (default 0: a free one)")
    w.add_argument("--no-open", action="store_true", help="print the URL, do not open a browser")
    w.set_defaults(func=_view)

    d = commands["doctor"]
    d.add_argument("--install-validator", action="store_true",
                   help="npm install the Khronos glTF-Validator into the per-user folder "
                        "($XDG_DATA_HOME/sssbake/node_modules), then check")
    d.set_defaults(func=_doctor)

    p = commands["presets"]
    _profile_argument(p, BAKE_DEFAULTS.profile)
    p.set_defaults(func=_presets)
    return parser


def _flags(parser) -> dict[str, str]:
    """Each option `parser` sets (its destination) -> the flag that sets it, for messages."""
    return {a.dest: a.option_strings[-1] for a in parser._actions if a.option_strings}


def _within(name: str) -> str:
    """`BakeOptions` field `name`'s range for a flag's help (`core.ranges.Range`), or nothing."""
    from sssbake.pipeline.options import BakeOptions

    allowed = next(f for f in fields(BakeOptions) if f.name == name).metadata.get("range")
    return f"; in {allowed.text()}" if allowed is not None else ""


def _technique_arguments(parser) -> None:
    """``--<technique>-<field>`` for each registered technique's options (`BakeOptions`' technique
    fields), with the help, choices and kind their dataclass field gives; absent: None."""
    from sssbake.pipeline.options import BakeOptions

    for f in fields(BakeOptions):
        if "technique" not in f.metadata:
            continue
        flag, text = "--" + f.name.replace("_", "-"), f.metadata["help"].format(default=f.default) + _within(f.name)
        if f.metadata["flag"]:
            # store_true with default None: an absent flag leaves the config's value alone
            parser.add_argument(flag, action="store_true", default=None, help=text)
        else:
            parser.add_argument(flag, type=_FLAG_TYPES[f.type.removesuffix(" | None")], choices=f.metadata["choices"],
                                help=text)


def _profile_argument(parser, default: str | None = None) -> None:
    from sssbake.pipeline.core.profile_models import PROFILE_MODELS
    from sssbake.pipeline.options import BAKE_DEFAULTS

    parser.add_argument("--profile", choices=PROFILE_MODELS, default=default,
                        help="diffusion profile: montecarlo matches a Monte Carlo random walk (docs/profile.md), scaled in a bake by each "
                             "closed mesh's escape and back gains (docs/fidelity.md); "
                             f"dipole is Jensen et al. 2001's, to reproduce the papers (default {BAKE_DEFAULTS.profile})")


def _budget_arguments(parser) -> None:
    from sssbake.pipeline.options import BAKE_DEFAULTS

    parser.add_argument("--budget-rmse", type=float,
                        help="the image RMSE (verify's, on the full asset) each technique should stay under: the bake "
                             "checks it, and with --techniques auto a pilot on a subsample chooses the parameters")
    parser.add_argument("--max-bytes-per-vertex", type=float,
                        help="with --techniques auto: the most bytes per vertex the planner may spend")
    parser.add_argument("--lambert-margin", type=float,
                        help="with --techniques auto: a planned technique ships only when its object RMSE on the "
                             "pilot's subsample is under (1 - this) x best-fit Lambert's, else the fallback alone; "
                             f"below 1, negative to tolerate worse (default {BAKE_DEFAULTS.lambert_margin:g})")


def _allow_root_argument(parser) -> None:
    parser.add_argument("--allow-root", dest="allow_roots", metavar="FOLDER", action="append", type=_folder,
                        help="a folder besides each asset's own that the files it references (glTF buffers and "
                             "images, USD layers and textures, OBJ materials) may lie in; repeat for more")


def _folder(text: str) -> str:
    if not os.path.isdir(text):
        raise argparse.ArgumentTypeError(f"{text!r} is not a folder")
    return os.path.abspath(text)


def _early_fork_server(argv: list[str]) -> None:
    """For ``bake`` on this machine (not ``--dask``, not ``--help``), start the fork server its
    workers come from now (`asset_process.start_fork_server`): its imports (~1.4 s) then run beside
    this process's own (~1 s) instead of after them."""
    if argv[:1] == ["bake"] and not {"-h", "--help"} & set(argv) and not any(a.startswith("--dask") for a in argv):
        from sssbake.pipeline.bake.asset_process import start_fork_server

        start_fork_server()


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    _early_fork_server(argv)
    # a command's arguments only where one is given: ``sssbake --help`` imports no technique
    args = build_parser(bool(argv) and argv[0] in COMMANDS).parse_args(argv)
    try:
        return args.func(args)
    except SssbakeError as e:
        print(f"error: {_one_line(str(e))}", file=sys.stderr)
        return e.exit_code
    except KeyboardInterrupt:  # Ctrl-C outside a batch's own handling (`_bake`): verify, tradeoff, a start-up
        print("error: interrupted", file=sys.stderr)
        return 128 + signal.SIGINT
    except BrokenPipeError:  # `sssbake presets | head`: the reader has gone, and with it whom to tell
        # Python's flush of stdout at exit would fail again and print that it did
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 128 + signal.SIGPIPE


if __name__ == "__main__":
    sys.exit(main())
