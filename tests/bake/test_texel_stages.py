"""The thickness, atlas and thickness map made in a child beside the bake (a worker's) give the very
files made in turn (in this process); an atlas other than the child's guess is made in turn, and
its thickness map with it."""

import json
import os

import numpy as np
import pytest
from generate import blob

from sssbake.pipeline.bake.asset import STAGE_VERSIONS, bake_asset
from sssbake.pipeline.bake.cache import StageCache
from sssbake.pipeline.bake.stages import StageRunner, ThicknessParams, atlas_stage, thickness_stage
from sssbake.pipeline.bake.texel_stages import STAGES, TexelStages, atlas_params, miss_cap
from sssbake.pipeline.cli import main
from sssbake.pipeline.mesh.clean import clean_scene
from sssbake.pipeline.mesh.load import load_scene
from sssbake.pipeline.options import BakeOptions

OPTIONS = BakeOptions(scale_mm=1.0, material="marble", atlas_resolution=64, techniques=("prt",), prt_directions=32,
                      validate=False)


@pytest.fixture(scope="module")
def asset(tmp_path_factory):
    path = tmp_path_factory.mktemp("texels") / "blob.obj"
    blob(subdivisions=2).export(path)
    return path


@pytest.mark.skipif(len(os.sched_getaffinity(0)) < 2, reason="a worker makes them beside only with a second CPU")
def test_a_worker_makes_them_beside_into_the_same_files(asset, tmp_path):
    flags = ["--scale-mm", "1", "--material", "marble", "--atlas-resolution", "64", "--techniques", "prt",
             "--prt-directions", "32", "--no-validate", "--no-cache", "-q"]
    assert main(["bake", str(asset), "-o", str(tmp_path / "worker"), *flags]) == 0
    (tmp_path / "here").mkdir()
    here = bake_asset(asset, OPTIONS, tmp_path / "here" / "blob", StageCache(None)).report
    worker = json.loads((tmp_path / "worker" / "blob.report.json").read_text())
    for stage in STAGES:
        assert worker["stages"][stage]["runs"] == here["stages"][stage]["runs"] == 1
        assert worker["stages"][stage]["beside_seconds"] > 0, worker["stages"][stage]
        assert "beside_seconds" not in here["stages"][stage]
    assert (tmp_path / "worker" / "blob.glb").read_bytes() == (tmp_path / "here" / "blob.glb").read_bytes()


class Served:
    """What the child would send, made here: `TexelStages._made_beside` run to its end."""

    def __init__(self, stages: TexelStages):
        self.sent = dict(stages._made_beside())

    def take(self, name):
        return self.sent.pop(name, None)

    def close(self):
        pass


@pytest.fixture
def texels(asset):
    clean = clean_scene(load_scene(asset))
    mesh, surface = clean.scene.meshes[0], clean.surfaces[0]
    stages = TexelStages(StageRunner(StageCache(None)), OPTIONS, STAGE_VERSIONS, {0: (mesh, surface, "mesh")}, True)
    stages.beside = Served(stages)
    return stages, mesh, surface


def _equal_atlases(a, b):
    assert (a.source, a.width, a.height, a.notes) == (b.source, b.width, b.height, b.notes)
    for pa, pb in zip(a.parts, b.parts, strict=True):
        np.testing.assert_array_equal(pa.uvs, pb.uvs)
        np.testing.assert_array_equal(pa.faces, pb.faces)


def test_the_guessed_atlas_and_its_map_are_the_childs(texels):
    stages, mesh, surface = texels
    records = stages.runner.records
    thick = stages.thickness(0)
    direct = thickness_stage(surface, [p.normals for p in mesh.primitives], miss_cap(surface),
                             ThicknessParams(OPTIONS.thickness_rays))
    np.testing.assert_array_equal(thick.thickness, direct.thickness)
    atlas, _ = stages.atlas(0, reuse_input=True)
    stages.thickness_map(0, atlas)
    assert 0 in stages.from_beside and stages.beside.sent == {}
    for stage in STAGES:
        assert records[stage].runs == 1 and records[stage].beside_seconds > 0


def test_an_atlas_the_child_did_not_guess_is_made_here(texels):
    stages, mesh, _ = texels
    records = stages.runner.records
    stages.thickness(0)
    atlas, _ = stages.atlas(0, reuse_input=False)
    tmap = stages.thickness_map(0, atlas)
    assert 0 not in stages.from_beside
    # made here: their own runs, no child's time; the child's two are left unused
    assert records["atlas"].runs == records["thickness_map"].runs == 1
    assert records["atlas"].beside_seconds == records["thickness_map"].beside_seconds == 0
    assert set(stages.beside.sent) == {("atlas", 0), ("thickness_map", 0)}
    _equal_atlases(atlas, atlas_stage([(p.positions, p.faces, p.uvs) for p in mesh.primitives],
                                      atlas_params(OPTIONS, False)))
    assert tmap.image.shape == (atlas.height, atlas.width)
