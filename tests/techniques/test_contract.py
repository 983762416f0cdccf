"""The contract every registered technique keeps: its options are BakeOptions' fields and bake
flags with the same defaults, and it bakes a small sphere into glTF and USD that validate, whose
data read back from both files is the same, and that verify draws with finite figures."""

import dataclasses
import math

import numpy as np
import pytest
import trimesh

from sssbake.exporters.inspect_gltf import inspect_glb
from sssbake.exporters.inspect_usd import inspect_usdc
from sssbake.pipeline.bake.asset import STAGE_VERSIONS, bake_asset
from sssbake.pipeline.bake.cache import StageCache
from sssbake.pipeline.cli import build_parser
from sssbake.pipeline.options import BAKE_DEFAULTS, BakeOptions
from sssbake.pipeline.techniques.footprint import footprint
from sssbake.pipeline.techniques.registry import NAMES, TECHNIQUES
from sssbake.pipeline.verify.verify import verify_file


@pytest.fixture(scope="module")
def ball(tmp_path_factory):
    path = tmp_path_factory.mktemp("contract") / "ball.obj"
    trimesh.creation.icosphere(subdivisions=2, radius=5.0).export(path)
    return path


def assert_same(a, b, where="data"):
    """`a` and `b` hold the same values: arrays to float32 storage precision (USD keeps float32,
    glTF stores normals as normalized shorts), everything else exactly."""
    if dataclasses.is_dataclass(a):
        assert type(a) is type(b), where
        for f in dataclasses.fields(a):
            assert_same(getattr(a, f.name), getattr(b, f.name), f"{where}.{f.name}")
    elif isinstance(a, (tuple, list)) and not np.isscalar(a):
        assert len(a) == len(b), where
        for i, (x, y) in enumerate(zip(a, b)):
            assert_same(x, y, f"{where}[{i}]")
    elif isinstance(a, (np.ndarray, float, int, np.number)):
        x, y = np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)
        assert x.shape == y.shape, where
        np.testing.assert_allclose(x, y, rtol=1e-6, atol=5e-5, err_msg=where)
    else:
        assert a == b, where


def finite_numbers(value, where="result"):
    """Every number in a JSON-like `value`, with where it is."""
    if isinstance(value, dict):
        for k, v in value.items():
            yield from finite_numbers(v, f"{where}.{k}")
    elif isinstance(value, (list, tuple)):
        for i, v in enumerate(value):
            yield from finite_numbers(v, f"{where}[{i}]")
    elif isinstance(value, (int, float)) and not isinstance(value, bool):
        yield where, value


@pytest.mark.parametrize("technique", TECHNIQUES, ids=NAMES)
def test_options_are_bake_options_flags_and_toml_keys(technique):
    options = technique.options_type()
    options.check()
    assert BAKE_DEFAULTS.technique_options(technique.name) == options
    flags = build_parser()._subparsers._group_actions[0].choices["bake"]._option_string_actions
    for f in dataclasses.fields(options):
        key = f"{technique.name}_{f.name}"
        assert getattr(BAKE_DEFAULTS, key) == getattr(options, f.name)
        assert f"--{key.replace('_', '-')}" in flags, key
        # a TOML key sets the technique's field
        value = getattr(options, f.name)
        if isinstance(value, bool) or value is None:
            continue
        other = BakeOptions().merged({key: value})
        assert getattr(other.technique_options(technique.name), f.name) == value
    assert STAGE_VERSIONS[technique.name] == technique.stage_version


@pytest.mark.parametrize("technique", TECHNIQUES, ids=NAMES)
def test_bakes_exports_reads_back_and_verifies(technique, ball, tmp_path):
    options = BakeOptions(material="marble", scale_mm=1.0, techniques=(technique.name,), atlas_resolution=128)
    result = bake_asset(ball, options, tmp_path / "ball", StageCache(None))
    report = result.report
    glb, usdc = tmp_path / "ball.glb", tmp_path / "ball.usdc"
    assert len(report[technique.name]) == 1
    assert report["stages"][technique.name]["runs"] == 1
    assert report["validation"]["gltf"]["errors"] == 0 and report["validation"]["usd"]["errors"] == 0
    for other in NAMES:
        assert other == technique.name or not report[other]
    # bytes per vertex as the files hold them (`footprint`): the same in both formats, and all of it
    # counted: lpv's grid and screen's tables too, not only attributes
    used = footprint(inspect_glb(glb))["techniques"][technique.name]
    assert used == footprint(inspect_usdc(usdc))["techniques"][technique.name]
    assert used["total"] == pytest.approx(used["attributes"] + used["tables"]) and used["total"] > 0

    from_glb, from_usd = technique.read(glb), technique.read_usd(usdc)
    assert len(from_glb) == len(from_usd) == 1
    assert_same(next(iter(from_glb.values())), next(iter(from_usd.values())))

    figures = verify_file(glb, technique.name, size=96, frames=1, out_dir=tmp_path)
    assert figures["technique"] == technique.name and figures["bytes_per_vertex"] == used["total"]
    bad = [(where, v) for where, v in finite_numbers(figures) if not math.isfinite(v)]
    assert bad == []
    assert 0 <= figures["rmse_object"] < 1 and figures["frame_ms_sss"] > 0
