"""A bake on a machine without node: the files are written unvalidated, the terminal says so once per
batch with the fix, each report records why under ``validation.gltf.skipped``, and once a validator
is there the next bake validates them instead of calling them up to date."""

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from sssbake.exporters.gltf_validator import VALIDATOR_VERSION, user_folder

SAMPLE = Path(__file__).resolve().parents[2] / "samples" / "sphere.obj"


def _bake(out: Path, path: str) -> subprocess.CompletedProcess:
    # a child process: the bake's fork server keeps the environment it started with, so PATH must be
    # the command's own from the start
    return subprocess.run([sys.executable, "-m", "sssbake.pipeline.cli", "bake", str(SAMPLE), "-o", str(out),
                           "--scale-mm", "1", "--techniques", "none", "-q"],
                          capture_output=True, text=True, timeout=600, env={**os.environ, "PATH": path})


@pytest.mark.skipif(shutil.which("node") is None, reason="the rebake with a validator needs node")
def test_no_node_skips_validation_says_so_and_the_next_bake_validates(tmp_path):
    (tmp_path / "bin").mkdir()
    out = tmp_path / "out"
    skipped = _bake(out, str(tmp_path / "bin"))
    assert skipped.returncode == 0, skipped.stderr
    why = ("node (Node.js) is not installed: install Node.js and npm (Debian: apt-get install nodejs npm), then run "
           f"`sssbake doctor --install-validator` (npm installs gltf-validator@{VALIDATOR_VERSION} in "
           f"{user_folder()}), or set SSSBAKE_GLTF_VALIDATOR to a node_modules folder that holds it")
    warnings = [line for line in skipped.stderr.splitlines() if line.startswith("warning:")]
    assert warnings == [f"warning: glTF validation skipped for 1 of 1 asset(s), first {SAMPLE}: {why}"]
    report = json.loads((out / "sphere.report.json").read_text())
    assert report["validation"]["gltf"] == {"skipped": why, "validator_missing": True}
    assert report["validation"]["usd"]["errors"] == 0  # USD's validator is Python's: it still ran
    assert report["warnings"] == [f"glTF validation skipped: {why}"]
    (record,) = json.loads((out / "batch.json").read_text())["assets"]
    assert (record["status"], record["validation_skipped"]) == ("ok", why)

    validated = _bake(out, os.environ["PATH"])  # node is back: not up to date, baked again and validated
    assert validated.returncode == 0, validated.stderr
    assert "warning:" not in validated.stderr
    (record,) = json.loads((out / "batch.json").read_text())["assets"]
    assert record["status"] == "ok" and "validation_skipped" not in record
    gltf = json.loads((out / "sphere.report.json").read_text())["validation"]["gltf"]
    assert (gltf["errors"], gltf["warnings"]) == (0, 0) and "skipped" not in gltf
    assert _bake(out, os.environ["PATH"]).returncode == 0
    (record,) = json.loads((out / "batch.json").read_text())["assets"]
    assert record["status"] == "up-to-date"


def test_only_a_missing_validator_makes_outputs_stale(monkeypatch):
    from sssbake.exporters import gltf_validator
    from sssbake.pipeline.bake.asset import _validator_installed_since

    looked = []
    monkeypatch.setattr(gltf_validator, "validator_available", lambda: looked.append(1) or True)
    # a hierarchy deeper than the validator checks stays so: never baked again for it
    deep = {"skipped": "x.gltf: a node hierarchy 1001 levels deep, ...", "validator_missing": False}
    assert not _validator_installed_since({"gltf": deep, "usd": {"errors": 0}})
    assert not _validator_installed_since({"gltf": {"errors": 0, "warnings": 0}, "usd": {"errors": 0}})
    assert looked == []  # validated outputs cost no lookup
    assert _validator_installed_since({"gltf": {"skipped": "no node", "validator_missing": True}}) and looked == [1]
    monkeypatch.setattr(gltf_validator, "validator_available", lambda: False)
    assert not _validator_installed_since({"gltf": {"skipped": "no node", "validator_missing": True}})
