"""The budget check: the next bake's picks from the pilot scaled by the full asset's figures, the
cheapest attempt within the budget kept, and a bake that applies what the plan chose."""

import json
import re

import numpy as np
import trimesh

import sssbake.pipeline.bake.check as plan_check
from sssbake.pipeline.bake.cache import StageCache
from sssbake.pipeline.bake.check import _cost, bake_within_budget, next_picks
from sssbake.pipeline.options import BAKE_DEFAULTS


def entry(rows, techniques, pick, chosen=None):
    """A plan entry as the report holds it, its pilot with candidates of `techniques`."""
    return {"mesh": "m", "material": "x", "techniques": [techniques[pick]],
            "pilot": {"candidates": [{"technique": t, "label": f"{t} {i}", "params": {}} for i, t in enumerate(techniques)],
                      "rows": [{"rmse_image": r} for r in rows], "pick": pick,
                      "chosen": pick if chosen is None else chosen, "budget": 0.02, "vertices": 100}}


def test_over_the_budget_the_pilot_is_scaled_by_what_the_full_asset_measured():
    plan = [entry([0.04, 0.03, 0.02, 0.015, 0.01], ["prt"] * 5, pick=2)]
    # the full asset measured 1.5x the pilot: 0.02 * 1.5 = 0.03 > 0.02; 0.015 * 1.5 = 0.0225 still over,
    # 0.01 * 1.5 = 0.015 within: candidate 4
    assert next_picks(plan, {"prt": {"rmse_image": 0.03}}, 0.02, [{}]) == {"m/x": 4}
    # measured 1.2x: 0.015 * 1.2 = 0.018 is within, the first such
    assert next_picks(plan, {"prt": {"rmse_image": 0.024}}, 0.02, [{}]) == {"m/x": 3}
    # nothing dearer is expected within: the one expected least
    assert next_picks(plan, {"prt": {"rmse_image": 0.2}}, 0.02, [{}]) == {"m/x": 4}
    # an unmeasured candidate (an lpv pilot stops early) is worth a try
    short = [entry([0.04, 0.03, 0.025], ["lpv"] * 5, pick=2)]
    assert next_picks(short, {"lpv": {"rmse_image": 0.05}}, 0.02, [{}]) == {"m/x": 3}


def test_the_check_never_moves_to_a_candidate_worse_than_best_fit_lambert():
    plan = [entry([0.04, 0.03, 0.02, 0.015, 0.01], ["prt"] * 5, pick=2)]
    plan[0]["pilot"]["rows"][4]["beats_lambert"] = False
    # over the budget at 1.5x: 4 (0.015) is expected within but does not beat Lambert; 3 (0.0225), the least left
    assert next_picks(plan, {"prt": {"rmse_image": 0.03}}, 0.02, [{}]) == {"m/x": 3}
    plan[0]["pilot"]["rows"][3]["beats_lambert"] = False
    assert next_picks(plan, {"prt": {"rmse_image": 0.03}}, 0.02, [{}]) is None  # nothing dearer beats it
    # within the budget at 0.5x: the cheapest expected within (0), unless it does not beat Lambert
    cheap = [entry([0.03, 0.025, 0.015], ["prt"] * 3, pick=2)]
    cheap[0]["pilot"]["rows"][0]["beats_lambert"] = False
    assert next_picks(cheap, {"prt": {"rmse_image": 0.0075}}, 0.02, [{}]) == {"m/x": 1}
    # an entry none of whose candidates beat Lambert bakes the fallback alone: nothing to move
    fallback = [entry([0.04, 0.03], ["prt", "prt"], pick=1)]
    fallback[0]["techniques"] = []
    assert next_picks(fallback, {}, 0.02, [{}]) is None


def test_within_the_budget_a_cheaper_candidate_is_tried_and_nothing_new_ends_it():
    mixed = ["screen", "screen", "prt", "prt"]
    plan = [entry([0.05, 0.045, 0.03, 0.015], mixed, pick=3)]
    # prt within: screen (another technique, its scale unknown) is tried once, cheapest first
    assert next_picks(plan, {"prt": {"rmse_image": 0.012}}, 0.02, [{}]) == {"m/x": 0}
    # measured at 0.76x the pilot: 0.03 * 0.76 = 0.0228 over, 0.025 * 0.76 = 0.019 within: the cheapest such
    plan_prt = [entry([0.03, 0.025, 0.015], ["prt"] * 3, pick=2)]
    assert next_picks(plan_prt, {"prt": {"rmse_image": 0.0114}}, 0.02, [{}]) == {"m/x": 1}
    assert next_picks(plan_prt, {"prt": {"rmse_image": 0.0075}}, 0.02, [{}]) == {"m/x": 0}  # 0.5x: all of them
    # already tried: nothing new
    assert next_picks(plan_prt, {"prt": {"rmse_image": 0.0114}}, 0.02, [{"m/x": 1}, {}]) is None
    # the cheapest already, within: stay
    first = [entry([0.01, 0.005], ["screen", "screen"], pick=0)]
    assert next_picks(first, {"screen": {"rmse_image": 0.01}}, 0.02, [{}]) is None
    # the dearest already, over: nowhere to go
    last = [entry([0.05, 0.04], ["prt", "prt"], pick=1)]
    assert next_picks(last, {"prt": {"rmse_image": 0.04}}, 0.02, [{}]) is None
    # back to the pilot's own choice: no pick, and a bake already made
    back = [entry([0.05, 0.045, 0.015], ["screen", "screen", "prt"], pick=0, chosen=2)]
    assert next_picks(back, {"screen": {"rmse_image": 0.04}}, 0.02, [{}, {"m/x": 0}]) is None
    assert next_picks(back, {"screen": {"rmse_image": 0.04}}, 0.02, [{"m/x": 0}]) == {}
    # a technique the check could not draw is left alone
    assert next_picks(plan, {"prt": {"error": "no drawable primitive"}}, 0.02, [{}]) is None


def test_attempts_within_the_budget_come_first_then_the_fewest_bytes_then_frame_time():
    over = {"screen": {"rmse_image": 0.03, "bytes_per_vertex": 0.0, "frame_ms_sss": 5.0}}
    prt = {"prt": {"rmse_image": 0.01, "bytes_per_vertex": 12.0, "frame_ms_sss": 2.0}}
    screen = {"screen": {"rmse_image": 0.019, "bytes_per_vertex": 0.0, "frame_ms_sss": 9.0}}
    fast = {"screen": {"rmse_image": 0.019, "bytes_per_vertex": 0.0, "frame_ms_sss": 4.0}}
    assert sorted([over, prt, screen, fast], key=lambda f: _cost(f, 0.02)) == [fast, screen, prt, over]
    worse = {"prt": {"rmse_image": 0.05}}
    assert sorted([worse, over], key=lambda f: _cost(f, 0.02)) == [over, worse]  # over: the least RMSE
    assert _cost({"prt": {"error": "x"}}, 0.02)[0] == 1  # a failed check is over


def test_the_check_bakes_again_keeps_the_cheapest_within_and_is_then_up_to_date(tmp_path, monkeypatch):
    src = tmp_path / "leaf.obj"
    leaf = trimesh.creation.box(extents=(60.0, 60.0, 8.0))  # thin for skin (3.7 mm diffusion length)
    for _ in range(3):
        leaf = leaf.subdivide()
    leaf.export(src)
    options = BAKE_DEFAULTS.merged({"material": "skin1", "scale_mm": 1.0, "techniques": ["auto"], "prt_directions": 16,
                                    "validate": False, "budget_rmse": 0.02, "max_bytes_per_vertex": 40.0})
    seen = []

    def scripted(glb, technique, vertices, out_dir):
        report = json.loads(glb.with_suffix(".report.json").read_text())
        budget = report["plan"][0]["params"]["prt_byte_budget"]
        seen.append(budget)
        # scripted figures: more bytes, less error; within the budget from 35 B/vertex on
        return {"rmse_image": 0.7 / budget, "bytes_per_vertex": report["prt"]["leaf.obj"]["bytesPerVertex"]["total"],
                "frame_ms_sss": 1.0}

    monkeypatch.setattr(plan_check, "check_technique", scripted)
    out = tmp_path / "leaf"
    result = bake_within_budget(src, options, out, StageCache(str(tmp_path / "cache")))
    check = result.report["check"]
    pilot = result.report["plan"][0]["pilot"]
    assert seen[0] == pilot["candidates"][pilot["chosen"]]["params"]["prt_byte_budget"]  # the pilot's pick first
    assert check["within"] and len(check["attempts"]) == len(seen) >= 2
    kept = check["attempts"][check["kept"]]
    assert max(kept["rmse_image"].values()) <= 0.02
    # the cheapest attempt within: none with fewer bytes met it
    within = [a for a in check["attempts"] if max(a["rmse_image"].values()) <= 0.02]
    assert kept["bytes_per_vertex"]["prt"] == min(a["bytes_per_vertex"]["prt"] for a in within)
    on_disk = json.loads(out.with_suffix(".report.json").read_text())
    assert on_disk["check"]["kept"] == check["kept"]
    # what was baked last is the kept attempt: the file's prt is its, within its byte budget
    assert on_disk["plan"][0]["pilot"]["pick"] == kept["picks"].get("leaf.obj/sssbake_default", pilot["chosen"])
    assert on_disk["prt"]["leaf.obj"]["bytesPerVertex"]["total"] == kept["bytes_per_vertex"]["prt"]
    assert on_disk["prt"]["leaf.obj"]["bytesPerVertex"]["total"] <= on_disk["plan"][0]["params"]["prt_byte_budget"]
    np.testing.assert_allclose(0.7 / on_disk["plan"][0]["params"]["prt_byte_budget"], max(kept["rmse_image"].values()))
    calls = len(seen)
    again = bake_within_budget(src, options, out, StageCache(str(tmp_path / "cache")))
    assert again.up_to_date and len(seen) == calls  # nothing checked twice


def test_an_asset_too_large_to_check_keeps_the_pilots_choice_marked_unchecked(tmp_path, monkeypatch):
    src = tmp_path / "ball.obj"
    trimesh.creation.icosphere(subdivisions=2, radius=1.0).export(src)
    options = BAKE_DEFAULTS.merged({"material": "skin1", "scale_mm": 100.0, "techniques": ["auto"],
                                    "validate": False, "budget_rmse": 0.05})
    monkeypatch.setattr(plan_check, "CHECK_MAX_VERTICES", 100)  # the ball has 162 welded vertices
    result = bake_within_budget(src, options, tmp_path / "ball", StageCache(str(tmp_path / "cache")))
    check = result.report["check"]
    assert check["within"] is None and len(check["attempts"]) == 1
    assert re.match(r"not checked: \d+ vertices, over the check.s 100 ", check["figures"]["screen"]["skipped"])
    pilot = result.report["plan"][0]["pilot"]
    assert pilot["pick"] == pilot["chosen"]


def test_candidates_whose_bytes_did_not_hold_are_passed_over():
    plan = [entry([0.04, 0.03, 0.02, 0.01], ["prt"] * 4, pick=0)]
    plan[0]["pilot"]["rows"][3]["holds_bytes"] = False  # simplification stopped short: more bytes than allowed
    plan[0]["pilot"]["rows"][1]["holds_bytes"] = False
    assert next_picks(plan, {"prt": {"rmse_image": 0.04}}, 0.02, [{}]) == {"m/x": 2}
    over = {"prt": {"rmse_image": 0.01, "bytes_per_vertex": 50.0}}
    within = {"prt": {"rmse_image": 0.019, "bytes_per_vertex": 30.0}}
    worse = {"prt": {"rmse_image": 0.03, "bytes_per_vertex": 20.0}}
    assert sorted([over, worse, within], key=lambda f: _cost(f, 0.02, 32.0)) == [within, worse, over]
