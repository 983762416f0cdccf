"""tradeoff: the sweeps run, are written as JSON/CSV/plot, and show the expected orderings."""

import csv
import json
from pathlib import Path

from generate import generate

from sssbake.pipeline.cli import main
from sssbake.pipeline.core.materials import preset
from sssbake.pipeline.techniques.prt.tradeoff import prt_tradeoff


def test_sweeps_are_ordered_and_written(tmp_path):
    generate(tmp_path)
    result = prt_tradeoff(tmp_path / "sphere.obj", 1.0, preset("marble"), tmp_path / "out", k=64, ks=(12, 48, 192),
                          orders=(1, 3), reference_fractions=(0.05, 0.3), lights=2, size=48)
    rows = result["rows"]
    by_k = [r["rmse_image"] for r in rows if r["sweep"] == "directions"]
    assert by_k[0] > by_k[1] > by_k[2]  # more directions, less interpolation error (Fig. 5)
    sh = {r["sh_order"]: r["rmse_image"] for r in rows if r["sweep"] == "sh"}
    lloyd = next(r for r in rows if r["sweep"] == "quantization")
    assert sh[3] < sh[1] and lloyd["rmse_image"] < sh[3]
    assert lloyd["bytes_per_vertex"] > 3 * 64  # the uncompressed baseline stores K codes per channel
    refs = {(r["reference_fraction"], r["sh_order"], r["weights"]): r for r in rows if r["sweep"] == "reference_points"}
    assert refs[(0.3, 3, "barycentric")]["rmse_image"] < refs[(0.05, 3, "barycentric")]["rmse_image"]
    assert result["frame_ms_sss"] > 0 and result["frame_ratio"] > 0
    saved = json.loads(Path(result["outputs"]["json"]).read_text())
    assert saved["rows"] == rows
    with open(result["outputs"]["csv"]) as f:
        assert len(list(csv.DictReader(f))) == len(rows)
    assert Path(result["outputs"]["plot"]).stat().st_size > 0


def test_cli_needs_a_scale_for_unitless_files(tmp_path, capsys):
    generate(tmp_path)
    assert main(["tradeoff", str(tmp_path / "sphere.obj")]) == 1
    assert "pass --scale-mm" in capsys.readouterr().err
