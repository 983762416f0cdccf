"""A sixth technique from outside the package (tests/toy_technique/: its files, named in
``SSSBAKE_TECHNIQUES``; built in, it would be one line in `registry.ENTRIES`) bakes in the batch's
worker processes, verifies, and gets its own option, flag and report block."""

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import trimesh

from sssbake.pipeline.core.profile import profile_for, profile_total
from sssbake.pipeline.core.materials import Material, preset

TESTS = Path(__file__).resolve().parents[1]


def _sssbake(*args, plugins: str = "toy_technique.technique:Toy") -> subprocess.CompletedProcess:
    env = {**os.environ, "SSSBAKE_TECHNIQUES": plugins,
           "PYTHONPATH": os.pathsep.join(filter(None, [str(TESTS), os.environ.get("PYTHONPATH")]))}
    return subprocess.run([sys.executable, "-m", "sssbake.pipeline.cli", *map(str, args)], capture_output=True,
                          text=True, timeout=600, env=env)


def test_toy_technique_bakes_and_verifies(tmp_path):
    trimesh.creation.icosphere(subdivisions=2, radius=5.0).export(tmp_path / "ball.obj")
    help_text = _sssbake("bake", "--help").stdout
    assert "--toy-gain" in help_text and "lpv, toy;" in help_text

    baked = _sssbake("bake", tmp_path / "ball.obj", "-o", tmp_path / "out", "--scale-mm", 1, "--techniques", "toy",
                     "--toy-gain", 0.5, "--no-cache", "-q")
    assert baked.returncode == 0, baked.stderr
    report = json.loads((tmp_path / "out" / "ball.report.json").read_text())
    (block,) = report["toy"].values()
    # the material as baked: marble with the ball's escape gain
    (record,) = [m["scattering"] for m in report["materials"].values() if m["scattering"]]
    params = profile_for(Material.from_json(record))
    assert Material.from_json(record).half_space == preset("marble")
    np.testing.assert_allclose(block["albedo"], 0.5 * profile_total(params),
                               rtol=1e-12)
    assert report["stages"]["toy"]["runs"] == 1 and report["validation"]["gltf"]["errors"] == 0

    verified = _sssbake("verify", tmp_path / "out" / "ball.glb", "--technique", "toy", "--size", 64, "--frames", 1,
                        "--json")
    assert verified.returncode == 0, verified.stderr
    figures = json.loads(verified.stdout)
    # Lambert with an albedo is not scattering: no closer to the reference than best-fit Lambert
    assert np.isfinite(figures["rmse_object"]) and figures["rmse_object"] >= figures["rmse_object_lambert"]

    refused = _sssbake("bake", tmp_path / "ball.obj", "-o", tmp_path / "bad", "--scale-mm", 1, "--techniques", "toy",
                       "--toy-gain", 0, "-q")
    assert refused.returncode != 0 and "toy_gain must be in (0, 10], got 0.0" in refused.stderr


def test_a_plugin_that_does_not_load_is_named():
    done = _sssbake("presets", plugins="toy_technique.technique:Nothing")
    assert done.returncode != 0
    assert "SSSBAKE_TECHNIQUES: cannot load technique 'toy_technique.technique:Nothing'" in done.stderr
