"""``OUT/report.html``: one self-contained page per batch (``sssbake bake … --report``).

Per asset: its status and warnings, the planner's decisions (``--techniques auto``), and per
technique it baked the bytes per vertex, the bake's seconds and, verified against the offline
reference (`verify_technique`: small images, the clustered reference checked against the exact sum
at a sample of vertices), the image RMSE, the frame times and the picture (reference | technique |
Lambert, drawn at `PICTURE_SIZE`²: a thumbnail a click enlarges). What the verification cost is on
the page and in each asset's ``.report.json`` (``verification``): its seconds, and those as a
fraction of the bake's. Each row says whether the technique is worse than best-fit Lambert (the full
asset's figures, or where it was not verified its pilot's), and the page counts and names those
that are. A table at the top gives per asset and for the batch the bake's and the verification's
seconds, the techniques and those worse than Lambert. An asset whose glTF the validator did not
check says so. A bake under a budget (``--budget-rmse``) brings its own check's figures, and the
page plots what its pilot measured per candidate beside what the full asset measured
(`plan_check`). A Pareto plot (matplotlib) puts every verified technique of the batch at its bytes
per vertex and frame-time ratio against its RMSE. Images are inline PNG (base64) and the style
inline, so the page opens from anywhere, headless browsers included.
"""

from __future__ import annotations

import base64
import html
import io
import json
import time
from pathlib import Path

from sssbake.exporters.atomic import atomic_path
from sssbake.exporters.inspect_gltf import inspect_glb
from sssbake.pipeline.bake.asset import json_default
from sssbake.pipeline.planning.pilot import PILOT_SIZE, beats_lambert
from sssbake.pipeline.planning.plan import lambert_line, worse_than_lambert
from sssbake.pipeline.techniques.footprint import footprint
from sssbake.pipeline.techniques.registry import NAMES

#: Side in pixels of each image in a row's picture (reference | technique | Lambert). The figures
#: stay at the pilot's `PILOT_SIZE`² (what a budget means), where light bleeding into a shadow, what
#: tells the techniques apart, spans a few pixels; the pictures are drawn again larger (at 512² the
#: bundled samples' page was 1.5 times as large as at 384²).
PICTURE_SIZE = 384
#: Thumbnails 480 CSS pixels wide (three images of `PILOT_SIZE`, the figures' size); a click
#: enlarges one to the window (`.pic:target`, no script: the page is one file), a click on it closes it.
STYLE = """body{font-family:sans-serif;margin:2em;color:#222}table{border-collapse:collapse;margin:.5em 0}
td,th{border:1px solid #bbb;padding:.25em .6em;text-align:left}th{background:#eee}img{max-width:100%}
.failed,.worse{color:#b00}.asset{margin-bottom:2.5em}tr.worse td{background:#fde8e8}
.notice{background:#fff4d6;border-left:4px solid #d90;padding:.4em .8em}.cost{font-size:1.1em}
.pic img{width:480px;max-width:none;cursor:zoom-in}.pic .shut{display:none}
.pic:target{position:fixed;inset:0;z-index:9;margin:0;background:rgba(0,0,0,.88);display:flex;align-items:center;
justify-content:center}.pic:target img{width:auto;max-width:98vw;max-height:96vh;cursor:auto}
.pic:target .shut{display:block;position:fixed;inset:0;cursor:zoom-out}"""


def write_report(out_dir: Path, summary: dict, verify: bool = True, budget_rmse: float | None = None) -> Path:
    """Write ``out_dir / report.html`` for the batch `summary` (`batch.run_batch`'s) and return it.

    Parameters
    ----------
    verify : bool
        Render each baked technique against the offline reference (slow on big meshes); without
        it the page shows what the bake reports alone.
    budget_rmse : float, optional
        Each verified row says whether its image RMSE is within it, and the page counts them (an
        asset baked under a budget is judged by its own).
    """
    out_dir = Path(out_dir)
    sections, points, spent, baked = [], [], 0.0, 0.0
    worse, worse_pilot = [], []  # marks (`plan.lambert_line`): from the full asset's figures, from the pilot's
    # the summary table: a row per asset; all of their techniques, those worse than Lambert, their bakes' seconds
    overview, counted, flagged, bakes = [], 0, 0, 0.0
    for index, record in enumerate(summary["assets"]):
        name = html.escape(record["asset"])
        overview.append(f"<tr><td><a href='#asset-{index}'>{name}</a></td><td>{html.escape(record['status'])}</td>")
        if record["status"] == "failed":
            sections.append(f'<div class="asset" id="asset-{index}"><h2>{name}</h2>'
                            f'<p class="failed">{html.escape(record["error"])}</p></div>')
            overview[-1] += "<td colspan='5'></td></tr>"
            continue
        if record["status"] == "same-file":
            sections.append(f'<div class="asset" id="asset-{index}"><h2>{name}</h2><p>another name of '
                            f'{html.escape(record["same_as"])}, baked once under that name</p></div>')
            overview[-1] += "<td colspan='5'></td></tr>"
            continue
        glb = next(Path(p) for p in record["outputs"] if p.endswith(".glb"))
        report_path = Path(next(p for p in record["outputs"] if p.endswith(".report.json")))
        report = json.loads(report_path.read_text())
        rows, costs, references = [], {}, {}  # one reference per draw unit for all of the asset's techniques
        marked = 0  # of the asset's techniques, those worse than best-fit Lambert
        check = report.get("check", {})
        budget = check.get("budget", budget_rmse)
        for technique in NAMES:
            if not report.get(technique):
                continue
            figures = check.get("figures", {}).get(technique)
            if figures is None and verify:
                t = time.perf_counter()
                figures = verify_technique(glb, technique, report["vertices"], out_dir / ".report", references)
                costs[technique] = _cost(figures, time.perf_counter() - t)
            figures = figures or {}
            if "rmse_image" in figures:
                points.append((f"{Path(record['asset']).stem} {technique}", figures, budget))
                worsened = not beats_lambert(figures["rmse_object"], figures["rmse_object_lambert"], 0.0)
                if worsened:
                    worse.append({"asset": record["asset"], "technique": technique,
                                  "rmse_object": figures["rmse_object"],
                                  "lambert_rmse_object": figures["rmse_object_lambert"]})
            else:
                marks = [m for m in worse_than_lambert(report) if m["technique"] == technique]
                worse_pilot += [{"asset": record["asset"], **m} for m in marks]
                worsened = bool(marks)
            marked += worsened
            rows.append(_technique_row(technique, report, figures, budget, worsened, costs.get(technique),
                                       f"pic-{index}-{technique}"))
        if costs:
            report["verification"] = _verification(costs, report.get("seconds"))
            spent, baked = spent + report["verification"]["seconds"], baked + (report.get("seconds") or 0.0)
            with atomic_path(report_path) as tmp:
                Path(tmp).write_text(json.dumps(report, indent=1, default=json_default))
        else:  # a verification an earlier report wrote is not this page's
            report.pop("verification", None)
        sections.append(_asset_section(name, record, report, rows, marked, f"asset-{index}"))
        overview[-1] += _overview_cells(report.get("seconds"), report.get("verification"), len(rows), marked)
        counted, flagged, bakes = counted + len(rows), flagged + marked, bakes + (report.get("seconds") or 0.0)
    body = "".join(sections)
    plot = _pareto(points) if points else ""
    lines = [lambert_line(worse, f"at {PILOT_SIZE}² on the full asset"),
             lambert_line(worse_pilot, "on the pilot's subsample; not verified")]
    plot = "".join(f"<p class='worse'>{html.escape(line)}</p>" for line in lines if line) + plot
    budgets = {b for _, _, b in points if b is not None}
    if budgets:
        within = sum(b is not None and f["rmse_image"] <= b for _, f, b in points)
        plot = (f"<p>{within} of {len(points)} verified techniques within the RMSE budget "
                f"{', '.join(f'{b:g}' for b in sorted(budgets))}.</p>") + plot
    overview.append(f"<tr class='total'><th>all</th><td>{summary['ok']} baked, {summary['failed']} failed</td>"
                    + _overview_cells(bakes, {"seconds": spent, "bake_seconds": baked} if spent else None, counted,
                                      flagged))
    table = ("<table class='summary'><tr><th>asset</th><th>status</th><th>bake s</th><th>verification s</th>"
             "<th>verification / bake</th><th>techniques</th><th>worse than best-fit Lambert</th></tr>"
             f"{''.join(overview)}</table>")
    page = (f"<!doctype html><html><head><meta charset='utf-8'><title>sssbake batch report</title>"
            f"<style>{STYLE}</style></head><body><h1>sssbake batch report</h1>"
            f"<p class='cost'>{summary['ok']} baked, {summary['failed']} failed in {summary['seconds']:.1f} s"
            + (f"; <strong>verification {spent:.1f} s, {_fraction(spent, baked)} the bakes' own {baked:.1f} s</strong>"
               if spent else "")
            + ".</p>"
            f"{table}{plot}{body}</body></html>")
    path = out_dir / "report.html"
    with atomic_path(path) as tmp:
        # as its charset says; a file name's bytes that are not UTF-8 (os.fsdecode's escapes) as \udcNN
        Path(tmp).write_text(page, encoding="utf-8", errors="backslashreplace")
    return path


def verify_technique(glb: Path, technique: str, vertices: int, out_dir: Path, references: dict | None = None) -> dict:
    """`verify.verify_file`'s figures of `technique` in `glb` at the pilot's `PILOT_SIZE`² (its pictures at
    `PICTURE_SIZE`²), against the
    clustered reference checked at a sample of vertices (``reference_check``; the exact sum at every
    vertex cost three times the bake: `checked_reference`); ``{"error": line}`` when the file holds
    nothing it can draw, ``{"skipped": line}`` above `check.CHECK_MAX_VERTICES` (the reference's memory);
    `references` as `verify_file`'s (the asset's techniques share theirs)."""
    from sssbake.pipeline.bake.check import CHECK_MAX_VERTICES
    from sssbake.pipeline.verify.verify import verify_file

    if vertices > CHECK_MAX_VERTICES:
        return {"skipped": f"not verified: {vertices} vertices, over {CHECK_MAX_VERTICES} (its reference would need "
                           f"about {vertices * 50e3 / 1e9:.2g} GB)"}
    try:
        return verify_file(glb, technique, size=PILOT_SIZE, out_dir=out_dir, frames=3, reference_sum="checked",
                           references=references, picture_size=PICTURE_SIZE)
    except ValueError as error:
        return {"error": str(error).splitlines()[0]}


def _cost(figures: dict, seconds: float) -> dict:
    """One technique's verification in the report JSON: its wall `seconds`, the reference's, the
    reference's check (`checked_reference.check_figures`) where it ran, and the RMSE figures it gave."""
    return {"seconds": round(seconds, 3), "reference": figures.get("reference"),
            "reference_seconds": figures.get("reference_seconds"), "reference_check": figures.get("reference_check"),
            **{k: figures[k] for k in ("rmse_image", "rmse_object") if k in figures}}


def _verification(costs: dict, bake_seconds: float | None) -> dict:
    """The report JSON's ``verification``: ``seconds`` (all `costs`, technique -> `_cost`), ``bake_seconds``,
    ``bake_fraction`` (None without the bake's) and ``techniques`` (`costs`)."""
    spent = sum(c["seconds"] for c in costs.values())
    return {"seconds": round(spent, 3), "bake_seconds": bake_seconds,
            "bake_fraction": round(spent / bake_seconds, 4) if bake_seconds else None, "techniques": costs}


def _fraction(spent: float, baked: float | None) -> str:
    """``"0.25 ×"`` of `spent` over `baked`, or ``"beside"`` without a bake time."""
    return f"{spent / baked:.2f} ×" if baked else "beside"


def _overview_cells(bake_seconds: float | None, verification: dict | None, techniques: int, marked: int) -> str:
    """The summary table's cells after an asset's (or the batch's) name and status, to the row's end:
    its bakes' `bake_seconds`, the `verification` this page made (``seconds`` and the ``bake_seconds``
    they are a fraction of; None where it verified nothing), its baked `techniques` and how many of
    them are `marked` worse than best-fit Lambert."""
    cost = "<td>—</td><td>—</td>"
    if verification:
        spent = verification["seconds"]
        cost = f"<td>{spent:.2f}</td><td>{_fraction(spent, verification['bake_seconds'])}</td>"
    flag = " class='worse'" if marked else ""
    return f"<td>{bake_seconds or 0.0:.2f}</td>{cost}<td>{techniques}</td><td{flag}>{marked}</td></tr>"


def _validation_notice(report: dict) -> str:
    """A notice where the glTF validator did not run on the asset's outputs, with the reason the bake
    gave: a glTF entry of its ``validation`` that holds only ``skipped`` (no validator installed, a
    hierarchy too deep for it), else, with no glTF entry at all, the validate stage's ``skipped``
    (``--no-validate``) or its warning (reports of older bakes)."""
    gltf = [v for key, v in report.get("validation", {}).items() if key != "usd"]
    skipped = next((v["skipped"] for v in gltf if "skipped" in v), None)
    if gltf and skipped is None:
        return ""
    prefix = "glTF validation skipped: "
    reason = (skipped or report.get("stages", {}).get("validate", {}).get("skipped")
              or next((w[len(prefix):] for w in report.get("warnings", []) if w.startswith(prefix)), "no reason given"))
    return f"<p class='notice'>The glTF validator did not run on these outputs: {html.escape(reason)}</p>"


def _check_line(figures: dict) -> str:
    """The reference of verify's `figures` in words; with a sampled check (``reference_check``:
    `checked_reference.check_figures`) the samples and the bound on the RMSE figures."""
    check = figures.get("reference_check")
    if not check:
        return f"{figures.get('reference', 'exact')} reference"
    lo, hi = check["rms_ci95"]
    return (f"clustered reference, RMSE figures within {check['rms']:.2g} of the exact reference's (95 % CI "
            f"{lo:.2g}–{hi:.2g}): exact sums at {check['vertices']} of {check['of']} vertices and energy scales of "
            f"{check['sources']} sources (off by up to {check['scale_error']:.2%}), drawn at random")


def _asset_section(name: str, record: dict, report: dict, rows: list[str], marked: int, anchor: str) -> str:
    """One asset's part of the page (id `anchor`): its status, times, warnings, plan and technique
    `rows`, of which `marked` are worse than best-fit Lambert."""
    warnings = "".join(f"<li>{html.escape(w)}</li>" for w in report.get("warnings", []))
    plan = "".join(f"<tr><td>{html.escape(e['mesh'])}</td><td>{html.escape(e['material'])}</td>"
                   f"<td>{html.escape(', '.join(e['techniques']) or 'no SSS data')}</td>"
                   f"<td>{html.escape('; '.join(e['reasons']))}</td></tr>" for e in report.get("plan", []))
    plan_table = (f"<h3>Plan</h3><table><tr><th>mesh</th><th>material</th><th>techniques</th><th>reason</th></tr>"
                  f"{plan}</table>") if plan else ""
    if report.get("check"):
        plan_table += _check_section(report)
    table = ("<table><tr><th>technique</th><th>bytes / vertex: attributes / with tables</th><th>RMSE image</th>"
             "<th>RMSE object</th>"
             "<th>Lambert RMSE</th><th>vs best-fit Lambert</th><th>frame ms (plain)</th><th>budget</th>"
             "<th>verification</th><th>reference | technique | Lambert (click to enlarge)</th></tr>"
             f"{''.join(rows)}</table>") if rows else "<p>No technique baked: the standard fallback only.</p>"
    check = report.get("check")
    spent = (f" (the last of {len(check['attempts'])}; with the pilot and the checks {check['seconds']:.1f} s)"
             if check and "seconds" in check else "")
    cost = report.get("verification")
    # what this page's own check of the asset took, on a line of its own beside the bake's time
    verified = (f"<p class='cost'><strong>verification {cost['seconds']:.2f} s "
                f"({_fraction(cost['seconds'], cost['bake_seconds'])} the bake)</strong> beside the bake's "
                f"{cost['bake_seconds'] or 0.0:.2f} s</p>" if cost else "")
    flagged = (f"<p class='worse'><strong>{marked} of {len(rows)} technique{'s' if len(rows) > 1 else ''} worse "
               "than best-fit Lambert</strong></p>" if marked else "")
    return (f'<div class="asset" id="{anchor}"><h2>{name}</h2><p>{record["status"]}, bake '
            f'{report.get("seconds", 0):.2f} s{spent}, {len(report.get("warnings", []))} warnings</p>{verified}'
            f'{flagged}{_validation_notice(report)}{"<ul>" + warnings + "</ul>" if warnings else ""}'
            f"{plan_table}{table}</div>")


def _technique_row(technique: str, report: dict, figures: dict, budget: float | None, worse: bool,
                   cost: dict | None, anchor: str) -> str:
    """One technique's row; `worse`: worse than best-fit Lambert (on the full asset when verified,
    else in its pilot), the row marked in words as well as colour; `cost`: its verification here
    (`_cost`; None: the budget check's figures); `anchor`: its picture's id, the target of the link
    that enlarges it."""
    glb = next(p for p in report["outputs"] if p.endswith(".glb"))
    used = footprint(inspect_glb(glb))["techniques"].get(technique, {"attributes": 0.0, "total": 0.0})
    per_vertex = f"{used['attributes']:.1f} / {used['total']:.1f}"  # as the file holds it, `footprint`
    mark = "<td class='worse'><strong>worse than Lambert</strong></td>" if worse else "<td>—</td>"
    tr = "<tr class='worse'>" if worse else "<tr>"
    if "error" in figures or "skipped" in figures:
        line = figures.get("error", figures.get("skipped"))
        return (f"{tr}<td>{technique}</td><td>{per_vertex}</td><td colspan='3'>{html.escape(line)}</td>{mark}"
                "<td colspan='4'></td></tr>")
    if not figures:
        return (f"{tr}<td>{technique}</td><td>{per_vertex}</td><td colspan='3'>not verified</td>{mark}"
                "<td colspan='4'></td></tr>")
    spent = (f"{cost['seconds']:.2f} s; " if cost else "the budget check's; ") + _check_line(figures)
    picture = base64.b64encode(Path(figures["pngs"]["comparison"]).read_bytes()).decode()
    return (f"{tr}<td>{technique}</td><td>{per_vertex}</td><td>{figures['rmse_image']:.4f}</td>"
            f"<td>{figures['rmse_object']:.4f}</td><td>{figures['rmse_object_lambert']:.4f}</td>"
            f"{mark if worse else '<td>better</td>'}"
            f"<td>{figures['frame_ms_sss']:.1f} ({figures['frame_ms_plain']:.1f})</td>"
            + ("<td>—</td>" if budget is None else
               f"<td>{'within' if figures['rmse_image'] <= budget else 'over'} {budget:g}</td>") +
            f"<td>{html.escape(spent)}</td><td><div class='pic' id='{anchor}'><a href='#{anchor}'>"
            f"<img alt='{technique}' src='data:image/png;base64,{picture}'></a>"
            "<a class='shut' href='#_' aria-label='close'></a></div></td></tr>")


def _check_section(report: dict) -> str:
    """The budget check's attempts, and per piloted entry its pilot's RMSE per candidate against
    the full asset's at the candidates baked."""
    check = report["check"]
    if not any(a["rmse_image"] for a in check["attempts"]):  # nothing baked to check
        return ""
    attempts = ""
    for i, a in enumerate(check["attempts"]):
        picks = ", ".join(f"{k}: candidate {v}" for k, v in a["picks"].items()) or "the pilot's choices"
        errors = ", ".join(f"{t} {r:.4f}" if r is not None else f"{t} not checked" for t, r in a["rmse_image"].items())
        attempts += (f"<tr><td>{i}{' (kept)' if i == check['kept'] else ''}</td><td>{html.escape(picks)}</td>"
                     f"<td>{html.escape(errors)}</td></tr>")
    verdict = {True: "within", False: "over", None: "unchecked, against"}[check["within"]]
    text = (f"<h3>Budget check ({verdict} {check['budget']:g})</h3>"
            f"<table><tr><th>bake</th><th>candidate picks</th><th>RMSE on the full asset</th></tr>{attempts}</table>")
    piloted = [e for e in report.get("plan", []) if e.get("pilot")]
    if not piloted:
        return text
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    # wide enough for a label per candidate (prt has one per byte budget and K)
    width = max(max(0.32 * len(e["pilot"]["candidates"]), 5.0) for e in piloted)
    fig, axes = plt.subplots(1, len(piloted), figsize=(width * len(piloted), 4.2), squeeze=False)
    for ax, e in zip(axes[0], piloted):
        pilot = e["pilot"]
        labels = [c["label"].split(" (")[0] for c in pilot["candidates"]]  # without the point count
        measured = [(i, r["rmse_image"]) for i, r in enumerate(pilot["rows"]) if r["rmse_image"] is not None]
        ax.plot([i for i, _ in measured], [r for _, r in measured], "o-", label=f"pilot ({pilot['vertices']} vertices)")
        for a in check["attempts"]:
            at = a["picks"].get(f"{e['mesh']}/{e['material']}", pilot["chosen"])
            r = a["rmse_image"].get(pilot["candidates"][at]["technique"])
            if r is not None:
                ax.plot([at], [r], "rs")
        ax.plot([], [], "rs", label="full asset")
        ax.axhline(pilot["budget"], color="k", lw=1, ls="--", label="budget")
        ax.set_xticks(range(len(labels)), labels, rotation=60, ha="right", fontsize=7)
        ax.set(ylabel="image RMSE", title=f"{e['mesh']} / {e['material']}")
        ax.legend(fontsize=7)
    fig.tight_layout()
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=80)
    plt.close(fig)
    return text + f"<img alt='pilot' src='data:image/png;base64,{base64.b64encode(buffer.getvalue()).decode()}'>"


def _pareto(points: list[tuple[str, dict, float | None]]) -> str:
    """The batch's verified techniques (`_pareto_figure`) as a picture on the page."""
    import matplotlib.pyplot as plt

    fig = _pareto_figure(points)
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=80)
    plt.close(fig)
    return ("<h2>All verified techniques</h2><img alt='Pareto' "
            f"src='data:image/png;base64,{base64.b64encode(buffer.getvalue()).decode()}'>")


def _pareto_figure(points: list[tuple[str, dict, float | None]]):
    """A matplotlib figure of the batch's verified `points` (name, figures, budget): object RMSE
    against bytes per vertex (symlog: screen's 0 beside prt's hundreds) and against the frame-time
    ratio (log), each axis's scale and limits from `_axis`."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    ys = [f["rmse_object"] for _, f, _ in points]
    for ax, key, label, scale in ((axes[0], "bytes_per_vertex", "bytes per vertex", "symlog"),
                                  (axes[1], "frame_ratio", "frame time / plain shader", "log")):
        xs = []
        for name, f, _ in points:
            x = (f.get(key) or 0.0) if key == "bytes_per_vertex" else f["frame_ms_sss"] / max(f["frame_ms_plain"], 1e-9)
            ax.scatter(x, f["rmse_object"])
            ax.annotate(name, (x, f["rmse_object"]), textcoords="offset points", xytext=(4, 4), fontsize=7)
            xs.append(x)
        xscale, xlim = _axis(xs, scale)
        ax.set(xlabel=label, ylabel="image RMSE (object)", title=f"accuracy vs {label}", xscale=xscale, xlim=xlim,
               ylim=_axis(ys, "linear")[1])
    fig.tight_layout()
    return fig


def _axis(values: list[float], scale: str) -> tuple[str, tuple[float, float]]:
    """A plot axis's scale and limits for `values` (matplotlib's own on one value, or on equal ones,
    are a sliver with no labelled tick on a log axis).

    The scale is `scale` (``"linear"``, ``"log"`` or ``"symlog"``, matplotlib's default linthresh 2)
    but linear where every value is 0 (nothing to spread out) and symlog for a log axis over a value
    at or under 0 (log cannot place it). The limits pad the values' span in the scale's coordinates
    by a tenth each side; a single value (no span) gets a decade about it on log and symlog axes (a
    factor √10 each side, so that a labelled power of ten falls within) and a tenth of itself (1 at
    0) each side on a linear one.
    """
    import numpy as np
    from matplotlib.scale import LogTransform, SymmetricalLogTransform
    from matplotlib.transforms import IdentityTransform

    v = np.asarray(values, dtype=np.float64)
    if not np.any(v):
        scale = "linear"
    elif scale == "log" and v.min() <= 0:
        scale = "symlog"
    transform = {"linear": IdentityTransform(), "log": LogTransform(10),
                 "symlog": SymmetricalLogTransform(10, 2, 1)}[scale]
    t = transform.transform(v)
    lo, hi = float(t.min()), float(t.max())
    if hi - lo > 1e-9 * max(abs(lo), abs(hi)):
        low, high = transform.inverted().transform(np.array([lo - 0.1 * (hi - lo), hi + 0.1 * (hi - lo)]))
    elif scale == "linear":
        pad = 0.1 * abs(v.max()) or 1.0
        low, high = v.max() - pad, v.max() + pad
    else:  # one value, not 0: a decade about it holds a power of ten
        low, high = sorted((v.max() / 10 ** 0.5, v.max() * 10 ** 0.5))
    return scale, (float(low), float(high))
