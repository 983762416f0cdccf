"""The budget check (``--budget-rmse``): every technique a bake wrote is verified on the full asset
(`check_technique`); with ``--techniques auto``, a plan entry whose technique is over the budget
moves to a dearer candidate of its pilot (`plan_pilot`), one within it to a cheaper one, and the
asset is baked again, the stage cache keeping what did not change.

The pilot's RMSE on its subsample is not the full asset's (the subsample is coarser:
benchmarks/README.md#pilot-subsample), so the check scales the pilot's
figures of the baked technique by what the full asset measured, and moves to the first candidate
whose scaled figure meets the budget (one not measured is tried), passing over those whose bytes
did not hold, or that did not beat best-fit Lambert, in the pilot (an entry none beat bakes the
fallback alone and is not moved). Within the budget, a cheaper candidate of another technique
(whose scale is not known) is tried once: screen's pilot errs high, and would otherwise hand a
thick object to prt for good. At most `MAX_BAKES` bakes. The cheapest that met the budget (bytes
per vertex, then frame time) is kept, or the one with the least RMSE when none did; an attempt over
``max_bytes_per_vertex`` is kept only when all are.

The report gets ``check``: the budget, each attempt's picks and figures, the kept attempt's
verify figures (the HTML report shows them) and the seconds the pilot, the bakes and the checks
took together. Assets above `CHECK_MAX_VERTICES` are not checked (the reference would not fit in
memory): the pilot's choice stands, marked unchecked.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

from sssbake.exporters.atomic import atomic_path
from sssbake.pipeline.bake.asset import BakeResult, bake_asset, job_key, json_default, report_dependencies_hold
from sssbake.pipeline.bake.cache import StageCache
from sssbake.pipeline.mesh.digest import file_digest
from sssbake.pipeline.options import BakeOptions
from sssbake.pipeline.planning.pilot import PILOT_SIZE
from sssbake.pipeline.render.sweep import CLUSTERED_ABOVE
from sssbake.pipeline.techniques.registry import NAMES

#: Bakes of one asset the check may make.
MAX_BAKES = 4
#: Largest asset (render vertices) the check verifies: its clustered float64 reference peaks near
#: 50 KB per vertex (benchmarks/README.md#budget-check-memory).
CHECK_MAX_VERTICES = 300_000


def check_technique(glb: Path, technique: str, vertices: int, out_dir: Path) -> dict:
    """`verify.verify_file`'s figures of `technique` in `glb` at the pilot's `PILOT_SIZE`² (its pictures at
    the report's `html_report.PICTURE_SIZE`²: the report shows the kept attempt's), the reference
    summed through clusters above `tradeoff.CLUSTERED_ABOVE` `vertices` (the exact sum takes
    minutes there); ``{"error": line}`` when the file holds nothing it can draw, ``{"skipped": line}``
    above `CHECK_MAX_VERTICES`."""
    from sssbake.pipeline.verify.html_report import PICTURE_SIZE
    from sssbake.pipeline.verify.verify import verify_file

    if vertices > CHECK_MAX_VERTICES:
        return {"skipped": f"not checked: {vertices} vertices, over the check's {CHECK_MAX_VERTICES} (its reference "
                           f"would need about {vertices * 50e3 / 1e9:.2g} GB)"}
    try:
        return verify_file(glb, technique, size=PILOT_SIZE, out_dir=out_dir, frames=3, picture_size=PICTURE_SIZE,
                           reference_sum="clustered" if vertices > CLUSTERED_ABOVE else "exact")
    except ValueError as error:
        return {"error": str(error).splitlines()[0]}


def bake_within_budget(path: Path, options: BakeOptions, out_base: Path, cache: StageCache, *,
                       trace_memory: bool = False) -> BakeResult:
    """`bake.bake_asset` under `options.budget_rmse` (module docstring).

    Raises
    ------
    AssetError, MaterialError, ValueError
        As `bake.bake_asset`.
    """
    budget = options.budget_rmse
    if budget is None:
        raise ValueError("check: no budget_rmse to check against; pass --budget-rmse")
    path = Path(path)
    final = job_key(file_digest(path), options, {"checked": True})
    report_path = out_base.with_suffix(".report.json")
    if report_path.exists():
        try:
            old = json.loads(report_path.read_text())
        except (OSError, ValueError):
            old = {}
        if (old.get("check", {}).get("key") == final and all(Path(p).exists() for p in old.get("outputs", []))
                and report_dependencies_hold(old, path, options)):
            return BakeResult(old, tuple(Path(p) for p in old["outputs"]), up_to_date=True)

    t = time.perf_counter()
    picks: dict[str, int] = {}
    attempts: list[dict] = []
    while True:
        result = bake_asset(path, options, out_base, cache, trace_memory=trace_memory, picks=picks)
        out_dir = out_base.parent / ".sssbake-check" / f"{out_base.name}.{len(attempts)}"
        figures = {t: check_technique(result.outputs[0], t, result.report["vertices"], out_dir)
                   for t in NAMES if result.report.get(t)}
        attempts.append({"picks": dict(picks), "figures": figures, "plan": result.report["plan"]})
        following = next_picks(result.report["plan"], figures, budget, [a["picks"] for a in attempts])
        if following is None or len(attempts) == MAX_BAKES:
            break
        picks = following
    kept = min(range(len(attempts)),
               key=lambda i: _cost(attempts[i]["figures"], budget, options.max_bytes_per_vertex))
    if attempts[kept]["picks"] != picks:  # bake the kept attempt again (its stages come from the cache)
        result = bake_asset(path, options, out_base, cache, trace_memory=trace_memory, picks=attempts[kept]["picks"])
    report = dict(result.report)
    report["check"] = {
        "key": final, "budget": budget, "kept": kept, "seconds": round(time.perf_counter() - t, 3),
        # None: some technique too large to check
        "within": (None if any("skipped" in f for f in attempts[kept]["figures"].values()) else
                   all(f.get("rmse_image", float("inf")) <= budget for f in attempts[kept]["figures"].values())),
        "attempts": [{"picks": a["picks"],
                      "rmse_image": {t: f.get("rmse_image") for t, f in a["figures"].items()},
                      "bytes_per_vertex": {t: f.get("bytes_per_vertex") for t, f in a["figures"].items()},
                      "techniques": sorted(a["figures"])} for a in attempts],
        "figures": attempts[kept]["figures"],
    }
    with atomic_path(report_path) as tmp:
        Path(tmp).write_text(json.dumps(report, indent=1, default=json_default))
    return BakeResult(report, result.outputs)


def next_picks(plan: list[dict], figures: dict, budget: float, tried: list[dict]) -> dict | None:
    """The picks of the next bake (module docstring), or None when there is nothing new to try.

    Parameters
    ----------
    plan : list of dict
        The report's plan entries (`plan.PlanEntry.to_json`), with their ``pilot``.
    figures : dict
        Per technique, the check's figures (``rmse_image``).
    tried : list of dict
        The picks already baked.
    """
    picks, moved = dict(tried[-1]), False
    for e in plan:
        pilot = e.get("pilot")
        if not pilot or not e["techniques"]:  # no candidate beat best-fit Lambert: the fallback alone
            continue
        technique, at = e["techniques"][0], pilot["pick"]
        measured = figures.get(technique, {}).get("rmse_image")
        predicted = pilot["rows"][at]["rmse_image"] if at < len(pilot["rows"]) else None
        if measured is None:
            continue
        scale = measured / predicted if predicted else 1.0

        def estimate(i):
            row = pilot["rows"][i] if i < len(pilot["rows"]) else None
            if row is None or row["rmse_image"] is None:
                return None
            return row["rmse_image"] * (scale if pilot["candidates"][i]["technique"] == technique else 1.0)

        def holds(i):  # the pilot saw its bytes hold (prt's simplification may stop short) and it beat Lambert
            row = pilot["rows"][i] if i < len(pilot["rows"]) else {}
            return row.get("holds_bytes", True) and row.get("beats_lambert", True)

        if measured > budget:
            dearer = [i for i in range(at + 1, len(pilot["candidates"])) if holds(i)]
            to = next((i for i in dearer if estimate(i) is None or estimate(i) <= budget), None)
            if to is None and dearer:
                to = min(dearer, key=lambda i: estimate(i))
        else:  # a cheaper candidate the scaled pilot expects within, or one of another technique, unmeasured here
            to = next((i for i in range(at) if holds(i) and (pilot["candidates"][i]["technique"] != technique
                       or (estimate(i) is not None and estimate(i) <= budget))), None)
        if to is not None and to != at:
            key = f"{e['mesh']}/{e['material']}"
            if to == pilot["chosen"]:  # the pilot's own choice needs no pick: {} and it are one bake
                picks.pop(key, None)
            else:
                picks[key] = to
            moved = True
    if not moved or picks in tried:
        return None
    return picks


def _cost(figures: dict, budget: float, max_bytes: float | None = None) -> tuple:
    """Order of attempts: within the budget first, then bytes per vertex, then frame time; over it,
    by the worst RMSE; last, any over `max_bytes` per vertex."""
    errors = [f.get("rmse_image", float("inf")) for f in figures.values() if "skipped" not in f]
    worst = max(errors, default=0.0)
    spent = sum(f.get("bytes_per_vertex") or 0.0 for f in figures.values())
    if max_bytes is not None and spent > max_bytes:
        return (2, spent, worst)
    if worst <= budget:
        return (0, spent, sum(f.get("frame_ms_sss", 0.0) for f in figures.values()))
    return (1, worst, 0.0)

