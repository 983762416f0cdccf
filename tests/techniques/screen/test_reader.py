"""Reading the screen tables back from the files the bake writes: the glb and the usdc give the
samples the stage made (as float32), per primitive and per material prim."""

import json

import numpy as np
import pygltflib
import pytest
from fixtures import bake_screen_sphere, baked_material

from sssbake.exporters.gltf import EXTENSION
from sssbake.pipeline.core.errors import StaleDataError
from sssbake.pipeline.core.materials import preset
from sssbake.pipeline.techniques.screen.reader import ScreenReadError, read_screen_glb, read_screen_usd
from sssbake.pipeline.techniques.screen.samples import screen_samples


@pytest.fixture(scope="module")
def baked(tmp_path_factory):
    folder = tmp_path_factory.mktemp("read_screen")
    result, options = bake_screen_sphere(folder, material="skin1", screen_samples=10, screen_uniform=3)
    return folder, options, screen_samples(baked_material(result), options.technique_options("screen").samples_options())


def assert_same(read, made):
    for name in ("offsets", "weights", "table"):
        np.testing.assert_array_equal(getattr(read, name), getattr(made, name).astype(np.float32))
    assert (read.driver, read.uniform_radius_mm, read.table_reach_mm) == (
        made.driver, made.uniform_radius_mm, made.table_reach_mm)


def test_glb_and_usd_give_the_stage_s_samples(baked):
    folder, _, made = baked
    from_glb = read_screen_glb(folder / "ball.glb")
    assert list(from_glb) == [(0, 0)]
    assert_same(from_glb[(0, 0)], made)
    from_usd = read_screen_usd(folder / "ball.usdc")
    assert len(from_usd) == 1
    assert_same(next(iter(from_usd.values())), made)


def test_files_without_screen_tables_and_broken_blocks_are_refused(baked, tmp_path):
    folder, _, _ = baked
    gltf = pygltflib.GLTF2.load(str(folder / "ball.glb"))
    block = gltf.materials[0].extensions[EXTENSION]
    broken = json.loads(json.dumps(block))
    broken["screen"]["driver"] = 7
    gltf.materials[0].extensions[EXTENSION] = broken
    gltf.save(str(tmp_path / "broken.glb"))
    with pytest.raises(ScreenReadError, match="material 0: screen: need a positive table reach and a driver"):
        read_screen_glb(tmp_path / "broken.glb")
    del broken["screen"]
    gltf.save(str(tmp_path / "none.glb"))
    with pytest.raises(ScreenReadError, match="bake with --techniques screen"):
        read_screen_glb(tmp_path / "none.glb")


def test_tables_another_tool_broke_are_refused(baked, tmp_path):
    """The rdTable's accessor renumbered (found by name, read equal), then its bytes rewritten
    (the CRC-32 refuses it)."""
    folder, _, made = baked
    gltf = pygltflib.GLTF2.load(str(folder / "ball.glb"))
    ref = gltf.materials[0].extensions[EXTENSION]["screen"]["rdTable"]
    gltf.accessors.append(gltf.accessors[ref["accessor"]])
    gltf.accessors[ref["accessor"]] = pygltflib.Accessor(bufferView=gltf.accessors[0].bufferView, count=1,
                                                         componentType=5126, type="SCALAR")
    gltf.asset.generator = "glTF-Transform v4.5.1"
    gltf.save(str(tmp_path / "moved.glb"))
    assert_same(read_screen_glb(tmp_path / "moved.glb")[(0, 0)], made)
    blob = bytearray(gltf.binary_blob())
    view = gltf.bufferViews[gltf.accessors[-1].bufferView]
    blob[view.byteOffset:view.byteOffset + 4] = bytes(4)
    gltf.set_binary_blob(bytes(blob))
    gltf.asset.generator = "glTF-Transform v4.5.1"  # pygltflib's save wrote its own
    gltf.save(str(tmp_path / "rewritten.glb"))
    with pytest.raises(StaleDataError, match=r"sssbake/material0/screen/rdTable.*CRC-32.*likely broken by glTF-Transform"):
        read_screen_glb(tmp_path / "rewritten.glb")


def test_inspect_summarises_the_material_tables(baked):
    from sssbake.exporters.inspect_gltf import inspect_glb
    from sssbake.exporters.inspect_usd import inspect_usdc

    folder, _, made = baked
    sizes = {"offsets": 4 * made.offsets.size, "weights": 4 * made.weights.size, "rdTable": 4 * made.table.size}
    (gl,) = inspect_glb(folder / "ball.glb")["materials"]
    (us,) = inspect_usdc(folder / "ball.usdc")["materials"]
    for info in (gl, us):
        block = info["techniques"]["screen"]
        assert {k: t["bytes"] for k, t in block["tables"].items()} == sizes
        assert block["bytes"] == sum(sizes.values())
    # USD: the tables are not listed value by value among the material's attributes
    assert not any(key.startswith("screen:") for key in us["sss"]) and us["extras"]["screen"]["samples"] == 10
