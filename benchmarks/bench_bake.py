"""Per-stage bake time and peak memory: one asset, or the dragon swept over sizes and techniques.

    python benchmarks/bench_bake.py [ASSET] [--scale-mm X] [--resolution N] [--techniques prt]
    python benchmarks/bench_bake.py --sweep [--sizes 50k,150k] [--sets prt,all] [--json PATH]

One asset: one line per stage, its seconds, peak traced allocation of the stage (numpy and Python)
and the process's resident high-water mark after it.

``--sweep``: the dragon of ../shared at each size (10k and 150k simplified from the 50k and 200k
files into a temporary folder, `closed_simplified`; 50k, 200k and 800k the files themselves),
baked with each technique alone and all together, each bake in a fresh child process so that its
memory is its own. Per bake and stage: wall seconds, the peak resident memory of the process during
the stage and the stage's own part of it (that peak less the resident memory at the stage's start);
the texel stages (thickness, atlas, thickness map) are made in a child beside the others
(`bake.beside`): their seconds are what the bake waited for them, the child's own beside them, and
no memory of their own (the process tree's peak counts the child and xatlas); per bake the total, the process's peak and the peak of its process tree (with
xatlas and the glTF validator's node; sampled every 0.1 s, so a short spike can be missed). At the
end, per set, the exponents b and d of time ≈ a·n^b and memory ≈ c·n^d fitted in log-log over the
sizes that ran (n: the file's vertices); the total's memory is the bake's part of the process peak
(less the resident memory before the bake). An N log N stage fits b ≈ 1.1 over 10k..800k.

Every bake runs without the stage cache, so each stage does its work, and validates as a bake does
by default.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import tempfile
import time
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import trimesh

from sssbake.pipeline.bake.asset import bake_asset
from sssbake.pipeline.bake.beside import allow_fork
from sssbake.pipeline.bake.asset_process import tree_rss
from sssbake.pipeline.bake.cache import StageCache
from sssbake.pipeline.bake.stages import StageRunner
from sssbake.pipeline.mesh.simplify import simplify
from sssbake.pipeline.options import BAKE_DEFAULTS, TECHNIQUES

DRAGON = Path(__file__).resolve().parents[2] / "shared" / "assets" / "dragon"
DEFAULT_ASSET = DRAGON / "dragon.obj"
#: Per sweep size: the dragon file it comes from and, for a simplified one, its vertex target.
SIZES = {"10k": ("dragon.obj", 10_000), "50k": ("dragon.obj", None), "150k": ("dragon_subdiv1.ply", 150_000),
         "200k": ("dragon_subdiv1.ply", None), "800k": ("dragon_subdiv2.ply", None)}
SETS = (*TECHNIQUES, "all")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("asset", nargs="?", default=str(DEFAULT_ASSET))
    ap.add_argument("--scale-mm", type=float, default=10.0, help="mm per file unit (dragon: 10 → 14 cm long)")
    ap.add_argument("--material", default="marble")
    ap.add_argument("--resolution", type=int, default=BAKE_DEFAULTS.atlas_resolution)
    ap.add_argument("--techniques", default="", help="e.g. prt")
    ap.add_argument("--sweep", action="store_true", help="the dragon over --sizes and --sets")
    ap.add_argument("--sizes", default=",".join(SIZES), help=f"sweep sizes among {','.join(SIZES)}")
    ap.add_argument("--sets", default=",".join(SETS), help=f"sweep technique sets among {','.join(SETS)}")
    ap.add_argument("--json", help="sweep: also write the table here")
    ap.add_argument("--timeout", type=float, default=7200.0, help="sweep: seconds a bake may take")
    ap.add_argument("--child-out", help=argparse.SUPPRESS)  # a sweep's child: bake `asset`, write its figures here
    args = ap.parse_args()
    # no asset limits: the benchmark measures what a bake takes (prt would refuse the 800k dragon
    # under the default --asset-memory 16 from its forecast)
    options = BAKE_DEFAULTS.merged({"scale_mm": args.scale_mm, "material": args.material,
                                    "atlas_resolution": args.resolution, "techniques": args.techniques,
                                    "asset_memory_gib": 0.0, "asset_timeout_s": 0.0})
    if args.child_out:
        Path(args.child_out).write_text(json.dumps(child_bake(Path(args.asset), options)))
    elif args.sweep:
        sweep(args)
    else:
        one(Path(args.asset), options)


def one(asset: Path, options) -> None:
    """Bake `asset` once in this process and print its stages."""
    if not asset.exists():
        print(f"skipped: {asset} not found")
        return
    with tempfile.TemporaryDirectory() as tmp:
        result = bake_asset(asset, options, Path(tmp) / asset.stem, StageCache(None), trace_memory=True)
        sizes = {p.suffix: p.stat().st_size for p in result.outputs}
    r = result.report
    print(f"{asset.name}: {r['vertices']} vertices, {r['faces']} faces, total {r['seconds']:.2f} s")
    print(f"{'stage':<14}{'seconds':>9}{'peak traced MB':>16}{'process peak RSS MB':>21}")
    for name, s in r["stages"].items():
        if s.get("skipped"):
            print(f"{name:<14}{'skipped':>9}  ({s['skipped']})")
            continue
        print(f"{name:<14}{s['seconds']:>9.2f}{s.get('peak_traced_mb', 0.0):>16.1f}{s['peak_rss_mb']:>21.1f}")
    for mesh, a in r["atlas"].items():
        print(f"atlas {mesh!r}: {a['width']}x{a['height']} texels, {a['charts']} charts, "
              f"xatlas child peak RSS {a['xatlas_peak_rss_mb']} MB")
    for mesh, p in r["prt"].items():
        print(f"prt {mesh!r}: {json.dumps(p['seconds'])}; {p['referencePoints']} reference points, "
              f"{p['bytesPerVertex']['total']:.1f} B/vertex; q compression rms/max {p['compressionRmsOverMax']:.4f}")
    print("output bytes:", json.dumps(sizes))
    print("validation:", json.dumps(r["validation"]))


def _status_mb(field: str) -> float:
    """``VmHWM`` or ``VmRSS`` of this process, MB."""
    with open("/proc/self/status") as f:
        return next(int(line.split()[1]) for line in f if line.startswith(field + ":")) / 1024.0


def _reset_peak() -> None:
    # Linux: "5" resets the process's resident high-water mark (VmHWM) to its current resident size.
    with open("/proc/self/clear_refs", "w") as f:
        f.write("5")


def child_bake(asset: Path, options) -> dict:
    """Bake `asset` (no cache) in this process, each stage's peak resident memory measured apart.

    The process is fresh, as a bake's worker is, so its texel stages (thickness, atlas, thickness
    map) are made in a child beside the others (`bake.beside`): they get their seconds in that
    child (``beside_seconds``) and what the bake waited for them, no memory figures of their own
    (the process tree's peak counts the child). The kernel's high-water mark is reset as each stage
    on the main thread starts and read as it ends; the peak between stages is read before each
    reset, so `process_peak_mb` is the bake's whole peak.
    """
    allow_fork()
    stages: dict[str, dict] = {}
    peak = _status_mb("VmHWM")  # imports
    before = _status_mb("VmRSS")
    measure = StageRunner._measure

    @contextmanager
    def measured(runner, rec):
        nonlocal peak
        peak = max(peak, _status_mb("VmHWM"))
        start = _status_mb("VmRSS")
        _reset_peak()
        with measure(runner, rec):
            yield
        top = _status_mb("VmHWM")
        peak = max(peak, top)
        s = stages.setdefault(rec.name, {"peak_mb": 0.0, "own_mb": 0.0})
        s["peak_mb"], s["own_mb"] = max(s["peak_mb"], top), max(s["own_mb"], top - start)

    StageRunner._measure = measured
    try:
        with tempfile.TemporaryDirectory() as tmp:
            result = bake_asset(asset, options, Path(tmp) / asset.stem, StageCache(None))
    except Exception as e:  # the sweep goes on with the next bake and says why this one failed
        return {"error": f"{type(e).__name__}: {e}".splitlines()[0]}
    finally:
        StageRunner._measure = measure
    r = result.report
    for name, s in r["stages"].items():
        if "beside_seconds" in s:
            stages[name] = {"peak_mb": None, "own_mb": None, "beside_seconds": s["beside_seconds"]}
        if name in stages:
            stages[name]["seconds"] = s["seconds"]
    return {
        "seconds": r["seconds"],
        "stages": stages,
        "skipped": [name for name, s in r["stages"].items() if s.get("skipped")],
        "process_peak_mb": max(peak, _status_mb("VmHWM")),
        "rss_before_mb": before,
        "xatlas_peak_mb": max((a["xatlas_peak_rss_mb"] or 0.0 for a in r["atlas"].values()), default=None),
        "warnings": r["warnings"],
    }


def closed_simplified(source: Path, vertices: int, folder: Path) -> tuple[Path, bool]:
    """`source` simplified to about `vertices` vertices, written to `folder` as PLY; and whether it is closed.

    fast-simplification can leave two faces on the same three vertices (a pinched pair, open
    around it), and lpv voxelises a surface that is not closed by the slower winding number
    (`lpv_grid.voxelise`), which would skew the sweep: both faces of each such pair are dropped,
    then the vertices no face uses.
    """
    mesh = trimesh.load(source, process=False, force="mesh")
    s = simplify(np.asarray(mesh.vertices, np.float64), np.asarray(mesh.faces), target_count=2 * vertices)
    _, inverse, counts = np.unique(np.sort(s.faces, axis=1), axis=0, return_inverse=True, return_counts=True)
    out = trimesh.Trimesh(s.positions, s.faces[counts[inverse.ravel()] == 1], process=False)
    out.remove_unreferenced_vertices()
    path = folder / f"{source.stem}_{vertices // 1000}k.ply"
    out.export(path)
    return path, bool(out.is_watertight)


def fit_exponent(n: list[float], y: list[float]) -> float | None:
    """b of y ≈ a·n^b by least squares in log-log over the positive `y`; None under two points."""
    pts = [(a, b) for a, b in zip(n, y) if b is not None and b > 0]
    if len(pts) < 2:
        return None
    x, v = np.log(np.array(pts)).T
    return float(np.polyfit(x, v, 1)[0])


def sweep(args) -> None:
    """Bake the dragon at each of `args.sizes` with each of `args.sets`, print the table and the fits."""
    sizes, sets = args.sizes.split(","), args.sets.split(",")
    unknown = sorted(set(sizes) - set(SIZES)) + sorted(set(sets) - set(SETS))
    if unknown:
        sys.exit(f"unknown size or set {unknown}; sizes {list(SIZES)}, sets {list(SETS)}")
    table: dict[str, dict] = {}
    with tempfile.TemporaryDirectory() as tmp:
        for size in sizes:
            name, target = SIZES[size]
            source = DRAGON / name
            if not source.exists():
                print(f"== {size}: skipped ({source} not found)")
                continue
            if target is None:
                asset, closed = source, None
            else:
                asset, closed = closed_simplified(source, target, Path(tmp))
            vertices = len(trimesh.load(asset, process=False, force="mesh").vertices)
            note = "" if closed is None else f", simplified from {name}, " + (
                "closed" if closed else "not closed: lpv takes the winding-number voxelisation")
            print(f"== {size}: {asset.name}, {vertices} vertices{note}", flush=True)
            table[size] = {"asset": str(asset), "vertices": vertices, "closed": closed, "sets": {}}
            for set_name in sets:
                bake = _run_child(asset, set_name, args, Path(tmp) / "child.json")
                table[size]["sets"][set_name] = bake
                _print_bake(set_name, bake)
    fits = _fits(table, sets)
    _print_fits(fits)
    if args.json:
        Path(args.json).write_text(json.dumps({"scale_mm": args.scale_mm, "material": args.material,
                                               "atlas_resolution": args.resolution, "sizes": table, "fits": fits},
                                              indent=1))


def _run_child(asset: Path, set_name: str, args, out: Path) -> dict:
    """The figures of one bake of `asset` with `set_name`, made by a fresh process (`child_bake`), and
    the peak resident memory of its process tree (xatlas, the validator's node), sampled every 0.1 s."""
    techniques = ",".join(TECHNIQUES) if set_name == "all" else set_name
    cmd = [sys.executable, __file__, str(asset), "--scale-mm", str(args.scale_mm), "--material", args.material,
           "--resolution", str(args.resolution), "--techniques", techniques, "--child-out", str(out)]
    out.unlink(missing_ok=True)
    t0 = time.perf_counter()
    tree_peak = 0
    with tempfile.TemporaryFile("w+") as log:
        # its own process group, so that a timeout kills xatlas and the validator with it
        child = subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, text=True, start_new_session=True)
        while child.poll() is None:
            if time.perf_counter() - t0 > args.timeout:
                os.killpg(child.pid, signal.SIGKILL)
                child.wait()
                return {"error": f"over {args.timeout:g} s"}
            tree_peak = max(tree_peak, tree_rss(child.pid))
            time.sleep(0.1)
        if not out.exists():
            log.seek(0)
            tail = (log.read().strip().splitlines() or ["no output"])[-1]
            return {"error": f"child died (exit status {child.returncode}): {tail}"}
    return {**json.loads(out.read_text()), "tree_peak_mb": tree_peak / 2**20,
            "process_seconds": round(time.perf_counter() - t0, 2)}


def _print_bake(set_name: str, bake: dict) -> None:
    if "error" in bake:
        print(f"  {set_name}: failed: {bake['error']}", flush=True)
        return
    print(f"  {set_name}: total {bake['seconds']:.2f} s ({bake['process_seconds']:.1f} s with the process start), "
          f"process peak {bake['process_peak_mb']:.0f} MB ({bake['rss_before_mb']:.0f} MB before the bake), "
          f"process tree peak {bake['tree_peak_mb']:.0f} MB sampled (xatlas {bake['xatlas_peak_mb']} MB)")
    print(f"    {'stage':<14}{'seconds':>9}{'peak MB':>10}{'own MB':>9}  (beside: the child's seconds, and the wait)")
    for name, s in bake["stages"].items():
        mb = (f"{v:>{w}.0f}" if v is not None else f"{'-':>{w}}" for v, w in ((s["peak_mb"], 10), (s["own_mb"], 9)))
        beside = f"  beside {s['beside_seconds']:.2f} s" if "beside_seconds" in s else ""
        print(f"    {name:<14}{s['seconds']:>9.2f}{''.join(mb)}{beside}", flush=True)
    for w in bake["warnings"]:
        print(f"    warning: {w}")


def _fits(table: dict, sets: list[str]) -> dict:
    """Per set, per stage and for the total: the sizes that ran, the time and memory exponents and the
    largest seconds and MB fitted (an exponent of a stage that takes milliseconds is noise)."""
    fits = {}
    for set_name in sets:
        ran = [(t["vertices"], t["sets"][set_name]) for t in table.values() if "error" not in t["sets"][set_name]]
        series = {stage: [(n, b["stages"][stage]["seconds"], b["stages"][stage]["own_mb"]) for n, b in ran
                          if stage in b["stages"]]
                  for stage in dict.fromkeys(name for _, b in ran for name in b["stages"])}
        # the atlas's memory is its xatlas child's
        series["xatlas"] = [(n, b["stages"]["atlas"].get("beside_seconds", b["stages"]["atlas"]["seconds"]),
                             b["xatlas_peak_mb"]) for n, b in ran
                            if b["xatlas_peak_mb"]]
        series["total"] = [(n, b["seconds"], b["process_peak_mb"] - b["rss_before_mb"]) for n, b in ran]
        fits[set_name] = {stage: {"vertices": [n for n, _, _ in pts],
                                  "time_exponent": fit_exponent([n for n, _, _ in pts], [t for _, t, _ in pts]),
                                  "memory_exponent": fit_exponent([n for n, _, _ in pts], [m for _, _, m in pts]),
                                  "max_seconds": max((t for _, t, _ in pts), default=None),
                                  "max_mb": max((m for _, _, m in pts if m is not None), default=None)}
                          for stage, pts in series.items()}
    return fits


def _print_fits(fits: dict) -> None:
    print("\nexponents: time ≈ a·n^b, memory ≈ c·n^d (stage: its own MB; xatlas: the atlas's seconds and its "
          "child's peak; total: the bake's part of the process peak)")
    for set_name, rows in fits.items():
        print(f"  {set_name}")
        for stage, r in rows.items():
            b, d = (f"{v:.2f}" if v is not None else "-" for v in (r["time_exponent"], r["memory_exponent"]))
            mb = f", {r['max_mb']:.0f} MB" if r["max_mb"] is not None else ""
            top = f"largest {r['max_seconds']:.2f} s{mb}" if r["vertices"] else "no size ran"
            print(f"    {stage:<14} b {b:>5}  d {d:>5}  over {len(r['vertices'])} sizes ({top})")


if __name__ == "__main__":
    main()
