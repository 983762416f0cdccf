"""Which stages a changed option reruns: exactly those that read it, the rest come from the stage cache.

The expectations are written from what each stage reads (`bake.asset`, `bake.stages` and the
techniques' ``bake``), not recorded from a run:

- load reads the file and ``allow_roots``; clean reads the scene alone;
- atlas reads the mesh, ``atlas_resolution`` and ``atlas_padding``; thickness the welded surface
  and ``thickness_rays``; thickness_map the atlas, the surface and ``thickness_rays``;
- a mesh technique reads the welded surface, the material, the mesh's millimetres per unit
  (``scale_mm``) and its own ``<technique>_*`` options (kernels also the atlas and its padding),
  but not ``spectral_variant`` (an extra file made from the baked asset at export) nor
  ``lpv_vein_mm`` under the homogeneous ``lpv_field``;
- screen, per material, reads the material and its ``screen_*`` options: no mesh, no scale;
- the pilot (which measures each requested technique that has one, prt, screen and lpv, against
  best-fit Lambert, one run each) reads the welded surface, the material, the scale, and that
  technique's options as its bake reads them.
"""

import copy
import dataclasses
import math
import os
import shutil
from pathlib import Path

import numpy as np
import pytest
from generate import blob

from sssbake.pipeline.bake import stages
from sssbake.pipeline.bake.asset import STAGE_VERSIONS, bake_asset
from sssbake.pipeline.bake.cache import StageCache
from sssbake.pipeline.bake.invariants import check_cached
from sssbake.pipeline.bake.stages import StageRunner
from sssbake.pipeline.mesh.atlas import Atlas
from sssbake.pipeline.mesh.clean import CleanScene
from sssbake.pipeline.mesh.scene import Scene
from sssbake.pipeline.mesh.thickness import ThicknessResult
from sssbake.pipeline.mesh.thickness_map import ThicknessMap
from sssbake.pipeline.options import BakeOptions
from sssbake.pipeline.planning.pilot import Pilot
from sssbake.pipeline.techniques.technique import TechniqueBake

MESH_TECHNIQUES = {"prt", "kernels", "spectral", "lpv"}
ATLAS_READERS = {"atlas", "thickness_map", "kernels"}

# Cheap settings for a 162-vertex blob: the test is about which stages run, not what they make.
BASE = BakeOptions(scale_mm=1.0, material="marble", atlas_resolution=64, validate=False,
                   techniques=("prt", "kernels", "spectral", "screen", "lpv"), prt_directions=32,
                   spectral_eigenpairs=24, screen_samples=16, lpv_resolution=12, lpv_max_steps=16)


@pytest.fixture(scope="module")
def baseline(tmp_path_factory):
    """The blob's file, the stage cache its baseline bake filled and the baseline's output folder."""
    root = tmp_path_factory.mktemp("reruns")
    asset = root / "blob.obj"
    blob(subdivisions=2).export(asset)
    (root / "out").mkdir()
    result = bake_asset(asset, BASE, root / "out" / "blob", StageCache(root / "cache"))
    assert recomputed(result.report) == set(STAGE_VERSIONS)  # a cold cache runs every stage
    return asset, root / "cache", root / "out"


def recomputed(report: dict) -> set[str]:
    """The cached stages (`STAGE_VERSIONS`) that ran at least once without a cache hit."""
    stages = report["stages"]
    return {name for name in STAGE_VERSIONS if name in stages and stages[name]["runs"] - stages[name]["cached"] > 0}


@pytest.mark.parametrize("option, value, expected", [
    # thickness is in file units; screen bakes at 1 mm per unit but reads the escape gain, which follows the size
    ("scale_mm", 2.0, MESH_TECHNIQUES | {"escape_gain", "screen", "pilot"}),
    ("material", "skin1", MESH_TECHNIQUES | {"escape_gain", "screen", "pilot"}),
    ("atlas_resolution", 48, ATLAS_READERS),
    ("atlas_padding", 6, ATLAS_READERS),
    ("thickness_rays", 4, {"thickness", "thickness_map"}),
    ("prt_directions", 24, {"prt", "pilot"}),
    ("prt_energy_dropped", 0.02, {"prt", "pilot"}),
    ("kernels_size", 5, {"kernels"}),
    ("kernels_bits", 16, {"kernels"}),  # its tables are quantised in the stage
    ("spectral_eigenpairs", 20, {"spectral"}),
    ("spectral_basis", True, {"spectral"}),  # the spectrum's tables are made in the stage
    ("spectral_variant", True, set()),  # only an extra file, made from the baked asset at export
    ("screen_samples", 12, {"screen", "pilot"}),
    ("lpv_resolution", 10, {"lpv", "pilot"}),
    ("lpv_field", "marble", {"lpv", "pilot"}),
    ("lpv_vein_mm", 12.0, set()),  # the veins are read only by the marble field, not by the homogeneous one
    ("techniques", ("prt", "kernels", "spectral", "screen"), set()),  # fewer techniques: the rest as they were
    ("lambert_margin", 0.2, {"pilot"}),  # read by the pilot alone
    # a folder more the references may lie in: the same file read, the same scene, nothing after load changes
    ("allow_roots", (str(Path(__file__).parent),), {"load"}),
])
def test_a_changed_option_reruns_only_the_stages_that_read_it(baseline, tmp_path, option, value, expected):
    asset, cache, _ = baseline
    shutil.copytree(cache, tmp_path / "cache")  # each case starts from the baseline's entries alone
    (tmp_path / "out").mkdir()
    result = bake_asset(asset, BASE.merged({option: value}), tmp_path / "out" / "blob", StageCache(tmp_path / "cache"))
    assert not result.up_to_date
    assert recomputed(result.report) == expected


def test_an_identical_rerun_is_up_to_date_and_rewrites_nothing(baseline):
    asset, cache, out = baseline

    def files():
        return {p: os.stat(p).st_mtime_ns for folder in (cache, out) for p in folder.rglob("*") if p.is_file()}

    before = files()
    result = bake_asset(asset, BASE, out / "blob", StageCache(cache))
    assert result.up_to_date
    assert files() == before
    assert {p.name for p in result.outputs} == {"blob.glb", "blob.mtlx", "blob.materials.json", "blob.usdc",
                                                "blob.report.json"}


# --- entries rewritten with a valid checksum around values their stage could not have made ------------


def leaves(value, path: tuple = ()):
    """(path, leaf) of every array and float in `value`, through dataclass fields, tuples, lists and
    dict values; a path step is ``(".", field)``, ``("[]", index)`` or ``("{}", key)``."""
    if isinstance(value, (np.ndarray, float)):
        yield path, value
    elif dataclasses.is_dataclass(value) and not isinstance(value, type):
        for f in dataclasses.fields(value):
            yield from leaves(getattr(value, f.name), (*path, (".", f.name)))
    elif isinstance(value, (tuple, list)):
        for i, x in enumerate(value):
            yield from leaves(x, (*path, ("[]", i)))
    elif isinstance(value, dict):
        for k, x in value.items():
            yield from leaves(x, (*path, ("{}", k)))


def with_leaf(value, path: tuple, leaf):
    """`value` with the leaf at `path` replaced: the containers on the way copied, the rest shared."""
    if not path:
        return leaf
    (kind, step), rest = path[0], path[1:]
    if kind == ".":
        new = copy.copy(value)
        object.__setattr__(new, step, with_leaf(getattr(value, step), rest, leaf))
        return new
    if kind == "{}":
        return {**value, step: with_leaf(value[step], rest, leaf)}
    items = list(value)
    items[step] = with_leaf(value[step], rest, leaf)
    return type(value)(items)


def nan(leaf):
    """(b): a NaN in a float array or for a float."""
    if isinstance(leaf, float):
        return math.nan
    if leaf.dtype.kind == "f" and leaf.size:
        out = leaf.copy()
        out.flat[0] = np.nan
        return out
    return None


def cut(leaf):
    """(c): the array one row short."""
    return leaf[:-1].copy() if isinstance(leaf, np.ndarray) and leaf.ndim and len(leaf) else None


def past_end(leaf):
    """(a): the largest index of an integer array made its dtype's largest value, far past any end."""
    if isinstance(leaf, np.ndarray) and leaf.dtype.kind in "iu" and leaf.size:
        out = leaf.copy()
        out.flat[int(np.argmax(out))] = np.iinfo(out.dtype).max
        return out
    return None


def name_of(path: tuple) -> str:
    return "".join(f".{s}" if k == "." else f"[{s!r}]" for k, s in path)


# Integer arrays that hold codes, not indices: any value of their dtype's range is one the bake writes.
CODES = {"weight_codes", "dq_codes", "ref_codes", "detail_codes", "detail_colour", "kernelCodes", "refCodes",
         "refDetail"}


def allowed(stage: str, path: tuple, kind: str) -> bool:
    """Where a mutation makes a value its stage could have made, so its check rightly lets it by."""
    last = path[-1][1] if path else None
    return ((kind == "nan" and stage == "load" and last in ("normals", "tangents"))  # cleaning recomputes them
            or (kind == "nan" and stage == "atlas" and last == "worker_peak_rss_mb")  # NaN where the OS does not say
            or (kind == "nan" and (".", "report") in path)  # a technique's report block is free-form
            or (kind == "cut" and stage == "screen" and last == "rdTable")  # its length adapts to the error bound
            # a triangle fewer: the scene of another file, which only reading this one again could tell
            or (kind == "cut" and stage == "load" and last == "faces")
            or (kind == "past_end" and last in CODES))


def test_every_stage_refuses_an_index_past_the_end_a_nan_and_an_array_cut_short(baseline, tmp_path, monkeypatch):
    """Each stage's invariants, applied to each value a bake reads from the cache, refuse every one of
    its arrays (and floats) with a NaN, cut short or holding an index past the end."""
    asset, cache, _ = baseline
    seen = []

    def recording(stage, value, inputs, params):
        seen.append((stage, value, inputs, params))
        check_cached(stage, value, inputs, params)

    monkeypatch.setattr(stages, "check_cached", recording)
    names = {}
    real_run = StageRunner.run

    def run(self, name, version, upstream, params, fn, *inputs, fresh=None):
        names[fn] = name
        return real_run(self, name, version, upstream, params, fn, *inputs, fresh=fresh)

    monkeypatch.setattr(StageRunner, "run", run)
    (tmp_path / "out").mkdir()
    result = bake_asset(asset, BASE, tmp_path / "out" / "blob", StageCache(cache))
    assert recomputed(result.report) == set()
    missed, tried = [], set()
    for stage_fn, value, inputs, params in seen:
        stage = names[stage_fn] if stage_fn is not stages.technique_stage else inputs[0].name
        for path, leaf in leaves(value):
            for kind, mutate in (("nan", nan), ("cut", cut), ("past_end", past_end)):
                bad = mutate(leaf)
                if bad is None or allowed(stage, path, kind):
                    continue
                tried.add((stage, kind))
                try:
                    check_cached(stage_fn, with_leaf(value, path, bad), inputs, params)
                except Exception:
                    continue
                missed.append(f"{stage}{name_of(path)} {kind}")
    assert not missed, missed
    # every stage with such fields was tried with each kind
    assert {s for s, k in tried if k == "past_end"} >= {"load", "clean", "atlas", "prt", "kernels"}
    assert {s for s, k in tried if k == "nan"} >= set(STAGE_VERSIONS)
    assert {s for s, k in tried if k == "cut"} >= set(STAGE_VERSIONS) - {"escape_gain", "pilot"}  # they hold no arrays


def leaf_at(value, path: tuple):
    for kind, step in path:
        value = getattr(value, step) if kind == "." else value[step]
    return value


def stage_of(value) -> str:
    """The stage whose entry holds `value`."""
    if isinstance(value, TechniqueBake):
        return "spectral" if isinstance(value.data, np.ndarray) else value.tables["technique"]
    return {Scene: "load", CleanScene: "clean", Atlas: "atlas", ThicknessResult: "thickness",
            ThicknessMap: "thickness_map", tuple: "escape_gain", Pilot: "pilot"}[type(value)]


def at(*steps) -> tuple:
    """A leaf's path from ``"name"`` (a field) and int (an item) steps; ``("key",)`` for a dict key."""
    return tuple(("{}", s[0]) if isinstance(s, tuple) else ("[]", s) if isinstance(s, int) else (".", s) for s in steps)


# Per stage, how its entry is rewritten: each kind on several stages, the three on the stages it met them in
REWRITES = {
    "load": (past_end, at("meshes", 0, "primitives", 0, "faces")),  # was: "face indices outside [0, n)"
    "clean": (cut, at("surfaces", 0, "weld", 0)),
    "atlas": (cut, at("parts", 0, "vmapping")),  # was: an IndexError in asset.py
    "thickness": (nan, at("thickness")),  # was: "fallback thickness_factor is not finite"
    "thickness_map": (cut, at("image")),
    "escape_gain": (nan, at(1, 0)),
    "prt": (past_end, at("data", "vertex_triangle")),
    "kernels": (nan, at("data", "kernels")),
    "spectral": (cut, at("data")),
    "screen": (nan, at("tables", ("weights",))),
    "lpv": (cut, at("tables", ("occupancy",))),
    "pilot": (nan, at("rows", 0, ("rmse_image",))),
}


def test_entries_rewritten_with_a_valid_checksum_are_recomputed_counted_and_warned(baseline, tmp_path):
    asset, cache, out = baseline
    shutil.copytree(cache, tmp_path / "cache")
    store = StageCache(tmp_path / "cache")
    rewritten = {}
    for entry in sorted((tmp_path / "cache").rglob("*.entry")):
        value = store.get(entry.stem)
        stage = stage_of(value)
        if stage not in rewritten:  # one entry per stage (the pilot has one per technique it measured)
            mutate, path = REWRITES[stage]
            store.put(entry.stem, with_leaf(value, path, mutate(leaf_at(value, path))))  # put writes a valid checksum
            rewritten[stage] = entry
    assert set(rewritten) == set(STAGE_VERSIONS)
    (tmp_path / "out").mkdir()
    result = bake_asset(asset, BASE, tmp_path / "out" / "blob", StageCache(tmp_path / "cache"))
    for suffix in (".glb", ".usdc"):
        rebaked, clean = (tmp_path / "out" / "blob").with_suffix(suffix), (out / "blob").with_suffix(suffix)
        assert rebaked.read_bytes() == clean.read_bytes()
    report = result.report["stages"]
    counted = {name: report[name].get("corrupt_cache_entries") for name in STAGE_VERSIONS}
    assert counted == dict.fromkeys(STAGE_VERSIONS, 1)
    warned = sorted(w for w in result.report["warnings"] if w.startswith("stage cache:"))
    assert len(warned) == len(rewritten)
    for line, (stage, entry) in zip(warned, sorted(rewritten.items())):
        assert line.startswith(f"stage cache: the {stage} entry {entry} breaks its stage's invariants (")
        assert line.endswith("); deleted and recomputed") and "\n" not in line
    # rewritten sound: the next bake takes every stage from the cache, and says nothing
    (tmp_path / "again").mkdir()
    again = bake_asset(asset, BASE, tmp_path / "again" / "blob", StageCache(tmp_path / "cache"))
    assert recomputed(again.report) == set()
    assert not [w for w in again.report["warnings"] if w.startswith("stage cache:")]
