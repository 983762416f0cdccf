"""The Khronos glTF-Validator accepts sssbake's output and catches broken files."""

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pygltflib
import pytest
from test_gltf import icosphere_asset

from sssbake.exporters import gltf_validator
from sssbake.exporters.gltf import UNSIGNED_INT, to_glb, write_glb
from sssbake.exporters.gltf_validator import ValidatorUnavailable, find_validator, user_folder, validate_glb, \
    validate_many
from sssbake.pipeline.mesh.baked import VertexAttribute


def _broken(data: bytes, how: str) -> bytes:
    gltf = pygltflib.GLTF2.load_from_bytes(data)
    attrs = gltf.meshes[0].primitives[0].attributes
    if how == "unsigned_int_attribute":
        gltf.accessors[attrs._THICKNESS].componentType = UNSIGNED_INT
    else:
        gltf.accessors[attrs.POSITION].min = []
        gltf.accessors[attrs.POSITION].max = []
    return b"".join(gltf.save_to_bytes())


def test_export_is_clean_and_broken_files_are_caught(tmp_path):
    path = tmp_path / "sphere.glb"
    write_glb(icosphere_asset(double_sided=True), path)
    good_bytes, _ = to_glb(icosphere_asset(extras={"table": np.eye(3)}))
    asset = icosphere_asset()
    n = len(asset.scene.meshes[0].primitives[0].positions)
    index = VertexAttribute("sss:prt:ref", np.c_[np.arange(n), np.zeros(n)], "", "uint16", "indices")
    technique_bytes, _ = to_glb(replace(
        asset, vertex_attributes={(0, 0): asset.vertex_attributes[(0, 0)] + (index,)},
        mesh_extras={0: {"prt": {"codes": np.arange(30, dtype=np.uint8).reshape(10, 3),
                                 "signed": np.array([-3, 4], dtype=np.int16)}}}))
    # one node process for all five: node's start-up dominates
    clean, with_table, with_technique, unsigned, unbounded = validate_many([
        path, good_bytes, technique_bytes, _broken(good_bytes, "unsigned_int_attribute"),
        _broken(good_bytes, "no_bounds"),
    ])

    for report in (clean, with_table, with_technique):
        assert (report.num_errors, report.num_warnings) == (0, 0), report.to_json()
        assert report.ok
    assert clean.uri == str(path) and with_table.uri == "<bytes>"
    assert clean.validator_version
    # The validator knows neither KHR_materials_diffuse_transmission nor sssbake's own extension:
    # infos, not warnings.
    unsupported = [m for m in clean.messages if m.code == "UNSUPPORTED_EXTENSION"]
    assert {m.severity for m in unsupported} == {"Information"}
    assert sorted(m.message.split("'")[1] if "'" in m.message else m.message for m in unsupported) == [
        "KHR_materials_diffuse_transmission", "SSSBAKE_subsurface"]

    assert "MESH_PRIMITIVE_ATTRIBUTES_ACCESSOR_UNSIGNED_INT" in unsigned.codes("Error")
    assert "MESH_PRIMITIVE_POSITION_ACCESSOR_WITHOUT_BOUNDS" in unbounded.codes("Error")
    assert not unsigned.ok and not unbounded.ok
    assert unbounded.to_json()["numErrors"] == unbounded.num_errors >= 1


def test_garbage_is_reported_as_an_error():
    with pytest.raises(RuntimeError, match="could not validate|failed"):
        validate_glb(b"not a gltf file")


def test_env_var_names_the_node_modules_folder(tmp_path, monkeypatch):
    package = tmp_path / "node_modules" / "gltf-validator"
    package.mkdir(parents=True)
    (package / "package.json").write_text("{}")
    monkeypatch.setenv(gltf_validator.ENV_VAR, str(tmp_path / "node_modules"))
    assert find_validator() == tmp_path / "node_modules"


def test_npm_is_asked_only_when_no_local_folder_holds_it(tmp_path, monkeypatch):
    monkeypatch.setenv("XDG_DATA_HOME", str(tmp_path / "no-user-install"))
    asked = []
    monkeypatch.setattr(gltf_validator, "_npm_root_global", lambda: asked.append(1) or tmp_path / "global")
    local = tmp_path / "node_modules"
    (local / "gltf-validator").mkdir(parents=True)
    (local / "gltf-validator" / "package.json").write_text("{}")
    monkeypatch.setenv(gltf_validator.ENV_VAR, str(local))
    assert find_validator() == local and asked == []
    # none of the local folders holds it: not $SSSBAKE_GLTF_VALIDATOR's, the package's, the working folder's
    (tmp_path / "global" / "gltf-validator").mkdir(parents=True)
    (tmp_path / "global" / "gltf-validator" / "package.json").write_text("{}")
    monkeypatch.setenv(gltf_validator.ENV_VAR, str(tmp_path / "elsewhere"))
    monkeypatch.setattr(gltf_validator, "__file__", str(tmp_path / "pkg" / "exporters" / "gltf_validator.py"))
    monkeypatch.chdir(tmp_path / "global")
    assert find_validator() == tmp_path / "global" and asked == [1]


def test_missing_node_says_how_to_install(monkeypatch):
    monkeypatch.setattr(gltf_validator.shutil, "which", lambda name: None)
    with pytest.raises(ValidatorUnavailable) as e:
        validate_glb(b"glTF")
    assert str(e.value).startswith("node (Node.js) is not installed: install Node.js and npm (Debian: apt-get install "
                                   "nodejs npm), then run `sssbake doctor --install-validator` (npm installs "
                                   f"gltf-validator@{gltf_validator.VALIDATOR_VERSION} in {user_folder()})")


REPO = Path(__file__).resolve().parents[2]


def test_the_per_user_folder_is_found_and_runs(tmp_path, monkeypatch):
    """Outside a checkout (no node_modules beside the package or in the working folder) the validator
    that `sssbake doctor --install-validator` put in $XDG_DATA_HOME/sssbake/node_modules is used."""
    checkout = REPO / "node_modules" / "gltf-validator"
    if not checkout.is_dir():
        pytest.skip("no node_modules/gltf-validator (npm ci) to stand in for a per-user install")
    monkeypatch.delenv(gltf_validator.ENV_VAR, raising=False)
    monkeypatch.setattr(gltf_validator, "__file__", str(tmp_path / "site-packages" / "sssbake" / "exporters" / "x.py"))
    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(gltf_validator, "_npm_root_global", lambda: None)
    monkeypatch.setenv("XDG_DATA_HOME", str(tmp_path / "data"))
    with pytest.raises(ValidatorUnavailable, match=f"{tmp_path / 'data' / 'sssbake' / 'node_modules'}.*doctor"):
        find_validator()
    (tmp_path / "data" / "sssbake" / "node_modules").mkdir(parents=True)
    (tmp_path / "data" / "sssbake" / "node_modules" / "gltf-validator").symlink_to(checkout)
    assert find_validator() == tmp_path / "data" / "sssbake" / "node_modules"
    assert validate_glb(b'{"asset": {"version": "2.0"}}').validator_version == gltf_validator.VALIDATOR_VERSION


def test_the_user_folder_follows_xdg(tmp_path, monkeypatch):
    monkeypatch.setenv("HOME", str(tmp_path))
    monkeypatch.delenv("XDG_DATA_HOME", raising=False)
    assert user_folder() == tmp_path / ".local" / "share" / "sssbake" / "node_modules"
    monkeypatch.setenv("XDG_DATA_HOME", "relative/data")  # the XDG spec: a relative one is ignored
    assert user_folder() == tmp_path / ".local" / "share" / "sssbake" / "node_modules"
    monkeypatch.setenv("XDG_DATA_HOME", str(tmp_path / "xdg"))
    assert user_folder() == tmp_path / "xdg" / "sssbake" / "node_modules"


def test_the_installed_version_is_package_lock_s_pin():
    lock = json.loads((REPO / "package-lock.json").read_text())
    assert gltf_validator.VALIDATOR_VERSION == lock["packages"]["node_modules/gltf-validator"]["version"]


def test_a_warning_message_has_to_json():
    """Regression: a Warning on an export (an input PNG's colour-space chunks, as in Khronos' BoxTextured.glb)
    reached the report through `ValidationMessage.to_json`, which did not exist."""
    import json

    from gltf_corpus import _textured_box, gradient, png

    (report,) = validate_many([_textured_box(png(gradient(), colour_chunks=True), "image/png").glb()])
    (message,) = [m for m in report.messages if m.severity == "Warning"]
    assert message.to_json() == {"code": "IMAGE_FEATURES_UNSUPPORTED", "severity": "Warning", "pointer": "/images/0",
                                 "message": message.message}
    assert json.loads(json.dumps(report.to_json()))["messages"][0]["code"] == "IMAGE_FEATURES_UNSUPPORTED"
