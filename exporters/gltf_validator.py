"""The Khronos glTF-Validator (npm package ``gltf-validator``), run through node in a subprocess.

The package is looked for in, in order: the folder named by ``SSSBAKE_GLTF_VALIDATOR`` (a
``node_modules`` folder), the checkout's and the working directory's ``node_modules``, the per-user
folder ``$XDG_DATA_HOME/sssbake/node_modules`` (`USER_FOLDER` under ``~/.local/share`` when
``XDG_DATA_HOME`` is unset), and ``npm root -g``. ``sssbake doctor --install-validator`` installs
`VALIDATOR_VERSION` into the per-user folder, where an installed wheel finds it; in a checkout,
``npm ci`` installs the version ``package-lock.json`` pins, the same one.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import tempfile
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from functools import cache
from pathlib import Path

from sssbake.pipeline.core.errors import AssetError, SssbakeError

ENV_VAR = "SSSBAKE_GLTF_VALIDATOR"
#: The per-user ``node_modules`` folder, under ``$XDG_DATA_HOME`` (default ``~/.local/share``): where
#: ``sssbake doctor --install-validator`` installs the validator (`user_folder`).
USER_FOLDER = Path("sssbake", "node_modules")
#: The gltf-validator that ``sssbake doctor --install-validator`` installs: package-lock.json's pin
#: (tests/exporters/test_gltf_validator.py holds them equal).
VALIDATOR_VERSION = "2.0.0-dev.3.10"
_SCRIPT = Path(__file__).with_name("gltf_validate.mjs")
SEVERITIES = ("Error", "Warning", "Information", "Hint")
_ERROR_LINE = re.compile(r"[A-Za-z]*Error\b")  # "RangeError: Maximum call stack size exceeded"


#: Deepest node hierarchy handed to the validator. It recurses once per level: it runs out of node's
#: stack between 5,000 and 8,000 levels, and its time grows with the square of the depth (3 s at 3,000
#: levels; 190 s at 20,000 with a larger stack), where glTF itself sets no limit.
MAX_NODE_DEPTH = 1000


class ValidatorUnavailable(SssbakeError, RuntimeError):
    """node or the gltf-validator package is missing, or (`ValidatorLimit`) it cannot check this input."""


class ValidatorLimit(ValidatorUnavailable):
    """An input's node hierarchy is deeper than the validator checks (`MAX_NODE_DEPTH`)."""


@dataclass(frozen=True)
class ValidationMessage:
    """One issue the validator reported.

    Attributes
    ----------
    code : str
        e.g. ``"UNSUPPORTED_EXTENSION"``.
    severity : str
        ``"Error"``, ``"Warning"``, ``"Information"`` or ``"Hint"``.
    pointer : str
        JSON pointer into the asset, ``""`` when the issue has none.
    message : str
    """

    code: str
    severity: str
    pointer: str
    message: str

    def to_json(self) -> dict:
        """The message in the validator's own key names."""
        return {"code": self.code, "severity": self.severity, "pointer": self.pointer, "message": self.message}


@dataclass(frozen=True)
class ValidationReport:
    """The validator's verdict on one file.

    Attributes
    ----------
    uri : str
        The file validated (``"<bytes>"`` for in-memory data).
    num_errors, num_warnings, num_infos, num_hints : int
    messages : tuple of ValidationMessage
    validator_version : str
    """

    uri: str
    num_errors: int
    num_warnings: int
    num_infos: int
    num_hints: int
    messages: tuple[ValidationMessage, ...] = field(default=())
    validator_version: str = ""

    @property
    def ok(self) -> bool:
        """No errors and no warnings (infos and hints are fine)."""
        return self.num_errors == 0 and self.num_warnings == 0

    def codes(self, severity: str | None = None) -> list[str]:
        """Issue codes, optionally only those of one severity (``"Error"``, ...)."""
        return [m.code for m in self.messages if severity is None or m.severity == severity]

    def to_json(self) -> dict:
        """The report in the validator's own key names, for ``.report.json``."""
        return {
            "uri": self.uri,
            "validatorVersion": self.validator_version,
            "numErrors": self.num_errors,
            "numWarnings": self.num_warnings,
            "numInfos": self.num_infos,
            "numHints": self.num_hints,
            "messages": [m.to_json() for m in self.messages],
        }


def validate_glb(path_or_bytes: str | os.PathLike | bytes) -> ValidationReport:
    """Validate one .glb/.gltf file, or GLB/glTF bytes.

    Raises
    ------
    ValidatorUnavailable
        node or the gltf-validator package cannot be found.
    RuntimeError
        The validator could not read the input at all (not glTF, not GLB).
    """
    return validate_many([path_or_bytes])[0]


def validate_many(items: Sequence[str | os.PathLike | bytes], timeout: float = 300.0) -> list[ValidationReport]:
    """Validate several files and/or byte strings with one node process (node starts slowly)."""
    modules = find_validator()
    with tempfile.TemporaryDirectory(prefix="sssbake-validate-") as tmp:
        paths, uris = [], []
        for k, item in enumerate(items):
            if isinstance(item, (bytes, bytearray, memoryview)):
                p = Path(tmp, f"{k}.glb" if bytes(item[:4]) == b"glTF" else f"{k}.gltf")
                p.write_bytes(item)
                paths.append(str(p))
                uris.append("<bytes>")
            else:
                paths.append(str(Path(item).resolve()))
                uris.append(str(item))
        if not paths:
            return []
        for path, uri in zip(paths, uris):
            depth = node_depth(path)
            if depth > MAX_NODE_DEPTH:
                raise ValidatorLimit(f"{Path(uri).name}: a node hierarchy {depth} levels deep, past the "
                                     f"{MAX_NODE_DEPTH} that gltf-validator checks (it recurses per level, in time "
                                     "growing with its square)")
        proc = subprocess.run(
            [_node(), str(_SCRIPT), str(modules), *(os.fsencode(p).hex() for p in paths)],
            capture_output=True, text=True, timeout=timeout,
        )
    if proc.returncode != 0:  # node's first stderr lines are a source excerpt: the error's own line says why
        lines = proc.stderr.strip().splitlines() or [""]
        why = next((line for line in lines if _ERROR_LINE.match(line)), lines[0])
        raise RuntimeError(f"gltf-validator failed (exit {proc.returncode}): {why}")
    return [_report(raw, uri) for raw, uri in zip(json.loads(proc.stdout), uris)]


def node_depth(path: str | os.PathLike) -> int:
    """Levels of the deepest node hierarchy in a glTF file (0 without nodes, or for a file sssbake's
    reader refuses: the validator says what is wrong with it)."""
    from sssbake.pipeline.mesh.load_gltf import read_gltf_file

    try:
        nodes = read_gltf_file(path).gltf.nodes
    except AssetError:
        return 0
    children = [[c for c in node.get("children") or () if isinstance(c, int) and 0 <= c < len(nodes)]
                for node in nodes]
    below = {c for kids in children for c in kids}
    stack, seen, deepest = [(i, 1) for i in range(len(nodes)) if i not in below], set(), 0
    while stack:  # a stack, not recursion: the depth is what is being measured
        i, depth = stack.pop()
        if i not in seen:
            seen.add(i)
            deepest = max(deepest, depth)
            stack.extend((c, depth + 1) for c in children[i])
    return deepest


def find_validator() -> Path:
    """The ``node_modules`` folder that holds ``gltf-validator``.

    Raises
    ------
    ValidatorUnavailable
    """
    looked = []
    for folder in _validator_folders():
        if (folder / "gltf-validator" / "package.json").is_file():
            return folder
        looked.append(str(folder))
    raise ValidatorUnavailable(f"the npm package gltf-validator was not found (looked in {', '.join(looked)}); "
                               f"{_install_hint()}")


def validator_available() -> bool:
    """Whether a validation would start here: node and the gltf-validator package both found."""
    try:
        find_validator()
        _node()
    except ValidatorUnavailable:
        return False
    return True


def user_folder() -> Path:
    """The per-user ``node_modules`` folder: `USER_FOLDER` under ``$XDG_DATA_HOME``, or under
    ``~/.local/share`` where that is unset or relative (the XDG spec ignores a relative one)."""
    base = os.environ.get("XDG_DATA_HOME", "")
    return (Path(base) if os.path.isabs(base) else Path.home() / ".local" / "share") / USER_FOLDER


def _install_hint() -> str:
    return (f"run `sssbake doctor --install-validator` (npm installs gltf-validator@{VALIDATOR_VERSION} in "
            f"{user_folder()}), or set {ENV_VAR} to a node_modules folder that holds it")


def _validator_folders() -> Iterator[Path]:
    """Where the validator may be, in order: ``$SSSBAKE_GLTF_VALIDATOR``, the checkout's and the
    working folder's ``node_modules``, the per-user folder, npm's global root. The last is asked
    only when the others fail: ``npm root -g`` is a node process, ~0.15 s of every bake that a local
    install spares."""
    env = os.environ.get(ENV_VAR)
    if env:
        yield Path(env)
    yield Path(__file__).resolve().parents[1] / "node_modules"
    yield Path.cwd() / "node_modules"
    yield user_folder()
    global_root = _npm_root_global()
    if global_root:
        yield global_root


def _node() -> str:
    node = shutil.which("node")
    if node is None:
        raise ValidatorUnavailable("node (Node.js) is not installed: install Node.js and npm (Debian: apt-get install "
                                   f"nodejs npm), then {_install_hint()}")
    return node


@cache
def _npm_root_global() -> Path | None:
    npm = shutil.which("npm")
    if npm is None:
        return None
    try:
        out = subprocess.run([npm, "root", "-g"], capture_output=True, text=True, timeout=30, check=True)
    except (subprocess.SubprocessError, OSError):
        return None
    return Path(out.stdout.strip()) if out.stdout.strip() else None


def _report(raw: dict, uri: str) -> ValidationReport:
    if "error" in raw:
        raise RuntimeError(f"gltf-validator could not validate {uri}: {raw['error']}")
    issues = raw["issues"]
    messages = tuple(
        ValidationMessage(
            code=m["code"],
            severity=SEVERITIES[m["severity"]],
            pointer=m.get("pointer", ""),
            message=m["message"],
        )
        for m in issues["messages"]
    )
    return ValidationReport(
        uri=uri,
        num_errors=issues["numErrors"],
        num_warnings=issues["numWarnings"],
        num_infos=issues["numInfos"],
        num_hints=issues["numHints"],
        messages=messages,
        validator_version=raw.get("validatorVersion", ""),
    )
