"""``OUT/report.html``: one self-contained page per batch (``sssbake bake … --report``).

Per asset: its status and warnings, the planner's decisions (``--techniques auto``), and per
technique it baked the bytes per vertex, the bake's seconds and, verified against the offline
reference (`verify.verify_file`, small images), the image RMSE, the frame times and the picture
(reference | technique | Lambert). A Pareto plot (matplotlib) puts every verified technique of the
batch at its bytes per vertex and frame-time ratio against its RMSE. Images are inline PNG (base64)
and the style inline, so the page opens from anywhere, headless browsers included.
"""

from __future__ import annotations

import base64
import html
import io
import json
from pathlib import Path

from ..exporters.atomic import atomic_path
from .options import TECHNIQUES

#: Image side of the verification renders (pixels).
VERIFY_SIZE = 160
STYLE = """body{font-family:sans-serif;margin:2em;color:#222}table{border-collapse:collapse;margin:.5em 0}
td,th{border:1px solid #bbb;padding:.25em .6em;text-align:left}th{background:#eee}img{max-width:100%}
.failed{color:#b00}.asset{margin-bottom:2.5em}"""


def write_report(out_dir: Path, summary: dict, verify: bool = True, budget_rmse: float | None = None) -> Path:
    """Write ``out_dir / report.html`` for the batch `summary` (`batch.run_batch`'s) and return it.

    Parameters
    ----------
    verify : bool
        Render each baked technique against the offline reference (slow on big meshes); without
        it the page shows what the bake reports alone.
    budget_rmse : float, optional
        Each verified row says whether its image RMSE is within it, and the page counts them.
    """
    from .verify import verify_file

    out_dir = Path(out_dir)
    sections, points = [], []
    for record in summary["assets"]:
        name = html.escape(record["asset"])
        if record["status"] == "failed":
            sections.append(f'<div class="asset"><h2>{name}</h2><p class="failed">{html.escape(record["error"])}</p></div>')
            continue
        glb = next(Path(p) for p in record["outputs"] if p.endswith(".glb"))
        report = json.loads(Path(next(p for p in record["outputs"] if p.endswith(".report.json"))).read_text())
        rows = []
        for technique in TECHNIQUES:
            if not report.get(technique):
                continue
            figures = {}
            if verify:
                try:
                    figures = verify_file(glb, technique, size=VERIFY_SIZE, out_dir=out_dir / ".report", frames=3)
                except ValueError as error:  # e.g. a technique whose data holds no drawable primitive
                    figures = {"error": str(error).splitlines()[0]}
            rows.append(_technique_row(technique, report, figures, budget_rmse))
            if "rmse_image" in figures:
                points.append((f"{Path(record['asset']).stem} {technique}", figures))
        sections.append(_asset_section(name, record, report, rows))
    body = "".join(sections)
    plot = _pareto(points) if points else ""
    if budget_rmse is not None:
        within = sum(f["rmse_image"] <= budget_rmse for _, f in points)
        plot = f"<p>{within} of {len(points)} verified techniques within the RMSE budget {budget_rmse:g}.</p>" + plot
    page = (f"<!doctype html><html><head><meta charset='utf-8'><title>sssbake batch report</title>"
            f"<style>{STYLE}</style></head><body><h1>sssbake batch report</h1>"
            f"<p>{summary['ok']} baked, {summary['failed']} failed in {summary['seconds']:.1f} s.</p>"
            f"{plot}{body}</body></html>")
    path = out_dir / "report.html"
    with atomic_path(path) as tmp:
        Path(tmp).write_text(page)
    return path


def _asset_section(name: str, record: dict, report: dict, rows: list[str]) -> str:
    warnings = "".join(f"<li>{html.escape(w)}</li>" for w in report.get("warnings", []))
    plan = "".join(f"<tr><td>{html.escape(e['mesh'])}</td><td>{html.escape(e['material'])}</td>"
                   f"<td>{html.escape(', '.join(e['techniques']) or 'no SSS data')}</td>"
                   f"<td>{html.escape('; '.join(e['reasons']))}</td></tr>" for e in report.get("plan", []))
    plan_table = (f"<h3>Plan</h3><table><tr><th>mesh</th><th>material</th><th>techniques</th><th>reason</th></tr>"
                  f"{plan}</table>") if plan else ""
    table = ("<table><tr><th>technique</th><th>bytes / vertex</th><th>RMSE image</th><th>RMSE object</th>"
             "<th>Lambert RMSE</th><th>frame ms (plain)</th><th>budget</th><th>reference | technique | Lambert</th></tr>"
             f"{''.join(rows)}</table>") if rows else "<p>No technique baked: the standard fallback only.</p>"
    return (f'<div class="asset"><h2>{name}</h2><p>{record["status"]}, bake {report.get("seconds", 0):.2f} s, '
            f'{len(report.get("warnings", []))} warnings</p>{"<ul>" + warnings + "</ul>" if warnings else ""}'
            f"{plan_table}{table}</div>")


def _technique_row(technique: str, report: dict, figures: dict, budget: float | None) -> str:
    from .verify import BYTES_PER_VERTEX

    blocks = list(report[technique].values())
    per_vertex = BYTES_PER_VERTEX[technique](blocks[0])
    if "error" in figures:
        return f"<tr><td>{technique}</td><td>{per_vertex:.1f}</td><td colspan='6'>{html.escape(figures['error'])}</td></tr>"
    if not figures:
        return f"<tr><td>{technique}</td><td>{per_vertex:.1f}</td><td colspan='6'>not verified</td></tr>"
    picture = base64.b64encode(Path(figures["pngs"]["comparison"]).read_bytes()).decode()
    return (f"<tr><td>{technique}</td><td>{per_vertex:.1f}</td><td>{figures['rmse_image']:.4f}</td>"
            f"<td>{figures['rmse_object']:.4f}</td><td>{figures['rmse_object_lambert']:.4f}</td>"
            f"<td>{figures['frame_ms_sss']:.1f} ({figures['frame_ms_plain']:.1f})</td>"
            + ("<td>—</td>" if budget is None else
               f"<td>{'within' if figures['rmse_image'] <= budget else 'over'} {budget:g}</td>") +
            f"<td><img alt='{technique}' src='data:image/png;base64,{picture}'></td></tr>")


def _pareto(points: list[tuple[str, dict]]) -> str:
    """The batch's verified techniques: RMSE against bytes per vertex and against the frame-time ratio."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    for ax, key, label in ((axes[0], "bytes_per_vertex", "bytes per vertex"),
                           (axes[1], "frame_ratio", "frame time / plain shader")):
        for name, f in points:
            x = (f.get(key) or 0.0) if key == "bytes_per_vertex" else f["frame_ms_sss"] / max(f["frame_ms_plain"], 1e-9)
            ax.scatter(x, f["rmse_object"])
            ax.annotate(name, (x, f["rmse_object"]), textcoords="offset points", xytext=(4, 4), fontsize=7)
        ax.set(xlabel=label, ylabel="image RMSE (object)", title=f"accuracy vs {label}",
               xscale="symlog" if key == "bytes_per_vertex" else "log")
    fig.tight_layout()
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=80)
    plt.close(fig)
    return f"<h2>All verified techniques</h2><img alt='Pareto' src='data:image/png;base64,{base64.b64encode(buffer.getvalue()).decode()}'>"
