"""USD and OBJ/PLY/STL loaders: confinement of every route to other files, OBJ/STL index and count
rules, and diagnoses that name the real cause."""

import os
import struct
from pathlib import Path

import numpy as np
import pytest
from bad_inputs import TRIANGLE, TRIANGLE_FACES, _binary_stl

from sssbake.pipeline.cli import main
from sssbake.pipeline.core.errors import AssetError
from sssbake.pipeline.mesh.load import load_scene

MARKER = "SECRETMARKER7f3a"

# A layer whose mesh, if composed, names itself and shifts its points far away.
SECRET_LAYER = f"""#usda 1.0
(
    defaultPrim = "{MARKER}"
)
def Mesh "{MARKER}"
{{
    point3f[] points = [(1000, 0, 0), (1001, 0, 0), (1000, 1, 0)]
    int[] faceVertexCounts = [3]
    int[] faceVertexIndices = [0, 1, 2]
    string secret = "{MARKER}"
}}
"""

OWN_MESH = """
def Mesh "Own"
{
    point3f[] points = [(0, 0, 0), (1, 0, 0), (0, 1, 0)]
    int[] faceVertexCounts = [3]
    int[] faceVertexIndices = [0, 1, 2]
}
"""


def stage(header: str = "", body: str = "") -> str:
    return f"#usda 1.0\n(\n{header}\n)\n{OWN_MESH}\n{body}\n"


@pytest.fixture
def tree(tmp_path):
    """``lib/asset/`` (the asset's folder) and ``private/secret.usda`` beside it."""
    (tmp_path / "lib" / "asset").mkdir(parents=True)
    (tmp_path / "private").mkdir()
    (tmp_path / "private" / "secret.usda").write_text(SECRET_LAYER)
    return tmp_path


def refused(asset: Path, needle: str, allow_roots=()) -> str:
    with pytest.raises(AssetError) as info:
        load_scene(asset, allow_roots)
    message = str(info.value)
    assert message.startswith(f"{asset}: ") and "\n" not in message and needle in message, message
    return message


SECRET = str(Path("..", "..", "private", "secret.usda"))


def usd_routes(tree: Path) -> dict[str, tuple[str, str]]:
    """Name -> (stage text, expected message start) for each way a layer can name another."""
    absolute = str(tree / "private" / "secret.usda")
    return {
        "sublayer": (stage(f"    subLayers = [@{SECRET}@]"), f"sublayer '{SECRET}' (from a.usda) resolves to"),
        "absolute_reference": (stage(body=f'def "R" (\n    references = @{absolute}@\n)\n{{\n}}'),
                               f"reference '{absolute}' (from a.usda) resolves to"),
        "payload": (stage(body=f'def "P" (\n    payload = @{SECRET}@</{MARKER}>\n)\n{{\n}}'),
                    f"payload '{SECRET}' (from a.usda) resolves to"),
        # the variant is not even selected: the walk checks every variant
        "variant_reference": (stage(body=(
            'def Xform "V" (\n    variantSets = "look"\n)\n{\n    variantSet "look" = {\n'
            f'        "other" (\n            references = @{SECRET}@\n        ) {{\n        }}\n    }}\n}}')),
            f"reference '{SECRET}' (from a.usda) resolves to"),
        "expression_sublayer": (stage('    expressionVariables = {\n        string DIR = "../../private"\n    }\n'
                                      '    subLayers = [@`"${DIR}/secret.usda"`@]'),
                                "sublayer '`\"${DIR}/secret.usda\"`' (from a.usda) resolves to"),
        "value_clip": (stage(body=(
            'def Xform "C" (\n    clips = {\n        dictionary default = {\n'
            f'            asset[] assetPaths = [@{SECRET}@]\n            double2[] active = [(0, 0)]\n'
            f'            string primPath = "/{MARKER}"\n        }}\n    }}\n)\n{{\n}}')),
            f"value clip '{SECRET}' (from a.usda) resolves to"),
    }


@pytest.mark.parametrize("route", ["sublayer", "absolute_reference", "payload", "variant_reference",
                                   "expression_sublayer", "value_clip"])
def test_usd_routes_outside_are_refused_and_allow_root_lets_them_in(tree, route):
    text, needle = usd_routes(tree)[route]
    asset = tree / "lib" / "asset" / "a.usda"
    asset.write_text(text)
    message = refused(asset, needle)
    assert f"outside the asset's folder; refused (pass --allow-root {tree / 'private'}" in message
    # With the folder allowed, the same file loads; composed arcs bring the secret mesh in.
    scene = load_scene(asset, (str(tree / "private"),))
    names = {m.name for m in scene.meshes}
    assert "Own" in names
    if route in ("sublayer", "absolute_reference", "payload", "expression_sublayer"):
        assert MARKER in names or any(m.primitives[0].positions[:, 0].min() >= 1000 for m in scene.meshes)


def test_a_nested_layer_is_checked_too_and_named(tree):
    # a.usda -> parts/inner.usda (allowed) -> ../../../private/secret.usda (outside)
    asset = tree / "lib" / "asset" / "a.usda"
    (asset.parent / "parts").mkdir()
    ref = str(Path("..", "..", "..", "private", "secret.usda"))
    (asset.parent / "parts" / "inner.usda").write_text(stage(f"    subLayers = [@{ref}@]"))
    asset.write_text(stage("    subLayers = [@./parts/inner.usda@]"))
    refused(asset, f"sublayer '{ref}' (from {Path('parts', 'inner.usda')}) resolves to")


def test_usd_symlink_beside_the_asset_pointing_out_is_refused(tree):
    asset_dir = tree / "lib" / "asset"
    os.symlink(tree / "private" / "secret.usda", asset_dir / "innocent.usda")
    asset = asset_dir / "a.usda"
    asset.write_text(stage("    subLayers = [@./innocent.usda@]"))
    secret = (tree / "private" / "secret.usda").resolve()
    refused(asset, f"sublayer './innocent.usda' (from a.usda) resolves to {secret}")


def test_usd_template_clips_are_refused(tree):
    asset = tree / "lib" / "asset" / "a.usda"
    asset.write_text(stage(body=(
        'def Xform "C" (\n    clips = {\n        dictionary default = {\n'
        '            asset templateAssetPath = @./clip.#.usda@\n            double templateStartTime = 0\n'
        '            double templateEndTime = 1\n            double templateStride = 1\n'
        '            string primPath = "/C"\n        }\n    }\n)\n{\n}')))
    refused(asset, "value clip set 'default' on </C> in ")


@pytest.mark.parametrize("kind, header, body", [
    ("sublayer", "    subLayers = [@./gone.usda@]", ""),
    ("reference", "", 'def Xform "R" (\n    references = @./gone.usda@\n)\n{\n}'),
    ("payload", "", 'def Xform "P" (\n    payload = @./gone.usda@\n)\n{\n}'),
])
def test_usd_missing_layer_is_named_not_no_meshes(tree, kind, header, body):
    asset = tree / "lib" / "asset" / "a.usda"
    asset.write_text(stage(header, body).replace(OWN_MESH, ""))
    refused(asset, f"{kind} './gone.usda' (from a.usda) not found")


def test_usd_layer_cycle_terminates(tree):
    folder = tree / "lib" / "asset"
    (folder / "a.usda").write_text(stage("    subLayers = [@./b.usda@]"))
    (folder / "b.usda").write_text("#usda 1.0\n(\n    subLayers = [@./a.usda@]\n)\n")
    assert [m.name for m in load_scene(folder / "a.usda").meshes] == ["Own"]


def test_usd_symlinked_asset_reads_beside_its_real_file(tree):
    # an asset library linked into the batch folder: the asset's references sit beside its real file
    store = tree / "store"
    store.mkdir()
    (store / "part.usda").write_text(SECRET_LAYER.replace(MARKER, "Part"))
    (store / "a.usda").write_text(stage("    subLayers = [@./part.usda@]"))
    os.symlink(store, tree / "lib" / "asset" / "linked")
    scene = load_scene(tree / "lib" / "asset" / "linked" / "a.usda")
    assert {m.name for m in scene.meshes} == {"Own", "Part"}


def obj_with(folder: Path, mtl: str, obj_extra: str = "") -> Path:
    (folder / "m.mtl").write_text(mtl)
    asset = folder / "a.obj"
    asset.write_text("mtllib m.mtl\n" + obj_extra + "usemtl skin\n"
                     + "".join(f"v {x} {y} {z}\nvt {x} {y}\n" for x, y, z in TRIANGLE)
                     + "f 1/1 2/2 3/3\nf 2/2 4/4 3/3\n")
    return asset


def png(path: Path, value: int) -> None:
    from PIL import Image

    Image.fromarray(np.full((4, 4, 3), value, np.uint8)).save(path)


def test_obj_texture_in_the_folder_is_read(tree):
    folder = tree / "lib" / "asset"
    png(folder / "skin.png", 200)
    scene = load_scene(obj_with(folder, "newmtl skin\nKd 1 1 1\nmap_Kd skin.png\n"))
    assert len(scene.images) == 1 and scene.materials[0].base_color_texture is not None


@pytest.mark.parametrize("kind", ["mtllib", "absolute_map_Kd", "symlinked_texture"])
def test_obj_references_outside_are_refused(tree, kind):
    folder = tree / "lib" / "asset"
    png(tree / "private" / "face.png", 17)
    if kind == "mtllib":
        asset = folder / "a.obj"
        asset.write_text("mtllib ../../private/x.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
        (tree / "private" / "x.mtl").write_text("newmtl x\nKd 1 0 0\n")
        needle = "material library '../../private/x.mtl' resolves to"
    elif kind == "absolute_map_Kd":
        asset = obj_with(folder, f"newmtl skin\nmap_Kd {tree / 'private' / 'face.png'}\n")
        needle = f"texture '{tree / 'private' / 'face.png'}' resolves to"
    else:
        os.symlink(tree / "private" / "face.png", folder / "skin.png")
        asset = obj_with(folder, "newmtl skin\nmap_Kd skin.png\n")
        needle = "texture 'skin.png' resolves to"
    message = refused(asset, needle)
    assert f"--allow-root {tree / 'private'}" in message
    scene = load_scene(asset, (str(tree / "private"),))
    assert len(scene.meshes) == 1


def test_ply_texture_file_outside_is_refused(tree):
    png(tree / "private" / "face.png", 17)
    asset = tree / "lib" / "asset" / "a.ply"
    asset.write_text("ply\nformat ascii 1.0\ncomment TextureFile ../../private/face.png\n"
                     "element vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
                     "property float s\nproperty float t\nelement face 1\nproperty list uchar int vertex_indices\n"
                     "end_header\n0 0 0 0 0\n1 0 0 1 0\n0 1 0 0 1\n3 0 1 2\n")
    refused(asset, "texture '../../private/face.png' resolves to")


@pytest.mark.parametrize("faces, line", [
    ("f 1 2 0\n", 5), ("f 1/0 2/1 3/1\n", 5), ("f 1//0 2//1 3//1\n", 5), ("f 2 3 4\n  f 00 1 2\n", 6),
])
def test_obj_face_index_zero_is_refused(tmp_path, faces, line):
    asset = tmp_path / "z.obj"
    asset.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\n" + faces)
    refused(asset, f"face index 0 on line {line}: OBJ indices start at 1")


def test_obj_negative_and_ten_are_not_zero(tmp_path):
    asset = tmp_path / "ok.obj"
    asset.write_text("".join(f"v {i} 0 {i % 2}\n" for i in range(10)) + "vn 0 0 1\nf 10//1 -1//1 -2//-1\nf 1 2 3\n")
    faces = load_scene(asset).meshes[0].primitives[0].faces
    assert len(faces) == 2


def test_stl_header_undercount_is_diagnosed(tmp_path):
    good = _binary_stl(TRIANGLE, TRIANGLE_FACES)
    under = tmp_path / "under.stl"
    under.write_bytes(good[:80] + struct.pack("<I", 1) + good[84:])
    refused(under, "header declares 1 triangle (134 bytes) but the file holds 2 triangles (184 bytes)")
    extra = tmp_path / "extra.stl"
    extra.write_bytes(good + b"\0" * 7)
    refused(extra, "header declares 2 triangles (184 bytes) but the file holds 2 triangles and 7 more bytes")
    # a binary STL whose 80-byte header starts with "solid" is still judged as binary
    solid = tmp_path / "solid.stl"
    solid.write_bytes(b"solid binary".ljust(80, b" ") + struct.pack("<I", 0) + good[84:])
    refused(solid, "header declares 0 triangles (84 bytes) but the file holds 2 triangles")
    ok = tmp_path / "ok.stl"
    ok.write_bytes(b"solid binary".ljust(80, b" ") + good[80:])
    assert len(load_scene(ok).meshes[0].primitives[0].faces) == 2


def all_bytes(folder: Path) -> bytes:
    return b"".join(p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file())


def test_bake_reads_nothing_outside(tree, capsys):
    """End to end: the refused asset fails alone and no output or cache file holds the secret."""
    src = tree / "lib" / "asset"
    routes = usd_routes(tree)
    for route in ("sublayer", "payload", "value_clip"):
        (src / f"{route}.usda").write_text(routes[route][0])
    (src / "good.obj").write_text("".join(f"v {x} {y} {z}\n" for x, y, z in TRIANGLE) + "f 1 2 3\nf 2 4 3\n")
    out = tree / "out"
    cache = tree / "cache"
    code = main(["bake", str(src), "-o", str(out), "--scale-mm", "1", "--cache-dir", str(cache),
                 "--techniques", "none", "-q"])
    assert code == 1
    err = capsys.readouterr().err
    for route in ("sublayer", "payload", "value_clip"):
        assert f"{route}.usda: " in err and "--allow-root" in err
        assert not list(out.glob(f"{route}.*"))
    assert (out / "good.glb").exists()
    assert MARKER.encode() not in all_bytes(out) + all_bytes(cache)
    # The control: allowed, the secret mesh is baked and its name is found in the outputs.
    code = main(["bake", str(src / "sublayer.usda"), "-o", str(tree / "out2"), "--scale-mm", "1",
                 "--cache-dir", str(cache), "--techniques", "none", "--allow-root", str(tree / "private"), "-q"])
    assert code == 0
    assert MARKER.encode() in all_bytes(tree / "out2")


def test_symlinked_asset_files_read_beside_their_real_file(tree):
    """A linked asset file (not folder): its companions sit beside the real file."""
    store = tree / "store"
    store.mkdir()
    (store / "part.usda").write_text(SECRET_LAYER.replace(MARKER, "Part"))
    (store / "a.usda").write_text(stage("    subLayers = [@./part.usda@]"))
    png(store / "skin.png", 90)
    obj_with(store, "newmtl skin\nmap_Kd skin.png\n")
    folder = tree / "lib" / "asset"
    for name in ("a.usda", "a.obj"):
        os.symlink(store / name, folder / name)
    assert {m.name for m in load_scene(folder / "a.usda").meshes} == {"Own", "Part"}
    scene = load_scene(folder / "a.obj")
    assert len(scene.images) == 1 and scene.source == str(folder / "a.obj")
