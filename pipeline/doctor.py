"""``sssbake doctor``: which of sssbake's run-time parts outside Python this machine has, each as ok
or missing with the command that fixes it; ``--install-validator`` installs the Khronos validator
into the per-user folder (`sssbake.exporters.gltf_validator.user_folder`).

Each probe that loads a native library (EGL through moderngl, Mitsuba with its libLLVM) runs in a
child Python: a driver or an LLVM that aborts its process then fails one line, not the doctor.
"""

from __future__ import annotations

import importlib.metadata
import importlib.util
import os
import shutil
import subprocess
import sys
from dataclasses import dataclass

from sssbake.pipeline.core.errors import SssbakeError

#: Seconds a probe's child may take (a cold import of Mitsuba and Dr.Jit is the slowest, ~3 s).
PROBE_TIMEOUT_S = 120
#: Chromium's names on PATH, as the browser tests look for it (tests/browser.py).
CHROMIUM_NAMES = ("chromium", "chromium-browser", "google-chrome")
#: Debian's packages for headless GL (.ci/setup installs the same).
EGL_PACKAGES = "libegl1 libegl-mesa0 libgl1-mesa-dri libgles2 libglvnd0 libgl1"

_EGL_PROBE = ("import moderngl\n"
              "ctx = moderngl.create_standalone_context(backend='egl')\n"
              "print(ctx.info['GL_RENDERER'] + ', OpenGL ' + ctx.info['GL_VERSION'])\n"
              "ctx.release()\n")
_MITSUBA_PROBE = ("import os\n"
                  "from sssbake.pipeline.verify.volpath import VARIANT, load_mitsuba\n"
                  "mi = load_mitsuba()\n"
                  "print(f\"Mitsuba {mi.__version__} ({VARIANT}), libLLVM {os.environ.get('DRJIT_LIBLLVM_PATH') or "
                  "'as Dr.Jit finds it'}\")\n")


class DoctorError(SssbakeError):
    """``--install-validator`` could not install it: no npm, or npm failed (its last line)."""


@dataclass(frozen=True)
class Check:
    """One run-time part and whether this machine has it.

    Attributes
    ----------
    part : str
        What it is, e.g. ``"Node.js"``.
    needed_for : str
        What in sssbake uses it.
    required : bool
        False for parts only an optional command needs; ``sssbake doctor`` exits 1 when a required
        one is missing.
    ok : bool
    detail : str
        Where it was found and its version, or why it is missing (one line).
    fix : str
        The command that installs it; ``""`` when ok.
    """

    part: str
    needed_for: str
    required: bool
    ok: bool
    detail: str
    fix: str = ""

    def line(self) -> str:
        """The check as the command prints it: one line."""
        status = "ok" if self.ok else "missing"
        kind = "" if self.required else "optional, "
        text = f"{status:<8} {self.part} ({kind}{self.needed_for}): {self.detail}"
        return text if self.ok else f"{text}; fix: {self.fix}"


def run_checks() -> list[Check]:
    """Check every run-time part: Node.js, the Khronos glTF-Validator, the vendored three.js,
    headless EGL through moderngl, Chromium and Mitsuba with its libLLVM (the last two optional).

    Returns
    -------
    list of Check
        In that order.
    """
    node = _check_node()
    return [node, _check_validator(node.ok), _check_three(), _check_egl(), _check_chromium(), _check_mitsuba()]


def install_validator() -> str:
    """Install `VALIDATOR_VERSION` of gltf-validator into the per-user folder with npm.

    Returns
    -------
    str
        One line saying what was installed where.

    Raises
    ------
    DoctorError
        npm is not on PATH, or it failed.
    """
    from sssbake.exporters.gltf_validator import VALIDATOR_VERSION, user_folder

    npm = shutil.which("npm")
    if npm is None:
        raise DoctorError("npm not found: install Node.js and npm (apt-get install nodejs npm), then run "
                          "sssbake doctor --install-validator again")
    prefix = user_folder().parent  # npm installs into <prefix>/node_modules
    prefix.mkdir(parents=True, exist_ok=True)
    package = f"gltf-validator@{VALIDATOR_VERSION}"
    try:
        proc = subprocess.run([npm, "install", "--prefix", str(prefix), package, "--no-audit", "--no-fund", "--silent"],
                              capture_output=True, text=True, timeout=600)
    except subprocess.TimeoutExpired:
        raise DoctorError(f"npm install {package} took over 600 s (is the npm registry reachable?)") from None
    if proc.returncode != 0:
        lines = [line for line in (proc.stderr + proc.stdout).splitlines() if line.strip()] or [""]
        raise DoctorError(f"npm install --prefix {prefix} {package} failed (exit {proc.returncode}): "
                          f"{lines[-1].strip()}")
    return f"installed {package} in {user_folder()}"


def _probe(code: str) -> tuple[bool, str]:
    """Run `code` in a child of this Python: (whether it succeeded, its last stdout line or the
    last line of its error)."""
    try:
        proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=PROBE_TIMEOUT_S)
    except subprocess.TimeoutExpired:
        return False, f"did not finish in {PROBE_TIMEOUT_S} s"
    if proc.returncode < 0:
        return False, f"crashed (signal {-proc.returncode})"
    out = [line.strip() for line in (proc.stdout if proc.returncode == 0 else proc.stderr).splitlines() if line.strip()]
    return proc.returncode == 0, out[-1] if out else f"exit {proc.returncode}"


def _check_node() -> Check:
    needed_for = "runs the glTF validator"
    node = shutil.which("node")
    if node is None:
        return Check("Node.js", needed_for, True, False, "node not found on PATH", "apt-get install nodejs npm")
    try:
        version = subprocess.run([node, "--version"], capture_output=True, text=True, timeout=30).stdout.strip()
    except (subprocess.SubprocessError, OSError) as e:
        return Check("Node.js", needed_for, True, False, f"{node} does not run ({e})", "apt-get install nodejs npm")
    return Check("Node.js", needed_for, True, True, f"{version} at {node}")


def _check_validator(have_node: bool) -> Check:
    """Found and, where node is there, run once on a minimal glTF: ok means a bake validates."""
    from sssbake.exporters.gltf_validator import VALIDATOR_VERSION, ValidatorUnavailable, find_validator, validate_glb

    needed_for, fix = "checks every glTF file a bake writes", "sssbake doctor --install-validator"
    try:
        folder = find_validator()
    except ValidatorUnavailable as e:
        return Check("Khronos glTF-Validator", needed_for, True, False, str(e).split(";")[0], fix)
    if not have_node:  # its package is there; the Node.js line says what is missing
        return Check("Khronos glTF-Validator", needed_for, True, True, f"in {folder} (not run: no Node.js)")
    try:
        version = validate_glb(b'{"asset": {"version": "2.0"}}').validator_version
    except (RuntimeError, OSError, subprocess.SubprocessError) as e:
        return Check("Khronos glTF-Validator", needed_for, True, False,
                     f"in {folder} but does not run: {str(e).splitlines()[0] if str(e) else type(e).__name__}", fix)
    tested = "" if version == VALIDATOR_VERSION else f" (sssbake is tested with {VALIDATOR_VERSION}: {fix})"
    return Check("Khronos glTF-Validator", needed_for, True, True, f"{version} in {folder}{tested}")


def _check_three() -> Check:
    from sssbake.pipeline.view.serve import THREE, ViewError, served_folders

    needed_for, fix = "sssbake view's page", f"{sys.executable} -m pip install --force-reinstall sssbake"
    try:
        served_folders()
        version = (THREE / "VERSION").read_text().strip()
    except (ViewError, OSError) as e:
        return Check("three.js, vendored", needed_for, True, False, str(e).split(";")[0], fix)
    return Check("three.js, vendored", needed_for, True, True, f"{version} in {THREE}")


def _check_egl() -> Check:
    needed_for = "the planner's pilot, verify and tradeoff render with the shipped GLSL"
    ok, said = _probe(_EGL_PROBE)
    if ok:
        return Check("headless EGL (moderngl)", needed_for, True, True, said)
    return Check("headless EGL (moderngl)", needed_for, True, False, f"no EGL context: {said}",
                 f"apt-get install {EGL_PACKAGES}")


def _check_chromium() -> Check:
    needed_for = "the report's and the viewer's headless screenshot tests"
    found = next((path for path in map(shutil.which, CHROMIUM_NAMES) if path), None)
    if found is None:
        return Check("Chromium", needed_for, False, False, f"none of {', '.join(CHROMIUM_NAMES)} on PATH",
                     "apt-get install chromium")
    return Check("Chromium", needed_for, False, True, f"at {found}")


def _check_mitsuba() -> Check:
    from sssbake.pipeline.verify.volpath import DEBIAN_LIBLLVM

    needed_for = "verify --reference volpath"
    if importlib.util.find_spec("mitsuba") is None or importlib.util.find_spec("drjit") is None:
        return Check("Mitsuba 3 + libLLVM 19", needed_for, False, False, "the Python packages mitsuba and drjit are "
                     "not installed", f"{sys.executable} -m pip install {' '.join(_physics_requirements())}")
    ok, said = _probe(_MITSUBA_PROBE)
    if ok:
        return Check("Mitsuba 3 + libLLVM 19", needed_for, False, True, said)
    # Dr.Jit reports a missing or unusable libLLVM as its import failing
    no_llvm = "DRJIT_LIBLLVM_PATH" not in os.environ and not os.path.isfile(DEBIAN_LIBLLVM)
    return Check("Mitsuba 3 + libLLVM 19", needed_for, False, False, said,
                 "apt-get install libllvm19" if no_llvm else
                 f"{sys.executable} -m pip install --force-reinstall {' '.join(_physics_requirements())}")


def _physics_requirements() -> list[str]:
    """The ``physics`` extra's requirements as this install declares them, quoted for a shell."""
    requires = importlib.metadata.requires("sssbake") or []
    return [f"'{r.split(';')[0].strip()}'" for r in requires if "extra == \"physics\"" in r.replace("'", '"')]
