"""Issue 31's fidelity benchmark: every technique, the standard fallback, plain Lambert of R_tot and
best-fit Lambert against physics (Mitsuba 3 volpath, `sssbake verify --reference volpath`), on the
bundled samples and meshes of ../shared/assets, two materials, front- and back-lit.

    python benchmarks/bench_fidelity.py [--out /tmp/sssbake-fidelity] [--size 128] [--spp 128]
        [--materials marble,skin1] [--meshes sphere,hand] [--markdown FILE]

Per (mesh, material) one bake with all five techniques (`sssbake bake --techniques
prt,kernels,spectral,screen,lpv`, the profile the bake defaults to), then per light one volpath
truth (cached by content in OUT/cache: a rerun renders nothing) and each technique's runtime under
the same lobe. Figures: relative RMSE with the truth's noise taken out in quadrature,
sqrt(r² - floor²), read per block of 8 × 8 pixels and per visible vertex
(`pipeline/verify/volpath_measures.py`); the floors are printed with them. Front: verify's default
light (the lobe around (0.4, 0.8, 0.45)); back: the lobe straight behind the object as the camera
sees it. "size / ℓ" is the bounding-box diagonal in diffusion lengths 1/σ_tr of the most
translucent channel, the planner's measure of how translucent the object is at its scale.

Shared assets that are missing are skipped with a line saying so (the samples always run).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path


from sssbake.pipeline.verify.volpath import verify_volpath

HERE = Path(__file__).resolve().parent
SHARED = HERE.parent.parent / "shared" / "assets"
#: (name, file, millimetres per file unit): the samples at their config's scale, the shared meshes
#: at benchmarks/shared_assets.toml's. Closed meshes only: volpath needs an inside.
MESHES = (
    ("sphere", HERE.parent / "samples" / "sphere.obj", 1.0),
    ("torus", HERE.parent / "samples" / "torus.ply", 1.0),
    ("thin_slab", HERE.parent / "samples" / "thin_slab.stl", 1.0),
    ("blob", HERE.parent / "samples" / "blob.obj", 1.0),
    ("duck", SHARED / "duck" / "Duck.glb", 100.0),
    ("hand", SHARED / "hand" / "hand_closed.obj", 200.0),
    ("armadillo", SHARED / "armadillo" / "armadillo.obj", 150.0),
)
TECHNIQUES = ("prt", "kernels", "spectral", "screen", "lpv")
LIGHTS = {"front": (0.4, 0.8, 0.45), "back": (0.3, -0.4, -1.0)}
#: The baselines, by verify_volpath's keys.
BASELINES = {"Lambert R_tot": "rmse_relative_lambert", "best-fit Lambert": "rmse_relative_lambert_fitted",
             "fallback": "rmse_relative_fallback"}


def bake(name: str, mesh: Path, mm: float, material: str, out: Path) -> Path | None:
    """The (mesh, material)'s .glb with every technique, baked once (None, with a line, on failure)."""
    folder = out / "bakes" / material
    glb = folder / f"{mesh.stem}.glb"
    if glb.is_file():
        return glb
    t = time.perf_counter()
    run = subprocess.run([sys.executable, "-m", "sssbake.pipeline.cli", "bake", str(mesh), "-o", str(folder), "--material", material, "--scale-mm",
                          str(mm), "--techniques", ",".join(TECHNIQUES), "--jobs", "1", "-q"],
                         capture_output=True, text=True)
    if run.returncode or not glb.is_file():
        print(f"{name} {material}: bake failed: {(run.stderr or run.stdout).strip().splitlines()[-1:]}")
        return None
    print(f"{name} {material}: baked in {time.perf_counter() - t:.0f} s", flush=True)
    return glb


def size_in_diffusion_lengths(glb: Path) -> float:
    """The bake report's smallest bounding-box diagonal over the most translucent channel's
    diffusion length (instance scales included)."""
    sizes = json.loads(glb.with_name(f"{glb.stem}.report.json").read_text())["sizes"]
    return min(min(s["size_in_diffusion_lengths"]) for entries in sizes.values() for s in entries)


def object_gains(glb: Path) -> dict:
    """The bake's escape and back gains per channel (`pipeline/core/back_share.py`; 1 where none
    applied)."""
    materials = json.loads(glb.with_name(f"{glb.stem}.report.json").read_text())["materials"]
    scattering = [m["scattering"] for m in materials.values() if m["scattering"]][0]
    return {key: scattering.get(key, [1.0, 1.0, 1.0]) for key in ("escape_gain", "back_gain")}


def case(glb: Path, light: tuple, args, out: Path) -> dict:
    """Every technique and baseline of one baked file under one light."""
    row: dict = {"techniques": {}}
    for t in TECHNIQUES:
        r = verify_volpath(glb, t, light, size=args.size, spp=args.spp, cache_dir=out / "cache", out_dir=out / "png")
        row["truth_seconds"] = max(row.get("truth_seconds", 0.0), 0.0 if r["truth_cached"] else r["truth_seconds"])
        row["techniques"][t] = {m: r["measures"][m]["rmse_relative_denoised"]["rmse_relative"] for m in r["measures"]}
        row["techniques"][t]["pixel"] = r["rmse_relative_denoised"]["rmse_relative"]
        row["techniques"][t]["scale"] = r["technique_scale"]
    row["baselines"] = {label: {m: r["measures"][m]["rmse_relative_denoised"].get(key) for m in r["measures"]}
                        for label, key in BASELINES.items()}
    row["floors"] = {m: r["measures"][m]["noise_floor"] for m in r["measures"]} | {"pixel": r["noise_floor"]}
    row["samples"] = {m: r["measures"][m]["samples"] for m in r["measures"]} | {"pixel": r["pixels"]}
    row["lambert_scale"] = r["lambert_scale"]
    return row


def table(rows: list[dict], measure: str) -> list[str]:
    """A markdown table of one measure: a technique in bold where it beats best-fit Lambert."""
    head = ["mesh", "material", "size / ℓ", "light", *TECHNIQUES, *BASELINES, "floor"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in rows:
        fit = r["baselines"]["best-fit Lambert"][measure]
        cells = [f"**{v:.3f}**" if v < fit else f"{v:.3f}" for v in (r["techniques"][t][measure] for t in TECHNIQUES)]
        base = ["—" if r["baselines"][b][measure] is None else f"{r['baselines'][b][measure]:.3f}" for b in BASELINES]
        lines.append("| " + " | ".join([r["mesh"], r["material"], f"{r['size_lengths']:.0f}", r["light"], *cells,
                                        *base, f"{r['floors'][measure]:.3f}"]) + " |")
    return lines


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default="/tmp/sssbake-fidelity")
    parser.add_argument("--size", type=int, default=128)
    parser.add_argument("--spp", type=int, default=128)
    parser.add_argument("--materials", default="marble,skin1")
    parser.add_argument("--meshes", help="comma-separated names (default: all of them present)")
    parser.add_argument("--markdown", help="also write the tables to this file")
    args = parser.parse_args()
    out = Path(args.out)
    wanted = set(args.meshes.split(",")) if args.meshes else None
    rows = []
    for name, mesh, mm in MESHES:
        if wanted is not None and name not in wanted:
            continue
        if not mesh.is_file():
            print(f"{name}: {mesh} is missing, skipped")
            continue
        for material in args.materials.split(","):
            glb = bake(name, mesh, mm, material, out)
            if glb is None:
                continue
            lengths = size_in_diffusion_lengths(glb)
            for light, direction in LIGHTS.items():
                row = {"mesh": name, "material": material, "light": light, "size_lengths": lengths,
                       **object_gains(glb),
                       **case(glb, direction, args, out)}
                rows.append(row)
                beats = [t for t in TECHNIQUES if row["techniques"][t]["block"] < row["baselines"]["best-fit Lambert"]["block"]]
                print(f"{name} {material} {light}: block RMSE " + ", ".join(
                    f"{t} {row['techniques'][t]['block']:.3f}" for t in TECHNIQUES) + "; " + ", ".join(
                    f"{b} {row['baselines'][b]['block']:.3f}" for b in BASELINES if row["baselines"][b]["block"] is not None)
                    + f"; floor {row['floors']['block']:.3f}; beat best-fit Lambert: {', '.join(beats) or 'none'}"
                    + (f"; truth {row['truth_seconds']:.0f} s" if row["truth_seconds"] else ""), flush=True)
    (out / "fidelity.json").write_text(json.dumps(rows, indent=1))
    text = [f"Block RMSE (8 × 8 pixels of {args.size}², {args.spp} spp; noise removed):", "",
            *table(rows, "block"), "", "Per-vertex RMSE (noise removed):", "", *table(rows, "vertex")]
    print("\n".join(text))
    if args.markdown:
        Path(args.markdown).write_text("\n".join(text) + "\n")


if __name__ == "__main__":
    sys.exit(main())
