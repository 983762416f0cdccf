"""sssbake as a user gets it: a wheel built from the tree's files, installed with its dependencies in a
fresh venv outside the checkout, and used from a folder outside it: it carries its run-time files
(shaders, schema, page, three.js, the three.js runtime, the material data), bakes a sample, inspects,
verifies and serves it with `sssbake view`, and finds the validator only where it is documented to.

Slow (a venv, ~40 dependencies from pip's index and cache, numba compiling in a fresh install):
minutes, most of them pip's and the first bake's."""

import json
import os
import re
import select
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

from module_graph import fetch, page_modules
from sssbake.exporters.gltf_validator import ENV_VAR, VALIDATOR_VERSION

REPO = Path(__file__).resolve().parents[2]
SAMPLE = REPO / "samples" / "sphere.obj"
#: Run-time files the wheel must carry: (folder in the checkout, glob). Installed under ``sssbake/``.
RUN_TIME_FILES = [
    ("runtime_shaders", "*.glsl"), ("runtime_shaders", "*.vert"), ("runtime_shaders", "*.frag"),
    ("exporters/schema", "*.json"), ("exporters/schema", "*.md"), ("exporters", "gltf_validate.mjs"),
    ("pipeline/view/page", "*.html"), ("pipeline/view/page", "*.js"),
    ("pipeline/view/three", "**/*"),
    ("runtime_three", "*.js"), ("runtime_three", "*.mjs"),
    ("pipeline/core/data", "*.json"), ("pipeline/core/data", "*.npz"),
]


def _run(args: list, cwd: Path, env: dict, timeout: float = 1800) -> subprocess.CompletedProcess:
    """Run `args`; its output in the assertion when it fails."""
    proc = subprocess.run([str(a) for a in args], cwd=cwd, env=env, capture_output=True, text=True, timeout=timeout)
    assert proc.returncode == 0, f"{args[:3]} exit {proc.returncode}:\n{proc.stdout[-3000:]}\n{proc.stderr[-3000:]}"
    return proc


def _tree_files() -> list[str]:
    """The checkout's files as a commit would hold them: tracked or new, not ignored (no
    node_modules, no build/ of an earlier build), present on disk."""
    out = subprocess.run(["git", "ls-files", "-z", "--cached", "--others", "--exclude-standard"], cwd=REPO,
                         capture_output=True, check=True).stdout
    return [name for name in os.fsdecode(out).split("\0") if name and (REPO / name).is_file()]


@pytest.fixture(scope="module")
def installed(tmp_path_factory):
    """(the wheel, the venv, a working folder outside the checkout, the environment its commands run in)."""
    root = tmp_path_factory.mktemp("wheel")
    assert not root.resolve().is_relative_to(REPO.resolve())
    # a copy of the tree's files: setuptools' build/ in the checkout could hold files since deleted
    src = root / "src"
    for name in _tree_files():
        (src / name).parent.mkdir(parents=True, exist_ok=True)
        (src / name).write_bytes((REPO / name).read_bytes())
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PYTHONHOME", "VIRTUAL_ENV", ENV_VAR)}
    venv = root / "venv"
    _run([sys.executable, "-m", "venv", venv], root, env)
    python = venv / "bin" / "python"
    pip = [python, "-m", "pip", "--disable-pip-version-check", "-q"]
    # pyproject's backend: venv's bundled setuptools predates its >= 68 and has no bdist_wheel of its own
    _run([*pip, "install", "setuptools>=70.1"], root, env)
    _run([*pip, "wheel", "--no-deps", "--no-build-isolation", "-w", root / "dist", src], root, env)
    (wheel,) = (root / "dist").glob("sssbake-*.whl")
    _run([*pip, "install", wheel], root, env)  # with its dependencies, not the physics extra
    work = root / "work"
    work.mkdir()
    env.update(PATH=f"{venv / 'bin'}{os.pathsep}{env.get('PATH', '')}", XDG_DATA_HOME=str(root / "data"))
    return wheel, venv, work, env


def test_the_wheel_carries_its_run_time_files(installed):
    wheel = zipfile.ZipFile(installed[0])
    names = set(wheel.namelist())
    for folder, pattern in RUN_TIME_FILES:
        files = [p for p in (REPO / folder).glob(pattern) if p.is_file() and "__pycache__" not in p.parts]
        assert files, f"{folder}/{pattern}: nothing in the checkout"
        for path in files:
            name = "sssbake/" + path.relative_to(REPO).as_posix()
            assert name in names, f"{name} is not in the wheel"
            assert wheel.read(name) == path.read_bytes(), name
    assert not [n for n in names if "node_modules" in n or n.startswith(("tests/", "samples/"))]


def test_bake_inspect_verify_and_view_outside_the_checkout(installed):
    _, venv, work, env = installed
    sssbake = venv / "bin" / "sssbake"
    site = _run([venv / "bin" / "python", "-c", "import sssbake.pipeline; print(sssbake.pipeline.__file__)"],
                work, env).stdout.strip()
    assert Path(site).is_relative_to(venv), site  # the wheel's package, not the checkout's

    # no validator beside the package, in the working folder or the per-user folder: the bake says so
    bake = [sssbake, "bake", SAMPLE, "-o", "out", "--scale-mm", "1", "--techniques", "prt", "-q"]
    baked = _run(bake, work, env)
    (warning,) = [line for line in baked.stderr.splitlines() if line.startswith("warning:")]
    assert warning.startswith(f"warning: glTF validation skipped for 1 of 1 asset(s), first {SAMPLE}: the npm "
                              "package gltf-validator was not found (looked in "), warning
    assert f"run `sssbake doctor --install-validator` (npm installs gltf-validator@{VALIDATOR_VERSION}" in warning
    report = json.loads((work / "out" / "sphere.report.json").read_text())
    assert report["validation"]["gltf"]["validator_missing"] is True
    assert report["validation"]["gltf"]["skipped"].startswith("the npm package gltf-validator was not found")

    checkout_validator = REPO / "node_modules" / "gltf-validator"
    if checkout_validator.is_dir():
        # where `sssbake doctor --install-validator` puts it (linked: npm's registry is not asked here)
        user = Path(env["XDG_DATA_HOME"]) / "sssbake" / "node_modules"
        user.mkdir(parents=True)
        (user / "gltf-validator").symlink_to(checkout_validator)
        doctor = _run([sssbake, "doctor"], work, env).stdout.splitlines()
        validator_line = f"ok       Khronos glTF-Validator (checks every glTF file a bake writes): {VALIDATOR_VERSION}"
        assert f"{validator_line} in {user}" in doctor, doctor
        assert any(line.startswith("ok       three.js, vendored") and str(venv) in line for line in doctor), doctor
        rebaked = _run(bake, work, env)  # the unvalidated outputs are not up to date now: baked and validated
        assert "warning:" not in rebaked.stderr
        gltf = json.loads((work / "out" / "sphere.report.json").read_text())["validation"]["gltf"]
        assert (gltf["errors"], gltf["warnings"]) == (0, 0) and "skipped" not in gltf

    glb = work / "out" / "sphere.glb"
    inspected = _run([sssbake, "inspect", glb], work, env).stdout
    assert inspected.startswith(f"{glb}: sssbake schema 2.") and "\n  prt " in inspected, inspected
    verified = _run([sssbake, "verify", glb], work, env).stdout
    assert re.search(r"\(prt, light .*\): RMSE image \d", verified), verified

    view = subprocess.Popen([sssbake, "view", glb, "--port", "0", "--no-open"], cwd=work, env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        # the URL line, or the process ending: a view that hangs before printing fails here, not the session
        assert select.select([view.stdout], [], [], 120)[0], "view printed nothing in 120 s"
        line = view.stdout.readline()
        url = re.search(r"http://127\.0\.0\.1:\d+/", line)
        assert url, f"view printed {line!r}: {view.stderr.read() if view.poll() is not None else ''}"
        modules = page_modules(url.group(0))
        assert fetch(url.group(0) + "model.glb") == glb.read_bytes()
    finally:
        view.kill()
        view.wait()
    three = Path(site).parent / "view" / "three"  # the installed package's vendored copy
    served = {u.removeprefix(url.group(0)): body for u, body in modules.items()}
    assert {"three/build/three.module.js", "three/build/three.core.js", "three/examples/jsm/loaders/GLTFLoader.js",
            "runtime_three/sssbake-three.js", "viewer.js"} <= set(served)
    for path, body in served.items():
        if path.startswith("three/"):
            assert body == (three / path.removeprefix("three/")).read_bytes(), path
