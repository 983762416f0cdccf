"""How the screen technique's sample tables are laid out, and the stage that makes them."""

import numpy as np
import pytest

from sssbake.pipeline.core.materials import preset
from sssbake.pipeline.options import BakeOptions, check_options
from sssbake.pipeline.techniques.screen.layout import TABLES, screen_bytes, screen_samples_from_tables, screen_tables
from sssbake.pipeline.techniques.screen.samples import ScreenSamplesOptions, screen_samples
from sssbake.pipeline.techniques.screen.stage import bake_screen


def test_tables_hold_the_samples_as_float32():
    options = ScreenSamplesOptions(samples=10, uniform=3)
    samples = screen_samples(preset("marble"), options)
    tables = screen_tables(samples, options)
    assert (tables["technique"], tables["samples"], tables["uniform"], tables["driver"]) == (
        "screen", 10, 3, samples.driver)
    assert tables["uniformRadiusMm"] == samples.uniform_radius_mm
    assert tables["tableReachMm"] == samples.table_reach_mm and tables["tableError"] == samples.table_error
    assert all(tables[name].dtype == np.float32 for name in TABLES)
    assert tables["offsets"].shape == (13, 2) and tables["weights"].shape == (13,)
    assert tables["rdTable"].shape == (samples.table.shape[1], 3)
    np.testing.assert_array_equal(tables["offsets"], samples.offsets.astype(np.float32))
    np.testing.assert_array_equal(tables["weights"], samples.weights.astype(np.float32))
    np.testing.assert_array_equal(tables["rdTable"], samples.table.T.astype(np.float32))
    assert screen_bytes(tables) == {"offsets": 104, "weights": 52, "rdTable": 12 * len(tables["rdTable"]),
                                    "total": 156 + 12 * len(tables["rdTable"])}


def test_stage_report():
    options = ScreenSamplesOptions(samples=6, uniform=0, table_error=1e-2)
    baked = bake_screen(preset("skin1"), options)
    report = baked.report
    assert report["options"] == options.__dict__ and (report["samples"], report["uniform"], report["offsets"]) == (
        6, 0, 6)
    assert report["tableSize"] == len(baked.tables["rdTable"]) and report["tableError"] <= 1e-2
    assert report["bytes"] == screen_bytes(baked.tables)
    assert {"driver", "uniformRadiusMm", "tableReachMm"} <= set(report)


@pytest.mark.parametrize("field, value, needle", [
    ("screen_samples", 0, "screen: samples must be"),
    ("screen_uniform", -1, "screen: uniform must be"),
    ("screen_table_error", 0.5, "screen: table_error must be"),
])
def test_bad_options_are_one_line(field, value, needle):
    with pytest.raises(ValueError, match=needle) as err:
        check_options(BakeOptions(techniques=("screen",), **{field: value}))
    assert "\n" not in str(err.value)


def test_options_default_to_the_precompute_defaults():
    assert BakeOptions().technique_options("screen").samples_options() == ScreenSamplesOptions()


def test_samples_come_back_from_their_tables():
    options = ScreenSamplesOptions(samples=7, uniform=2)
    samples = screen_samples(preset("ketchup"), options)
    back = screen_samples_from_tables(screen_tables(samples, options))
    for name in ("offsets", "weights", "table"):
        np.testing.assert_array_equal(getattr(back, name), getattr(samples, name).astype(np.float32))
    assert (back.driver, back.uniform_radius_mm, back.table_reach_mm, back.table_error) == (
        samples.driver, samples.uniform_radius_mm, samples.table_reach_mm, samples.table_error)


@pytest.mark.parametrize("change, needle", [
    ({"weights": np.ones(3, np.float32)}, "weights"),
    ({"rdTable": np.full((8, 3), np.nan, np.float32)}, "finite"),
    ({"driver": 5}, "driver"),
    ({"tableReachMm": None}, "malformed"),
])
def test_malformed_tables_are_refused(change, needle):
    options = ScreenSamplesOptions(samples=4, uniform=1)
    tables = screen_tables(screen_samples(preset("marble"), options), options)
    with pytest.raises(ValueError, match=needle):
        screen_samples_from_tables({**tables, **change})
