"""Outputs and cached scenes follow the files an asset references, not only the asset's own bytes:
a glTF's external buffer or texture, a USD sublayer, an OBJ's material library and texture. Changing
only such a file rebakes the asset (not "up-to-date", no stale cached scene or stage downstream) and
the new output shows the change; deleting it fails the asset with the loader's one line."""

import base64
import io
import json
import os
from pathlib import Path

import numpy as np
import pygltflib
import pytest
from PIL import Image

from sssbake.pipeline.bake.asset import dependencies_hold
from sssbake.pipeline.bake.batch import run_batch
from sssbake.pipeline.config import EMPTY_CONFIG
from sssbake.pipeline.mesh.confine import Confinement
from sssbake.pipeline.mesh.digest import file_digest

# Opaque: no atlas or thickness, so each bake takes well under a second; the glTF buffer case
# is translucent to show the stages after clean (atlas, thickness) are not served stale either.
OPAQUE = {"material": "opaque", "scale_mm": 1.0, "techniques": (), "validate": False}
MARBLE = {"material": "marble", "scale_mm": 1.0, "techniques": (), "validate": False, "atlas_resolution": 64}

TETRA = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], "<f4")
TETRA_FACES = np.array([0, 2, 1, 0, 1, 3, 0, 3, 2, 1, 2, 3], "<u2")
TETRA_UV = np.array([[0, 0], [1, 0], [0, 1], [1, 1]], "<f4")


def png(value: tuple[int, int, int]) -> bytes:
    buf = io.BytesIO()
    Image.fromarray(np.tile(np.array(value, np.uint8), (4, 4, 1))).save(buf, format="PNG")
    return buf.getvalue()


def tetra_bin(positions: np.ndarray) -> bytes:
    return positions.astype("<f4").tobytes() + TETRA_FACES.tobytes() + TETRA_UV.tobytes()


def write_gltf(folder: Path, *, texture: bool) -> Path:
    """``a.gltf`` with its buffer in ``a.bin`` and, with `texture`, its base colour in ``skin.png``."""
    (folder / "a.bin").write_bytes(tetra_bin(TETRA))
    doc = {
        "asset": {"version": "2.0"},
        "buffers": [{"byteLength": 48 + 24 + 32, "uri": "a.bin"}],
        "bufferViews": [{"buffer": 0, "byteLength": 48}, {"buffer": 0, "byteOffset": 48, "byteLength": 24},
                        {"buffer": 0, "byteOffset": 72, "byteLength": 32}],
        "accessors": [{"bufferView": 0, "componentType": 5126, "count": 4, "type": "VEC3",
                       "min": [0, 0, 0], "max": [1, 1, 1]},
                      {"bufferView": 1, "componentType": 5123, "count": 12, "type": "SCALAR"},
                      {"bufferView": 2, "componentType": 5126, "count": 4, "type": "VEC2"}],
        "meshes": [{"name": "tetra", "primitives": [{"attributes": {"POSITION": 0, "TEXCOORD_0": 2}, "indices": 1,
                                                     **({"material": 0} if texture else {})}]}],
        "nodes": [{"mesh": 0}],
        "scenes": [{"nodes": [0]}],
        "scene": 0,
    }
    if texture:
        (folder / "skin.png").write_bytes(png((200, 100, 50)))
        doc.update(images=[{"uri": "skin.png"}], textures=[{"source": 0}],
                   materials=[{"name": "skin", "pbrMetallicRoughness": {"baseColorTexture": {"index": 0}}}])
    (folder / "a.gltf").write_text(json.dumps(doc))
    return folder / "a.gltf"


def usd_layer(apex_x: float) -> str:
    return ('#usda 1.0\ndef Mesh "M"\n{\n'
            f'    point3f[] points = [(0, 0, 0), ({apex_x}, 0, 0), (0, 1, 0), (0, 0, 1)]\n'
            '    int[] faceVertexCounts = [3, 3, 3, 3]\n'
            '    int[] faceVertexIndices = [0, 2, 1, 0, 1, 3, 0, 3, 2, 1, 2, 3]\n}\n')


def write_usd(folder: Path) -> Path:
    """``a.usda``, all of whose geometry is in its sublayer ``part.usda``."""
    (folder / "part.usda").write_text(usd_layer(1.0))
    (folder / "a.usda").write_text('#usda 1.0\n(\n    subLayers = [@./part.usda@]\n)\n')
    return folder / "a.usda"


def mtl(kd: str) -> str:
    return f"newmtl skin\nKd {kd}\nmap_Kd skin.png\n"  # trimesh keeps Kd as 8-bit


def write_obj(folder: Path) -> Path:
    """``a.obj`` with its material in ``a.mtl`` and that material's texture ``skin.png``."""
    (folder / "a.mtl").write_text(mtl("0.2 0.4 0.6"))
    (folder / "skin.png").write_bytes(png((10, 20, 30)))
    lines = ["mtllib a.mtl", "usemtl skin"]
    lines += [f"v {x} {y} {z}" for x, y, z in TETRA] + [f"vt {u} {v}" for u, v in TETRA_UV]
    lines += [f"f {a + 1}/{a + 1} {b + 1}/{b + 1} {c + 1}/{c + 1}" for a, b, c in TETRA_FACES.reshape(-1, 3)]
    (folder / "a.obj").write_text("\n".join(lines) + "\n")
    return folder / "a.obj"


def bake(src: Path, out: Path, cache: Path, options: dict) -> dict:
    """The batch record of ``a.*`` (a sublayer is an asset of the batch too) and, when it baked, its report."""
    summary = run_batch([src], out, EMPTY_CONFIG, options, cache_dir=str(cache), progress=False, isolate=False)
    (record,) = [r for r in summary["assets"] if Path(r["asset"]).stem == "a"]
    report = out / "a.report.json"
    if record["status"] != "failed":
        record["report"] = json.loads(report.read_text())
    return record


def glb(out: Path) -> pygltflib.GLTF2:
    return pygltflib.GLTF2().load(str(out / "a.glb"))


def positions(out: Path) -> np.ndarray:
    """Every vertex position of the output's first mesh (n, 3)."""
    gltf = glb(out)
    accessor = gltf.accessors[gltf.meshes[0].primitives[0].attributes.POSITION]
    view = gltf.bufferViews[accessor.bufferView]
    data = gltf.binary_blob()[view.byteOffset + (accessor.byteOffset or 0):]
    return np.frombuffer(data, "<f4", accessor.count * 3).reshape(-1, 3)


def image_bytes(out: Path) -> list[bytes]:
    gltf = glb(out)
    blob = gltf.binary_blob()
    views = [gltf.bufferViews[im.bufferView] for im in gltf.images]
    return [bytes(blob[v.byteOffset:v.byteOffset + v.byteLength]) for v in views]


def base_color(out: Path) -> list[float]:
    return glb(out).materials[0].pbrMetallicRoughness.baseColorFactor


def move_apex_in_bin(folder: Path) -> None:
    (folder / "a.bin").write_bytes(tetra_bin(TETRA * np.array([1, 1, 2.5], "<f4")))


# (writer, options, change only the referenced file, the output shows it, the file to delete, its message)
CASES = {
    "gltf_buffer": (lambda f: write_gltf(f, texture=False), MARBLE, move_apex_in_bin,
                    lambda out: positions(out)[:, 2].max() == pytest.approx(2.5),
                    "a.bin", "buffer 0: missing file 'a.bin'"),
    "gltf_texture": (lambda f: write_gltf(f, texture=True), OPAQUE,
                     lambda f: (f / "skin.png").write_bytes(png((1, 2, 3))),
                     lambda out: image_bytes(out) == [png((1, 2, 3))],
                     "skin.png", "image 0: missing file 'skin.png'"),
    "usd_sublayer": (write_usd, OPAQUE, lambda f: (f / "part.usda").write_text(usd_layer(3.0)),
                     lambda out: positions(out)[:, 0].max() == pytest.approx(3.0),
                     "part.usda", "sublayer './part.usda' (from a.usda) not found"),
    "obj_mtl": (write_obj, OPAQUE, lambda f: (f / "a.mtl").write_text(mtl("0.9 0.1 0.05")),
                lambda out: base_color(out)[:3] == pytest.approx([0.9, 0.1, 0.05], abs=0.5 / 255), None, None),
    "obj_texture": (write_obj, OPAQUE, lambda f: (f / "skin.png").write_bytes(png((250, 5, 5))),
                    lambda out: image_bytes(out) == [png((250, 5, 5))], None, None),
}


@pytest.mark.parametrize("case", sorted(CASES))
def test_a_changed_referenced_file_rebakes_and_shows(tmp_path, case):
    write, options, change, shows, _, _ = CASES[case]
    src, out, cache = tmp_path / "in", tmp_path / "out", tmp_path / "cache"
    src.mkdir()
    asset = write(src)
    first = bake(src, out, cache, options)
    assert first["status"] == "ok", first
    deps = first["report"]["dependencies"]
    assert deps and all(file_digest(p) == d and Path(p).parent == src.resolve() for p, d in deps.items()), deps
    assert not shows(out)
    glb_bytes = (out / "a.glb").read_bytes()

    again = bake(src, out, cache, options)
    assert again["status"] == "up-to-date" and (out / "a.glb").read_bytes() == glb_bytes
    # another output folder, same cache: every stage comes from it
    elsewhere = bake(src, tmp_path / "out2", cache, options)["report"]["stages"]
    assert all(elsewhere[s]["cached"] == elsewhere[s]["runs"] == 1 for s in ("load", "clean")), elsewhere

    asset_bytes = asset.read_bytes()
    change(src)
    assert asset.read_bytes() == asset_bytes
    changed = bake(src, out, cache, options)
    assert changed["status"] == "ok", changed
    stages = changed["report"]["stages"]
    # neither the cached scene nor anything keyed after it was served
    ran = ("load", "clean", "atlas", "thickness") if options is MARBLE else ("load", "clean")
    assert all(stages[s]["cached"] == 0 and stages[s]["runs"] == 1 for s in ran), stages
    assert shows(out)
    assert changed["report"]["dependencies"] != deps
    assert all(file_digest(p) == d for p, d in changed["report"]["dependencies"].items())
    # the cache now holds the changed scene: a fresh output folder is baked from it, with the change
    fresh = bake(src, tmp_path / "out3", cache, options)
    assert fresh["report"]["stages"]["load"]["cached"] == 1 and shows(tmp_path / "out3")


@pytest.mark.parametrize("case", sorted(c for c in CASES if CASES[c][4]))
def test_a_deleted_referenced_file_fails_the_rebake_with_the_loaders_line(tmp_path, case):
    write, options, _, _, name, message = CASES[case]
    src, out, cache = tmp_path / "in", tmp_path / "out", tmp_path / "cache"
    src.mkdir()
    asset = write(src)
    assert bake(src, out, cache, options)["status"] == "ok"
    (src / name).unlink()
    failed = bake(src, out, cache, options)
    assert failed["status"] == "failed"
    assert failed["error"] == f"{asset}: {message}", failed["error"]


def test_an_obj_texture_deleted_then_restored_rebakes_each_time(tmp_path):
    # trimesh reads an OBJ on without a missing texture: not up to date, baked untextured, and
    # the missing file is recorded so that its coming back is a change too
    src, out, cache = tmp_path / "in", tmp_path / "out", tmp_path / "cache"
    src.mkdir()
    write_obj(src)
    assert bake(src, out, cache, OPAQUE)["status"] == "ok" and image_bytes(out) == [png((10, 20, 30))]
    (src / "skin.png").unlink()
    rebaked = bake(src, out, cache, OPAQUE)
    assert rebaked["status"] == "ok" and image_bytes(out) == []
    assert {Path(p).name: d for p, d in rebaked["report"]["dependencies"].items()} == {
        "a.mtl": file_digest(src / "a.mtl"), "skin.png": ""}
    assert bake(src, out, cache, OPAQUE)["status"] == "up-to-date"
    (src / "skin.png").write_bytes(png((7, 8, 9)))
    restored = bake(src, out, cache, OPAQUE)
    assert restored["status"] == "ok" and image_bytes(out) == [png((7, 8, 9))]
    assert restored["report"]["stages"]["load"]["cached"] == 0


def test_recorded_dependencies_are_not_trusted(tmp_path):
    """A report (or a shared cache entry) names the files to hash: a FIFO, a file outside the asset's
    folder or a garbled entry does not hold, and is neither read nor waited on."""
    folder = tmp_path / "asset"
    folder.mkdir()
    (folder / "a.bin").write_bytes(b"bytes")
    (tmp_path / "outside.bin").write_bytes(b"bytes")
    os.mkfifo(folder / "pipe")
    confinement = Confinement.for_asset(folder / "a.gltf")
    digest = file_digest(folder / "a.bin")
    assert dependencies_hold([(str(folder / "a.bin"), digest)], confinement)
    assert not dependencies_hold([(str(folder / "a.bin"), "0" * 64)], confinement)
    assert not dependencies_hold([(str(folder / "gone.bin"), digest)], confinement)
    assert dependencies_hold([(str(folder / "gone.bin"), "")], confinement)  # missing when read, still missing
    assert not dependencies_hold([(str(folder / "a.bin"), "")], confinement)
    assert not dependencies_hold([(str(folder / "pipe"), digest)], confinement)  # would block a reader
    assert not dependencies_hold([(str(tmp_path / "outside.bin"), digest)], confinement)
    assert dependencies_hold([(str(tmp_path / "outside.bin"), digest)], Confinement.for_asset(folder / "a.gltf",
                                                                                              [tmp_path]))
    assert not dependencies_hold([(None, digest)], confinement)
    assert not dependencies_hold([("nul\0byte", digest)], confinement)


def test_a_report_with_forged_dependencies_is_rebaked(tmp_path):
    src, out, cache = tmp_path / "in", tmp_path / "out", tmp_path / "cache"
    src.mkdir()
    write_gltf(src, texture=False)
    assert bake(src, out, cache, OPAQUE)["status"] == "ok"
    report = json.loads((out / "a.report.json").read_text())
    for forged in ({"/etc/hostname": "0" * 64}, ["a.bin"], None):
        (out / "a.report.json").write_text(json.dumps({**report, "dependencies": forged}))
        assert bake(src, out, cache, OPAQUE)["status"] == "ok"
    assert bake(src, out, cache, OPAQUE)["status"] == "up-to-date"


def test_scene_dependencies_name_what_each_reader_read(tmp_path):
    from sssbake.pipeline.mesh.load import load_scene

    for name, write in (("gltf", lambda f: write_gltf(f, texture=True)), ("usd", write_usd), ("obj", write_obj)):
        folder = tmp_path / name
        folder.mkdir()
        scene = load_scene(write(folder))
        read = [(Path(p).name, d) for p, d in scene.dependencies]
        expect = {"gltf": ["a.bin", "skin.png"], "usd": ["part.usda"], "obj": ["a.mtl", "skin.png"]}[name]
        assert read == [(n, file_digest(folder / n)) for n in expect], (name, read)
    # a data: URI and a GLB's own chunk are the asset's bytes: nothing to follow
    doc = json.loads((tmp_path / "gltf" / "a.gltf").read_text())
    doc["buffers"][0]["uri"] = "data:application/octet-stream;base64," + base64.b64encode(
        (tmp_path / "gltf" / "a.bin").read_bytes()).decode()
    del doc["images"], doc["textures"], doc["materials"], doc["meshes"][0]["primitives"][0]["material"]
    (tmp_path / "inline.gltf").write_text(json.dumps(doc))
    assert load_scene(tmp_path / "inline.gltf").dependencies == ()
