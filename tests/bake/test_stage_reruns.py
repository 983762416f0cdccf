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

import os
import shutil
from pathlib import Path

import pytest
from generate import blob

from sssbake.pipeline.bake.asset import STAGE_VERSIONS, bake_asset
from sssbake.pipeline.bake.cache import StageCache
from sssbake.pipeline.options import BakeOptions

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
    assert {p.name for p in result.outputs} == {"blob.glb", "blob.usdc", "blob.report.json"}
