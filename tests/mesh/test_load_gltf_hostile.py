"""Hostile glTF/GLB inputs: URIs that reach outside the asset's folder (every route, unit level and
end to end through `sssbake bake`), size bounds on buffers and images, and the glTF 2.0 rules a
broken file breaks, each refused with its exact one-line message (or, for an unknown GLB chunk, a
warning in the report)."""

import base64
import contextlib
import json
import os
import struct
import sys
import tracemalloc
from pathlib import Path

import numpy as np
import pytest
from bad_inputs import TRIANGLE, TRIANGLE_FACES, _glb, _glb_plus, _gltf, _set
from generate import generate
from gltf_corpus import GltfBuilder, _material, _mesh, _png_chunk, _scene, _texture, box24, gradient, png

from sssbake.pipeline.cli import main
from sssbake.pipeline.core.errors import AssetError
from sssbake.pipeline.mesh import load_gltf
from sssbake.pipeline.mesh.load import load_scene

MARKER = b"sssbake-hostile-secret-7f3a"
BIN, JSON_CHUNK = 0x004E4942, 0x4E4F534A

_opened: list[str] | None = None


def _audit(event: str, args: tuple) -> None:
    if event == "open" and _opened is not None and isinstance(args[0], (str, bytes, os.PathLike)):
        _opened.append(os.path.realpath(os.fsdecode(args[0])))


sys.addaudithook(_audit)  # hooks cannot be removed; this one records only inside `_opens`


@contextlib.contextmanager
def _opens():
    """Real paths of every file Python opens (builtin open, os.open) inside the block."""
    global _opened
    _opened = []
    try:
        yield _opened
    finally:
        _opened = None


def _box(image_uri: str | None = None, buffer_uri: str | None = None) -> tuple[str, bytes]:
    """A marble box glTF (text, blob): a base-colour texture at `image_uri` when given, its buffer a
    data: URI or the file `buffer_uri`."""
    b = GltfBuilder()
    _material(b, texture=None if image_uri is None else _texture(b, b"", "image/png", uri=image_uri))
    _mesh(b, box24(size=10.0))
    _scene(b, [{"name": "Box", "mesh": 0}])
    return b.gltf(buffer_uri)


@pytest.fixture
def tree(tmp_path):
    """``private/secret.png`` (a PNG carrying `MARKER`), ``private/secret.bin`` (a valid box buffer with
    `MARKER` inside its byteLength) and an empty ``assets/`` beside them."""
    private = tmp_path / "private"
    private.mkdir()
    image = png(gradient())
    (private / "secret.png").write_bytes(image[:-12] + _png_chunk(b"tEXt", b"Comment\0" + MARKER) + image[-12:])
    _, blob = _box()
    (private / "secret.bin").write_bytes(blob + MARKER + b"\0" * (-len(MARKER) % 4))
    (tmp_path / "assets").mkdir()
    return tmp_path


def _uri(tree: Path, route: str, name: str) -> str:
    """The URI by which an asset in ``assets/`` reaches ``private/<name>`` along `route`."""
    secret = tree / "private" / name
    assets = tree / "assets"
    if route == "symlinked file":
        os.symlink(secret, assets / f"innocent_{name}")
        return f"innocent_{name}"
    if route == "symlinked folder":
        if not (assets / "textures").exists():
            os.symlink(tree / "private", assets / "textures")
        return f"textures/{name}"
    return {
        "relative": f"../private/{name}",
        "climbing to the root": "../" * 40 + str(secret).lstrip("/"),
        "percent-encoded": f"..%2Fprivate%2F{name}",
        "absolute": str(secret),
        "file URI": secret.as_uri(),
    }[route]


ROUTES = ["relative", "climbing to the root", "percent-encoded", "absolute", "file URI", "symlinked file",
          "symlinked folder"]


def _write(tree: Path, kind: str, uri: str) -> Path:
    """``assets/hostile.gltf`` whose image 0 (`kind` "image") or buffer 0 (`kind` "buffer") is `uri`."""
    text, _ = _box(image_uri=uri) if kind == "image" else _box(buffer_uri=uri)
    if kind == "buffer":  # byteLength covers the marker: an allowed read brings it in
        doc = json.loads(text)
        doc["buffers"][0]["byteLength"] = (tree / "private" / "secret.bin").stat().st_size
        text = json.dumps(doc)
    path = tree / "assets" / "hostile.gltf"
    path.write_text(text)
    return path


@pytest.mark.parametrize("kind", ["image", "buffer"])
@pytest.mark.parametrize("route", ROUTES)
def test_every_route_outside_the_folder_is_refused_unopened_and_allow_root_opens_it(tree, route, kind):
    name = "secret.png" if kind == "image" else "secret.bin"
    uri = _uri(tree, route, name)
    asset = _write(tree, kind, uri)
    real = (tree / "private" / name).resolve()
    with _opens() as opened, pytest.raises(AssetError) as info:
        load_scene(asset)
    assert str(info.value) == (f"{asset}: {kind} 0 URI '{uri}' resolves to {real}, outside the asset's folder; "
                               f"refused (pass --allow-root {real.parent} to read it)")
    assert str(asset.resolve()) in opened  # the hook sees the loader's opens ...
    assert str(real) not in opened  # ... and the secret was never one of them

    scene = load_scene(asset, (str(tree / "private"),))
    if kind == "image":
        assert MARKER in scene.images[0].data
    else:
        np.testing.assert_allclose(np.abs(scene.meshes[0].primitives[0].positions).max(), 5.0)


def test_remote_and_nul_uris_are_refused_without_a_fetch(tree):
    asset = tree / "assets" / "remote.gltf"
    asset.write_text(_box(image_uri="http://169.254.169.254/latest/meta-data")[0])
    with pytest.raises(AssetError) as info:
        load_scene(asset)
    assert str(info.value) == (f"{asset}: image 0 URI 'http://169.254.169.254/latest/meta-data' is not a file beside "
                               "the asset; sssbake reads only relative paths, file: and data: URIs")
    asset.write_text(_box(image_uri="tex%00.png")[0])
    with pytest.raises(AssetError, match=r"image 0 URI 'tex%00.png' contains a NUL character$"):
        load_scene(asset)


def _bake(src: Path, out: Path, *extra: str) -> int:
    return main(["bake", str(src), "-o", str(out), "--scale-mm", "1", "--material", "marble", "--techniques", "none",
                 "--atlas-resolution", "64", "--no-validate", "-q", *extra])


def _files_holding(folder: Path, needle: bytes) -> list[str]:
    return sorted(str(p) for p in folder.rglob("*") if p.is_file() and needle in p.read_bytes())


def test_bake_refuses_every_route_and_no_output_or_cache_holds_the_secret(tree, capsys):
    src = tree / "assets"
    generate(tree / "good")
    (src / "good.obj").write_bytes((tree / "good" / "sphere.obj").read_bytes())
    routes = {"relative": "image", "file URI": "buffer", "symlinked file": "image", "absolute": "buffer"}
    for route, kind in routes.items():
        uri = _uri(tree, route, "secret.png" if kind == "image" else "secret.bin")
        _write(tree, kind, uri).rename(src / f"{route.replace(' ', '_')}.gltf")
    out = tree / "out"
    with _opens() as opened:
        code = _bake(src, out)
    assert code == 1
    assert not {str((tree / "private" / n).resolve()) for n in ("secret.png", "secret.bin")} & set(opened)
    records = {Path(r["asset"]).name: r for r in json.loads((out / "batch.json").read_text())["assets"]}
    assert records["good.obj"]["status"] == "ok"
    err = capsys.readouterr().err
    for route in routes:
        record = records[f"{route.replace(' ', '_')}.gltf"]
        assert record["status"] == "failed" and "outside the asset's folder; refused (pass --allow-root" in record["error"]
        assert "\n" not in record["error"] and record["error"] in err
    assert _files_holding(out, MARKER) == []  # outputs, reports and the stage cache alike
    assert not list(out.glob("relative.*")) and not list(out.glob("absolute.*"))

    # The positive control: allowed, the same files bake and the secret's bytes do reach the outputs.
    allowed = tree / "out_allowed"
    assert _bake(src, allowed, "--allow-root", str(tree / "private")) == 0
    assert str(allowed / "relative.glb") in _files_holding(allowed, MARKER)


def test_a_buffer_file_is_read_up_to_byte_length_only(tree):
    _, blob = _box()
    big = tree / "assets" / "big.bin"
    with open(big, "wb") as f:
        f.write(blob)
        f.truncate(1 << 30)  # 1 GiB (sparse): reading it whole would allocate a gigabyte
    asset = tree / "assets" / "big.gltf"
    asset.write_text(_box(buffer_uri="big.bin")[0])
    tracemalloc.start()
    try:
        scene = load_scene(asset)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert peak < 32 << 20 and len(scene.meshes[0].primitives[0].faces) == 12


def test_devices_and_oversized_buffers_and_images_are_refused(tree, monkeypatch):
    assets = tree / "assets"
    os.symlink("/dev/zero", assets / "zero.bin")
    asset = assets / "zero.gltf"
    asset.write_text(_box(buffer_uri="zero.bin")[0])
    with pytest.raises(AssetError) as info:
        load_scene(asset, ("/dev",))
    assert str(info.value) == f"{asset}: buffer 0 URI 'zero.bin' resolves to /dev/zero, which is not a regular file"

    doc = json.loads(_box()[0])
    doc["buffers"][0]["byteLength"] = load_gltf.MAX_BUFFER_BYTES + 4
    asset.write_text(json.dumps(doc))
    with pytest.raises(AssetError) as info:
        load_scene(asset)
    assert str(info.value) == f"{asset}: buffer 0 declares byteLength 2147483652, over the 2 GiB sssbake reads per buffer"

    monkeypatch.setattr(load_gltf, "MAX_IMAGE_BYTES", 1 << 20)
    with open(assets / "huge.png", "wb") as f:
        f.write(png(gradient()))
        f.truncate(3 << 20)
    asset.write_text(_box(image_uri="huge.png")[0])
    with pytest.raises(AssetError) as info:
        load_scene(asset)
    assert str(info.value) == f"{asset}: image 0 is over the 1 MiB sssbake reads per image"


def test_data_uri_length_is_checked_against_byte_length(tmp_path):
    doc = _gltf(TRIANGLE, TRIANGLE_FACES)
    declared = doc["buffers"][0]["byteLength"]
    path = tmp_path / "d.gltf"
    path.write_text(json.dumps(_set(doc, ("buffers/0/byteLength", declared + 8))))
    with pytest.raises(AssetError) as info:
        load_scene(path)
    assert str(info.value) == f"{path}: truncated buffer 0: {declared} bytes, byteLength says {declared + 8}"
    # Longer than declared: the buffer is its first byteLength bytes (the views still fit).
    payload = base64.b64decode(doc["buffers"][0]["uri"].split(",")[1]) + b"\xff" * 64
    doc = _set(doc, ("buffers/0/byteLength", declared),
               ("buffers/0/uri", "data:application/octet-stream;base64," + base64.b64encode(payload).decode()))
    path.write_text(json.dumps(doc))
    np.testing.assert_array_equal(load_scene(path).meshes[0].primitives[0].faces, TRIANGLE_FACES)


def _load_error(tmp_path: Path, doc: dict, name: str = "bad.gltf") -> str:
    path = tmp_path / name
    path.write_text(json.dumps(doc))
    with pytest.raises(AssetError) as info:
        load_scene(path)
    message = str(info.value)
    assert message.startswith(f"{path}: ") and "\n" not in message
    return message[len(f"{path}: "):]


def _quad(*edits) -> dict:
    return _set(_gltf(TRIANGLE, TRIANGLE_FACES), *edits)


@pytest.mark.parametrize("edits, problem", [
    ([("asset/version", "1.0")],
     "asset.version is '1.0'; only glTF 2.x is read (gltf-pipeline -i in.gltf -o out.gltf upgrades a glTF 1.0 file)"),
    ([("asset/version", "3.0")], "asset.version is '3.0'; only glTF 2.x is read "
                                 "(gltf-pipeline -i in.gltf -o out.gltf upgrades a glTF 1.0 file)"),
    ([("asset/version", 2.0)], "asset.version is 2.0, not a version string such as '2.0'"),
    ([("asset", {})], "no asset.version: not a glTF 2.0 file (the asset object and its version are required)"),
    ([("asset/minVersion", "2.1")], "asset.minVersion is '2.1'; sssbake reads glTF 2.0"),
    ([("accessors/0/componentType", 5125)],
     "mesh 0 primitive 0: POSITION accessor 0 is UNSIGNED_INT; glTF 2.0 allows FLOAT (KHR_mesh_quantization allows more)"),
    ([("meshes/0/primitives/0/attributes/COLOR_0", 1)],
     "mesh 0 primitive 0: COLOR_0 accessor 1 has type SCALAR, expected VEC3 or VEC4"),
    ([("meshes/0/primitives/0/attributes/WEIGHTS_0", 0)],
     "mesh 0 primitive 0: WEIGHTS_0 accessor 0 has type VEC3, expected VEC4"),
    ([("accessors/1/normalized", True)],
     "mesh 0 primitive 0: indices accessor 1 is normalized UNSIGNED_SHORT; glTF 2.0 allows UNSIGNED_BYTE, "
     "UNSIGNED_SHORT or UNSIGNED_INT"),
    ([("accessors/1/componentType", 5126), ("accessors/1/count", 3)],
     "mesh 0 primitive 0: indices accessor 1 is FLOAT; glTF 2.0 allows UNSIGNED_BYTE, UNSIGNED_SHORT or UNSIGNED_INT"),
    ([("bufferViews/0/byteStride", 256)],
     "buffer view 0 has byteStride 256; glTF 2.0 requires a multiple of 4 from 4 to 252"),
    ([("bufferViews/0/byteStride", 0)], "buffer view 0 has byteStride 0; glTF 2.0 requires a multiple of 4 from 4 to 252"),
    ([("bufferViews/1/byteOffset", 47)],
     "mesh 0 primitive 0 indices (accessor 1) starts at byte 47 of its buffer (0 into buffer view 1), "
     "not a multiple of its 2-byte component"),
    ([("bufferViews/0/byteLength", -4)], "buffer view 0 byteLength is -4; glTF 2.0 requires a whole number >= 1"),
    ([("buffers/0/byteLength", 0)], "buffer 0 byteLength is 0; glTF 2.0 requires a whole number >= 1"),
    ([("accessors/0/bufferView", None), ("accessors/0/count", 1 << 30)],
     "mesh 0 primitive 0 POSITION (accessor 0) has count 1073741824 and no buffer view: over the 2 GiB sssbake reads "
     "per buffer"),
])
def test_gltf_rules_are_refused_with_their_exact_message(tmp_path, edits, problem):
    doc = _quad(*edits)
    doc["accessors"][0] = {k: v for k, v in doc["accessors"][0].items() if v is not None}
    assert _load_error(tmp_path, doc) == problem


def test_accepted_variants_stay_accepted(tmp_path):
    path = tmp_path / "ok.gltf"
    for doc in (_quad(("asset/version", "2.1")), _quad(("asset/minVersion", "2.0")),
                _quad(("meshes/0/primitives/0/attributes/_CUSTOM_0", 1))):
        path.write_text(json.dumps(doc))
        np.testing.assert_array_equal(load_scene(path).meshes[0].primitives[0].faces, TRIANGLE_FACES)


def test_normalized_and_quantized_texcoords(tmp_path):
    uv = np.array([[0, 0], [255, 0], [0, 255], [255, 255]], np.uint8)
    doc = _quad()
    blob = base64.b64decode(doc["buffers"][0]["uri"].split(",")[1]) + uv.tobytes()
    doc["buffers"][0] = {"byteLength": len(blob),
                         "uri": "data:application/octet-stream;base64," + base64.b64encode(blob).decode()}
    doc["bufferViews"].append({"buffer": 0, "byteOffset": len(blob) - 8, "byteLength": 8})
    doc["accessors"].append({"bufferView": 2, "componentType": 5121, "count": 4, "type": "VEC2", "normalized": True})
    doc["meshes"][0]["primitives"][0]["attributes"]["TEXCOORD_0"] = 2
    path = tmp_path / "uv.gltf"
    path.write_text(json.dumps(doc))
    np.testing.assert_array_equal(load_scene(path).meshes[0].primitives[0].uvs[0], uv / 255.0)
    del doc["accessors"][2]["normalized"]
    assert _load_error(tmp_path, doc) == ("mesh 0 primitive 0: TEXCOORD_0 accessor 2 is UNSIGNED_BYTE; glTF 2.0 allows "
                                          "FLOAT, normalized UNSIGNED_BYTE, normalized UNSIGNED_SHORT "
                                          "(KHR_mesh_quantization allows more)")
    doc["extensionsUsed"] = doc["extensionsRequired"] = ["KHR_mesh_quantization"]
    path.write_text(json.dumps(doc))
    np.testing.assert_array_equal(load_scene(path).meshes[0].primitives[0].uvs[0], uv)


def _sparse_quad(indices: list[int]) -> dict:
    """The quad with a sparse accessor over POSITION replacing `indices` by (0, 0, 9)."""
    doc = _quad()
    blob = base64.b64decode(doc["buffers"][0]["uri"].split(",")[1])
    where = np.array(indices, np.uint16).tobytes()
    where += b"\0" * (-len(where) % 4)
    values = np.tile(np.array([0.0, 0.0, 9.0], np.float32), (len(indices), 1)).tobytes()
    doc["bufferViews"] += [{"buffer": 0, "byteOffset": len(blob), "byteLength": len(where)},
                           {"buffer": 0, "byteOffset": len(blob) + len(where), "byteLength": len(values)}]
    blob += where + values
    doc["buffers"][0] = {"byteLength": len(blob),
                         "uri": "data:application/octet-stream;base64," + base64.b64encode(blob).decode()}
    doc["accessors"][0]["sparse"] = {"count": len(indices), "indices": {"bufferView": 2, "componentType": 5123},
                                     "values": {"bufferView": 3}}
    return doc


def test_sparse_indices_must_increase_and_fit(tmp_path):
    path = tmp_path / "sparse.gltf"
    path.write_text(json.dumps(_sparse_quad([1, 3])))
    positions = load_scene(path).meshes[0].primitives[0].positions
    np.testing.assert_array_equal(positions[[1, 3], 2], [9.0, 9.0])
    np.testing.assert_array_equal(positions[[0, 2], 2], [0.0, 0.0])
    prefix = "mesh 0 primitive 0 POSITION (accessor 0): "
    assert _load_error(tmp_path, _sparse_quad([3, 1])) == prefix + "sparse indices are not strictly increasing (1 follows 3)"
    assert _load_error(tmp_path, _sparse_quad([2, 2])) == prefix + "sparse indices are not strictly increasing (2 follows 2)"
    assert _load_error(tmp_path, _sparse_quad([1, 4])) == prefix + "sparse index 4 out of range for 4 elements"
    assert _load_error(tmp_path, _set(_sparse_quad([1, 3]), ("accessors/0/count", 1), ("accessors/0/sparse/count", 2))) \
        == prefix + "sparse count 2 exceeds the accessor's count 1"


def _glb_error(tmp_path: Path, data: bytes) -> str:
    path = tmp_path / "bad.glb"
    path.write_bytes(data)
    with pytest.raises(AssetError) as info:
        load_scene(path)
    assert "\n" not in str(info.value)
    return str(info.value)[len(f"{path}: "):]


def test_glb_chunk_layout(tmp_path):
    quad = _gltf(TRIANGLE, TRIANGLE_FACES)
    good = _glb(quad)
    stray = good + b"abcd"
    stray = stray[:8] + struct.pack("<I", len(stray)) + stray[12:]
    assert _glb_error(tmp_path, stray) == "corrupt GLB: 4 stray bytes after chunk 0, too few for a chunk header"
    assert _glb_error(tmp_path, good + bytes(4)) == (f"corrupt GLB: header declares {len(good)} bytes, the file has "
                                                     f"{len(good) + 4} (4 bytes after the last chunk)")
    bin_first = struct.pack("<4sII", b"glTF", 2, 20) + struct.pack("<II", 0, BIN)
    assert _glb_error(tmp_path, bin_first) == "corrupt GLB: the first chunk is not JSON (type 0x004E4942)"
    assert _glb_error(tmp_path, struct.pack("<4sII", b"glTF", 2, 12)) == \
        "corrupt GLB: no chunks after the header (the JSON chunk is missing)"
    text = json.dumps(quad).encode()
    text += b" " * (-len(text) % 4)
    assert _glb_error(tmp_path, _glb_plus(quad, (JSON_CHUNK, text))) == (
        "corrupt GLB: chunk 1 is a JSON chunk; only one JSON chunk, then at most one BIN chunk, may lead the file")


def test_unknown_chunks_after_bin_are_ignored_with_a_warning_in_the_report(tmp_path):
    b = GltfBuilder()
    _material(b)
    _mesh(b, box24(size=10.0))
    _scene(b, [{"name": "Box", "mesh": 0}])
    glb = b.glb()
    extra = struct.pack("<II", 8, 0x5A5A5A5A) + b"zzzzzzzz"
    data = glb[:8] + struct.pack("<I", len(glb) + len(extra)) + glb[12:] + extra
    src = tmp_path / "in"
    src.mkdir()
    (src / "extra_chunk.glb").write_bytes(data)
    scene = load_scene(src / "extra_chunk.glb")
    warning = "GLB chunk 2 has unknown type 0x5A5A5A5A (8 bytes); ignored, as glTF 2.0 requires"
    assert scene.warnings == (warning,) and len(scene.meshes[0].primitives[0].faces) == 12
    assert _bake(src, tmp_path / "out") == 0
    report = json.loads((tmp_path / "out" / "extra_chunk.report.json").read_text())
    assert warning in report["warnings"]
