"""Real-world glTF ingestion: every file of the generated corpus (`gltf_corpus`) bakes with no
validator error or warning of sssbake's own making and keeps its data, or is refused with one line
naming the file and the problem; validator messages inherited from the input never fail an asset."""

import json
import sys
from pathlib import Path

import numpy as np
import pygltflib
import pytest
from gltf_corpus import DRACO, MESHOPT, box24, write_corpus

from sssbake.exporters.gltf import dequantize, read_accessor
from sssbake.exporters.gltf_validator import validate_many
from sssbake.pipeline.bake.asset import bake_asset
from sssbake.pipeline.bake.batch import run_batch
from sssbake.pipeline.bake.cache import StageCache
from sssbake.pipeline.config import BatchConfig
from sssbake.pipeline.core.errors import AssetError
from sssbake.pipeline.mesh.load import load_scene
from sssbake.pipeline.options import BakeOptions

SHARED_ASSETS = Path(__file__).resolve().parents[3] / "shared" / "assets"


@pytest.fixture(scope="module")
def corpus(tmp_path_factory):
    """The corpus written and baked as one batch (fallback only at 64², two files with screen)."""
    folder = tmp_path_factory.mktemp("corpus")
    files = write_corpus(folder / "in")
    rules = tuple({"glob": name, "techniques": (f.technique,)} for name, f in files.items() if f.technique)
    config = BatchConfig({"material": "marble", "atlas_resolution": 64, "techniques": ()}, rules, ())
    summary = run_batch([folder / "in"], folder / "out", config, {}, progress=False)
    records = {Path(r["asset"]).name: r for r in summary["assets"]}
    return folder, files, records


def _baked(corpus, name: str) -> tuple[dict, pygltflib.GLTF2]:
    """The report and the output glTF of a corpus file that baked."""
    _, _, records = corpus
    record = records[name]
    assert record["status"] == "ok", record
    report = json.loads(Path(record["outputs"][2]).read_text())
    return report, pygltflib.GLTF2.load(record["outputs"][0])


def _attribute(gltf: pygltflib.GLTF2, prim: pygltflib.Primitive, name: str) -> np.ndarray:
    index = getattr(prim.attributes, name)
    return dequantize(read_accessor(gltf, index), bool(gltf.accessors[index].normalized))


def _rows(*columns) -> np.ndarray:
    """Distinct rows of the columns side by side, in float32 (what both files store)."""
    return np.unique(np.column_stack([np.asarray(c, np.float64).astype(np.float32) for c in columns]), axis=0)


def _image(gltf: pygltflib.GLTF2, index: int) -> tuple[bytes, str]:
    image = gltf.images[index]
    view = gltf.bufferViews[image.bufferView]
    return gltf.binary_blob()[view.byteOffset : view.byteOffset + view.byteLength], image.mimeType


def test_the_corpus_is_valid_gltf(corpus):
    folder, files, _ = corpus
    names = sorted(files)
    reports = dict(zip(names, validate_many([folder / "in" / n for n in names])))
    for name, report in reports.items():
        expected = {"mislabelled_jpeg.glb": ["IMAGE_MIME_TYPE_INVALID"], "truncated_png.glb": ["IMAGE_UNEXPECTED_EOS"],
                    "box_textured_colorspace.glb": ["IMAGE_FEATURES_UNSUPPORTED"]}.get(name, [])
        assert [m.code for m in report.messages if m.severity in ("Error", "Warning")] == expected, name


def test_every_file_bakes_clean_or_is_refused_in_one_line(corpus):
    folder, files, records = corpus
    assert set(records) == set(files)  # .bin and .png files are not assets
    for name, spec in files.items():
        record = records[name]
        if spec.refuse:
            assert record["status"] == "failed", name
            error = record["error"]
            assert error.startswith(f"{folder / 'in' / name}: ") and spec.refuse in error and "\n" not in error, error
            continue
        report, _ = _baked(corpus, name)
        gltf = report["validation"]["gltf"]
        assert (gltf["errors"], gltf["warnings"]) == (0, 0), (name, gltf)
        assert all(m["inherited"] for m in gltf["messages"]), (name, gltf)
        assert report["validation"]["usd"]["errors"] == 0, name
        assert gltf["input"]["errors"] == gltf["inherited_errors"] + (name == "mislabelled_jpeg.glb"), name


def test_colour_space_png_warning_is_inherited_not_a_failure(corpus):
    report, gltf = _baked(corpus, "box_textured_colorspace.glb")
    v = report["validation"]["gltf"]
    assert (v["errors"], v["warnings"], v["inherited_errors"], v["inherited_warnings"]) == (0, 0, 0, 1)
    (message,) = v["messages"]
    assert (message["code"], message["severity"], message["pointer"], message["inherited"]) == (
        "IMAGE_FEATURES_UNSUPPORTED", "Warning", "/images/0", True)
    assert v["input"]["warnings"] == 1
    assert _image(gltf, 0) == (corpus[1]["box_textured_colorspace.glb"].values["image"], "image/png")
    assert report["screen"] and "screen" in gltf.materials[0].extensions["SSSBAKE_subsurface"]  # baked with a technique too


def test_an_inherited_error_does_not_fail_the_asset(corpus):
    report, gltf = _baked(corpus, "truncated_png.glb")
    v = report["validation"]["gltf"]
    assert (v["errors"], v["inherited_errors"]) == (0, 1)
    assert [(m["code"], m["inherited"]) for m in v["messages"]] == [("IMAGE_UNEXPECTED_EOS", True)]
    assert _image(gltf, 0) == (corpus[1]["truncated_png.glb"].values["image"], "image/png")
    # A JPEG the input calls image/png is written with its real type: the input's error is gone.
    report, gltf = _baked(corpus, "mislabelled_jpeg.glb")
    assert report["validation"]["gltf"]["input"]["errors"] == 1 and report["validation"]["gltf"]["messages"] == []
    assert _image(gltf, 0) == (corpus[1]["mislabelled_jpeg.glb"].values["image"], "image/jpeg")


@pytest.mark.parametrize("name, mime", [("box_textured_jpeg.glb", "image/jpeg"), ("external.gltf", "image/png"),
                                        ("data_uri.gltf", "image/png"), ("webp_fallback.glb", "image/png")])
def test_images_are_copied_byte_for_byte(corpus, name, mime):
    report, gltf = _baked(corpus, name)
    assert _image(gltf, 0) == (corpus[1][name].values["image"], mime)
    assert gltf.materials[0].pbrMetallicRoughness.baseColorTexture.index == 0
    assert gltf.textures[0].source == 0
    # only the thickness texture is added; the WebP alternative (no glTF holds it without its extension) is not
    assert [im.mimeType for im in gltf.images[1:]] == ["image/png"] and "EXT_texture_webp" not in gltf.extensionsUsed
    assert report["validation"]["gltf"]["input"] == {"errors": 0, "warnings": 0, "infos": 0}


def test_texture_transform_survives(corpus):
    _, gltf = _baked(corpus, "texture_transform.glb")
    info = gltf.materials[0].pbrMetallicRoughness.baseColorTexture
    assert info.extensions == {"KHR_texture_transform": corpus[1]["texture_transform.glb"].values["transform"]}
    assert "KHR_texture_transform" in gltf.extensionsUsed and not gltf.extensionsRequired
    prim = gltf.meshes[0].primitives[0]
    box = box24()
    np.testing.assert_array_equal(_rows(_attribute(gltf, prim, "TEXCOORD_0"), _attribute(gltf, prim, "TEXCOORD_1")),
                                  _rows(box["uvs"], box["uvs"] * 0.5))
    assert prim.attributes.TEXCOORD_2 is not None  # the atlas, after the file's two sets
    scene = load_scene(corpus[0] / "in" / "texture_transform.glb")
    ref = scene.materials[0].base_color_texture
    assert (ref.tex_coord, ref.uv_set, ref.transform.rotation, ref.transform.scale) == (0, 1, 0.5, (2.0, 3.0))


@pytest.mark.parametrize("name", ["sparse_substitution.glb", "sparse_no_bufferview.glb", "interleaved.glb"])
def test_sparse_and_interleaved_positions_reach_the_output(corpus, name):
    _, gltf = _baked(corpus, name)
    values = corpus[1][name].values
    prim = gltf.meshes[0].primitives[0]
    positions = _attribute(gltf, prim, "POSITION")
    np.testing.assert_array_equal(_rows(positions), _rows(values["positions"]))
    if name == "sparse_substitution.glb":
        moved = values["positions"][[2, 5, 17]]
        assert np.abs(moved).max() == pytest.approx(0.75)  # the substitutes stick out of the unit box
        assert all((np.abs(positions - m).max(axis=1) == 0).any() for m in moved.astype(np.float32))
    if name == "sparse_no_bufferview.glb":  # COLOR_0: zero but for three sparse values
        colours = _attribute(gltf, prim, "COLOR_0")
        np.testing.assert_array_equal(colours[:, 3], 1.0)
        np.testing.assert_array_equal(_rows(positions, colours[:, :3]),
                                      _rows(values["positions"], values["colors"]))
        assert (colours[:, 0] == 0.5).sum() >= 3
    if name == "interleaved.glb":
        np.testing.assert_array_equal(_rows(positions, _attribute(gltf, prim, "TEXCOORD_0")),
                                      _rows(values["positions"], values["uvs"]))


def test_normalized_uv_sets_and_vertex_colours_round_trip(corpus):
    _, gltf = _baked(corpus, "uv_sets_normalized.glb")
    values = corpus[1]["uv_sets_normalized.glb"].values
    prim = gltf.meshes[0].primitives[0]
    uv0, uv1 = _attribute(gltf, prim, "TEXCOORD_0"), _attribute(gltf, prim, "TEXCOORD_1")
    assert gltf.accessors[prim.attributes.TEXCOORD_1].componentType == 5126  # written as float
    np.testing.assert_array_equal(_rows(uv0, uv1), _rows(values["uv0"], values["uv1"]))
    assert uv1.max() == pytest.approx(0.75, abs=1e-4)
    assert gltf.materials[0].pbrMetallicRoughness.baseColorTexture.texCoord == 1

    _, gltf = _baked(corpus, "vertex_colors.glb")
    expected = corpus[1]["vertex_colors.glb"].values["colors"]
    assert len(gltf.meshes[0].primitives) == 3
    for prim, colours in zip(gltf.meshes[0].primitives, expected):
        out = _attribute(gltf, prim, "COLOR_0")
        assert gltf.accessors[prim.attributes.COLOR_0].type == "VEC4"
        scene_positions = _attribute(gltf, prim, "POSITION")
        np.testing.assert_array_equal(_rows(np.round(scene_positions, 5), out), _rows(
            np.round(_positions_of(corpus, "vertex_colors.glb", prim, gltf), 5), colours))
    alphas = [np.unique(_attribute(gltf, p, "COLOR_0")[:, 3]) for p in gltf.meshes[0].primitives]
    np.testing.assert_allclose(np.concatenate(alphas), [1.0, 200 / 255, 40000 / 65535], rtol=1e-6)


def _positions_of(corpus, name, prim, gltf):
    """The input positions of the input primitive at the same index as `prim` in the output."""
    index = gltf.meshes[0].primitives.index(prim)
    return load_scene(corpus[0] / "in" / name).meshes[0].primitives[index].positions


@pytest.mark.parametrize("name", ["skinned.glb", "morph_targets.glb"])
def test_deforming_meshes_bake_their_rest_pose(corpus, name):
    scene = load_scene(corpus[0] / "in" / name)
    assert scene.meshes[0].deforming
    _, gltf = _baked(corpus, name)
    np.testing.assert_array_equal(_rows(_attribute(gltf, gltf.meshes[0].primitives[0], "POSITION")),
                                  _rows(box24()["positions"]))


def _world(gltf: pygltflib.GLTF2) -> list[np.ndarray]:
    """World matrices of the output's mesh nodes, in node order."""
    parent = {c: i for i, n in enumerate(gltf.nodes) for c in (n.children or [])}

    def local(i):
        m = gltf.nodes[i].matrix
        return np.eye(4) if m is None else np.asarray(m, np.float64).reshape(4, 4).T

    out = []
    for i, node in enumerate(gltf.nodes):
        if node.mesh is None:
            continue
        world, j = local(i), i
        while j in parent:
            j = parent[j]
            world = local(j) @ world
        out.append(world)
    return out


def test_instanced_meshes_bake_once_and_keep_every_instance(corpus):
    report, gltf = _baked(corpus, "instanced_nodes.glb")
    assert len(gltf.meshes) == 1 and list(report["atlas"]) == ["Box"]
    np.testing.assert_array_equal([w[:3, 3] for w in _world(gltf)], [[-1.0, 0.0, 0.0], [1.0, 0.0, 0.0]])
    assert [n.name for n in gltf.nodes] == ["Left", "Right"]

    for name in ("gpu_instancing_used.glb", "gpu_instancing_required.glb"):
        values = corpus[1][name].values
        assert len(load_scene(corpus[0] / "in" / name).mesh_instances()[0]) == 3
        report, gltf = _baked(corpus, name)
        assert len(gltf.meshes) == 1 and list(report["atlas"]) == ["Box"]
        assert "EXT_mesh_gpu_instancing" not in (gltf.extensionsUsed or []) + (gltf.extensionsRequired or [])
        worlds = _world(gltf)
        assert len(worlds) == 3
        for world, t, q in zip(worlds, values["translations"], values["rotations"]):
            np.testing.assert_allclose(world[:3, 3], np.add(values["node_translation"], t), atol=1e-6)
            turned = np.allclose(q, [0.0, np.sqrt(0.5), 0.0, np.sqrt(0.5)])
            # a quarter turn about y takes +x to -z
            np.testing.assert_allclose(world[:3, 0], [0.0, 0.0, -1.0] if turned else [1.0, 0.0, 0.0], atol=1e-6)


def test_draco_is_decoded_and_a_fallback_is_read_as_it_is(corpus, monkeypatch):
    folder, files, _ = corpus
    box = box24()
    for name in ("draco_required.glb", "draco_fallback.glb"):
        prim = load_scene(folder / "in" / name).meshes[0].primitives[0]
        assert prim.faces.shape == (12, 3) and len(prim.positions) == 24
        # 14-bit quantization over the unit box: within 1e-4 of the authored corners
        assert np.abs(np.sort(prim.positions, axis=0) - np.sort(box["positions"], axis=0)).max() < 1e-4
        np.testing.assert_allclose(_rows(prim.positions.round(3), prim.uvs[0]), _rows(box["positions"], box["uvs"]),
                                   atol=1e-3)
        report, gltf = _baked(corpus, name)
        assert DRACO not in (gltf.extensionsUsed or [])
        assert len(_attribute(gltf, gltf.meshes[0].primitives[0], "POSITION")) >= 24
    np.testing.assert_array_equal(load_scene(folder / "in" / "draco_fallback.glb").meshes[0].primitives[0].positions,
                                  files["draco_fallback.glb"].values["decoded_positions"])

    import DracoPy

    def broken(_):
        raise ValueError("corrupt stream")

    monkeypatch.setattr(DracoPy, "decode", broken)
    assert len(load_scene(folder / "in" / "draco_fallback.glb").meshes) == 1  # the fallback needs no decoder
    with pytest.raises(AssetError, match="mesh 0 primitive 0: KHR_draco_mesh_compression data cannot be decoded"):
        load_scene(folder / "in" / "draco_required.glb")
    monkeypatch.setitem(sys.modules, "DracoPy", None)  # not installed
    with pytest.raises(AssetError) as info:
        load_scene(folder / "in" / "draco_required.glb")
    assert str(info.value) == (
        f"{folder / 'in' / 'draco_required.glb'}: {DRACO} is required and not supported (the Python package DracoPy "
        "is not installed); decompress it first (gltf-transform copy in.glb out.glb)")


def test_meshopt_fallback_is_read_and_required_meshopt_is_refused(corpus):
    folder, files, records = corpus
    values = files["meshopt_fallback.glb"].values
    prim = load_scene(folder / "in" / "meshopt_fallback.glb").meshes[0].primitives[0]
    np.testing.assert_array_equal(prim.positions, values["positions"])
    np.testing.assert_array_equal(prim.normals, values["normals"])
    np.testing.assert_array_equal(prim.faces, values["faces"])
    _, gltf = _baked(corpus, "meshopt_fallback.glb")
    assert MESHOPT not in (gltf.extensionsUsed or [])
    np.testing.assert_array_equal(_rows(_attribute(gltf, gltf.meshes[0].primitives[0], "POSITION")),
                                  _rows(values["positions"]))
    assert records["meshopt_required.glb"]["error"] == (
        f"{folder / 'in' / 'meshopt_required.glb'}: {MESHOPT} is required and not supported; "
        "decompress it first (gltfpack -i in.glb -o out.glb -noq)")


def test_an_obj_textures_colour_space_warning_is_inherited(tmp_path):
    """The input is not glTF (no report to compare codes with): the warning is about the OBJ's own
    image (re-encoded by the OBJ reader, its ICC profile kept), so it is inherited all the same."""
    from gltf_corpus import gradient, png

    box = box24(size=10.0)
    (tmp_path / "tex.png").write_bytes(png(gradient(), colour_chunks=True))
    (tmp_path / "box.mtl").write_text("newmtl Wax\nKd 1 1 1\nmap_Kd tex.png\n")
    lines = ["mtllib box.mtl", "usemtl Wax"]
    lines += [f"v {x} {y} {z}" for x, y, z in box["positions"]] + [f"vt {u} {1 - v}" for u, v in box["uvs"]]
    lines += ["f " + " ".join(f"{i + 1}/{i + 1}" for i in face) for face in box["faces"]]
    (tmp_path / "box.obj").write_text("\n".join(lines) + "\n")
    options = BakeOptions(material="marble", scale_mm=10.0, atlas_resolution=64, techniques=())
    result = bake_asset(tmp_path / "box.obj", options, tmp_path / "out", StageCache(None))
    v = result.report["validation"]["gltf"]
    assert (v["errors"], v["warnings"], v["inherited_warnings"]) == (0, 0, 1), v
    assert "input" not in v
    assert [(m["code"], m["pointer"], m["inherited"]) for m in v["messages"]] == [
        ("IMAGE_FEATURES_UNSUPPORTED", "/images/0", True)]


@pytest.mark.skipif(not SHARED_ASSETS.is_dir(), reason="../shared/assets is not here")
@pytest.mark.parametrize("rel", ["duck/Duck.glb", "damaged_helmet/DamagedHelmet.glb",
                                 "cesium_milk_truck/CesiumMilkTruck.glb"])
def test_shared_gltf_assets_bake_with_no_message_of_their_own(tmp_path, rel):
    path = SHARED_ASSETS / rel
    if not path.is_file():
        pytest.skip(f"{path} is not here")
    options = BakeOptions(material="marble", atlas_resolution=64, techniques=())
    report = bake_asset(path, options, tmp_path / path.stem, StageCache(None)).report
    v = report["validation"]["gltf"]
    assert (v["errors"], v["warnings"]) == (0, 0), v["messages"]
    assert v["input"]["errors"] == 0 and report["validation"]["usd"]["errors"] == 0
