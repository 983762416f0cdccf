"""`sssbake doctor`: each run-time part ok or missing with its fix, the exit status, and
`--install-validator` into the per-user folder."""

import json
import os
import shutil
import sys
from pathlib import Path

import pytest

from sssbake.exporters import gltf_validator
from sssbake.pipeline import doctor
from sssbake.pipeline.cli import main
from sssbake.pipeline.view.serve import THREE

REPO = Path(__file__).resolve().parents[1]
CHECKOUT_VALIDATOR = REPO / "node_modules" / "gltf-validator"
NODE = shutil.which("node")  # before `bare` empties PATH


@pytest.fixture
def bare(tmp_path, monkeypatch):
    """A machine as an installed wheel sees it: PATH holds only `tmp_path/bin` (no node, npm or
    Chromium), no validator beside the package, in the working folder or the per-user folder."""
    (tmp_path / "bin").mkdir()
    monkeypatch.setenv("PATH", str(tmp_path / "bin"))
    monkeypatch.delenv(gltf_validator.ENV_VAR, raising=False)
    monkeypatch.setenv("XDG_DATA_HOME", str(tmp_path / "data"))
    monkeypatch.setattr(gltf_validator, "__file__", str(tmp_path / "site-packages" / "sssbake" / "exporters" / "x.py"))
    monkeypatch.chdir(tmp_path)
    return tmp_path


def test_parts_missing_each_with_its_fix_and_exit_1(bare, capsys):
    assert main(["doctor"]) == 1
    lines = capsys.readouterr().out.splitlines()
    assert len(lines) == 7
    by_part = {c.part: c for c in doctor.run_checks()}
    assert lines[:6] == [c.line() for c in by_part.values()]
    node = by_part["Node.js"]
    assert (node.ok, node.required, node.detail, node.fix) == (False, True, "node not found on PATH",
                                                               "apt-get install nodejs npm")
    validator = by_part["Khronos glTF-Validator"]
    assert (validator.ok, validator.fix) == (False, "sssbake doctor --install-validator")
    assert str(bare / "data" / "sssbake" / "node_modules") in validator.detail
    assert lines[1] == (f"missing  Khronos glTF-Validator (checks every glTF file a bake writes): {validator.detail}; "
                        "fix: sssbake doctor --install-validator")
    chromium = by_part["Chromium"]
    assert (chromium.ok, chromium.required, chromium.fix) == (False, False, "apt-get install chromium")
    three = by_part["three.js, vendored"]
    assert (three.ok, three.detail) == (True, f"{(THREE / 'VERSION').read_text().strip()} in {THREE}")
    assert by_part["headless EGL (moderngl)"].ok, by_part["headless EGL (moderngl)"].detail  # needs no PATH
    assert not by_part["Mitsuba 3 + libLLVM 19"].required
    assert lines[6] == "2 required part(s) missing: Node.js, Khronos glTF-Validator"


@pytest.mark.parametrize("probe, detail", [
    ("raise SystemExit('EGL: no display found')", "no EGL context: EGL: no display found"),
    ("import os; os.abort()", "no EGL context: crashed (signal 6)"),
])
def test_a_failing_gl_probe_is_one_line_with_the_fix(monkeypatch, probe, detail):
    monkeypatch.setattr(doctor, "_EGL_PROBE", probe)
    check = doctor._check_egl()
    assert (check.ok, check.detail, check.fix) == (False, detail, f"apt-get install {doctor.EGL_PACKAGES}")


def test_install_validator_without_npm_is_one_line(bare, capsys):
    assert main(["doctor", "--install-validator"]) == 1
    captured = capsys.readouterr()
    assert captured.out == ""
    assert captured.err == ("error: npm not found: install Node.js and npm (apt-get install nodejs npm), then run "
                            "sssbake doctor --install-validator again\n")


def _fake_npm(bin_folder: Path, body: str) -> Path:
    """An `npm` on PATH that writes its arguments to npm-args.json beside it, then runs `body`
    (Python, with `args` and `prefix`, the folder after --prefix)."""
    npm = bin_folder / "npm"
    npm.write_text(f"#!{sys.executable}\nimport json, os, sys\nfrom pathlib import Path\nargs = sys.argv[1:]\n"
                   f"Path({str(bin_folder / 'npm-args.json')!r}).write_text(json.dumps(args))\n"
                   "prefix = Path(args[args.index('--prefix') + 1])\n" + body)
    npm.chmod(0o755)
    return bin_folder / "npm-args.json"


@pytest.mark.skipif(not CHECKOUT_VALIDATOR.is_dir() or NODE is None,
                    reason="needs node and node_modules/gltf-validator (npm ci) for the installed package")
def test_install_validator_installs_into_the_user_folder_and_rechecks(bare, capsys):
    os.symlink(NODE, bare / "bin" / "node")
    # npm's work here: the checkout's copy linked where `npm install --prefix` puts the package
    args_file = _fake_npm(bare / "bin", "(prefix / 'node_modules').mkdir(parents=True)\n"
                                        "(prefix / 'node_modules' / 'gltf-validator')"
                                        f".symlink_to({str(CHECKOUT_VALIDATOR)!r})\n")
    main(["doctor", "--install-validator"])
    out = capsys.readouterr().out.splitlines()
    folder = bare / "data" / "sssbake" / "node_modules"
    version = gltf_validator.VALIDATOR_VERSION
    assert json.loads(args_file.read_text()) == ["install", "--prefix", str(folder.parent), f"gltf-validator@{version}",
                                                 "--no-audit", "--no-fund", "--silent"]
    assert out[0] == f"installed gltf-validator@{version} in {folder}"
    # the recheck ran the installed validator: its own version, from the per-user folder
    assert out[2] == f"ok       Khronos glTF-Validator (checks every glTF file a bake writes): {version} in {folder}"


def test_a_failing_npm_is_one_line(bare, capsys):
    _fake_npm(bare / "bin", "print('npm ERR! code E404', file=sys.stderr)\n"
                            "print('npm ERR! 404 Not Found - GET https://registry.npmjs.org/gltf-validator', "
                            "file=sys.stderr)\nsys.exit(1)\n")
    assert main(["doctor", "--install-validator"]) == 1
    err = capsys.readouterr().err
    assert err == (f"error: npm install --prefix {bare / 'data' / 'sssbake'} gltf-validator@"
                   f"{gltf_validator.VALIDATOR_VERSION} failed (exit 1): npm ERR! 404 Not Found - GET "
                   "https://registry.npmjs.org/gltf-validator\n")
