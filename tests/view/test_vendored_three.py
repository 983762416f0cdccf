"""The three.js that `sssbake view` serves is vendored in the package (pipeline/view/three/): the
same bytes as npm's copy of the pinned version, and exactly the modules the page's graph loads."""

import json
import struct
from pathlib import Path

import pytest

from module_graph import page_modules, resolve, specifiers
from sssbake.pipeline.view.serve import THREE, ViewError, ViewServer, served_folders

REPO = Path(__file__).resolve().parents[2]
NPM_THREE = REPO / "node_modules" / "three"


def _vendored() -> set[str]:
    """The vendored files, as paths relative to `THREE` (its README.md aside: sssbake's own)."""
    return {p.relative_to(THREE).as_posix() for p in THREE.rglob("*") if p.is_file() and p.name != "README.md"}


def test_the_version_is_package_json_pin():
    pin = json.loads((REPO / "package.json").read_text())["dependencies"]["three"]
    locked = json.loads((REPO / "package-lock.json").read_text())["packages"]["node_modules/three"]["version"]
    assert (THREE / "VERSION").read_text().strip() == pin == locked
    licence = (THREE / "LICENSE").read_text()
    assert licence.startswith("The MIT License") and "three.js authors" in licence


@pytest.mark.skipif(not (NPM_THREE / "package.json").is_file(), reason="no node_modules/three (npm ci) to compare with")
def test_every_file_is_npm_s_bytes():
    assert json.loads((NPM_THREE / "package.json").read_text())["version"] == (THREE / "VERSION").read_text().strip()
    drifted = [name for name in sorted(_vendored() - {"VERSION"})
               if (THREE / name).read_bytes() != (NPM_THREE / name).read_bytes()]
    assert not drifted, f"differ from node_modules/three (copy them again, README.md there): {drifted}"


def test_the_page_loads_exactly_the_vendored_modules(tmp_path):
    body = json.dumps({"asset": {"version": "2.0"}, "extensionsUsed": ["SSSBAKE_subsurface"],
                       "extensions": {"SSSBAKE_subsurface": {"schemaVersion": "2.0.0"}}}).encode()
    body += b" " * (-len(body) % 4)
    glb = tmp_path / "x.glb"
    glb.write_bytes(b"glTF" + struct.pack("<III", 2, 20 + len(body), len(body)) + b"JSON" + body)
    with ViewServer(glb) as server:
        modules = page_modules(server.url)
    paths = {url.removeprefix(server.url) for url in modules}
    three = {p.removeprefix("three/") for p in paths if p.startswith("three/")}
    # every vendored module is loaded (none shipped for nothing) and every loaded one is vendored
    assert three == {name for name in _vendored() if name.endswith(".js")}
    assert {"", "viewer.js", "runtime_three/sssbake-three.js", "runtime_three/sssbake-format.mjs",
            "three/build/three.module.js", "three/build/three.core.js",
            "three/examples/jsm/loaders/GLTFLoader.js"} <= paths
    # the graph is the vendored files' own: each three.js import is served from THREE, byte for byte
    for url, data in modules.items():
        if url.startswith(server.url + "three/"):
            assert data == (THREE / url.removeprefix(server.url + "three/")).read_bytes(), url


def test_specifiers_and_their_resolution():
    source = ("// import { A } from './in-a-comment.js';\n"
              "import * as THREE from 'three';\nimport {\n\tB,\n\tC\n} from 'three/addons/x/B.js';\n"
              "export { D } from \"../d.js\";\nimport './effects.js';\nexport const E = ['from', 'x'];\n"
              "const m = await import('./later.js');\n")
    assert specifiers(source) == ["three", "three/addons/x/B.js", "../d.js", "./effects.js", "./later.js"]
    imports = {"three": "/three/build/three.module.js", "three/addons/": "/three/examples/jsm/"}
    base = "http://127.0.0.1:1/three/examples/jsm/loaders/GLTFLoader.js"
    assert resolve("three", base, imports) == "http://127.0.0.1:1/three/build/three.module.js"
    assert resolve("three/addons/x/B.js", base, imports) == "http://127.0.0.1:1/three/examples/jsm/x/B.js"
    assert resolve("../utils/S.js", base, imports) == "http://127.0.0.1:1/three/examples/jsm/utils/S.js"
    with pytest.raises(ValueError, match="'lodash'"):
        resolve("lodash", base, imports)


def test_an_install_without_three_is_one_line(tmp_path, monkeypatch):
    monkeypatch.setattr("sssbake.pipeline.view.serve.THREE", tmp_path / "three")
    with pytest.raises(ViewError) as e:
        served_folders()
    assert str(e.value) == (f"{tmp_path / 'three' / 'build' / 'three.module.js'}: missing from the installed sssbake "
                            "package; reinstall it (pip install --force-reinstall sssbake, or pip install -e . in a "
                            "checkout)")
