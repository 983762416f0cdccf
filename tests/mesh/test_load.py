"""Loader dispatch, the bad-input corpus, OBJ/PLY/STL through trimesh, and the shared test assets."""

import pickle
import struct
from pathlib import Path

import numpy as np
import pytest
from bad_inputs import write_bad_inputs

from sssbake.pipeline.core.errors import AssetError
from sssbake.pipeline.mesh.load import SUPPORTED_EXTENSIONS, load_scene

ASSETS = Path("/work/shared/assets")

QUAD = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [1.0, 1.0, 0.5]])
QUAD_FACES = np.array([[0, 1, 2], [1, 3, 2]])


def test_every_bad_input_is_a_one_line_asset_error(tmp_path):
    expected = write_bad_inputs(tmp_path)
    assert len(expected) >= 16
    problems = []
    for name, needle in expected.items():
        try:
            load_scene(tmp_path / name)
            problems.append(f"{name}: loaded without error")
        except AssetError as e:
            message = str(e)
            if name not in message or needle.lower() not in message.lower() or "\n" in message:
                problems.append(f"{name}: {message!r} lacks {needle!r}")
            if e.path != str(tmp_path / name) or message != f"{e.path}: {e.problem}":
                problems.append(f"{name}: path/problem fields do not make up the message")
    assert not problems, "\n".join(problems)


def test_asset_error_is_one_line_and_pickles():
    e = AssetError("a/b.obj", "first line\n  second line\n")
    assert str(e) == "a/b.obj: first line; second line"
    back = pickle.loads(pickle.dumps(e))
    assert (back.path, back.problem, str(back)) == (e.path, e.problem, str(e))


def test_missing_file_folder_and_extension(tmp_path):
    with pytest.raises(AssetError, match="file not found"):
        load_scene(tmp_path / "nope.obj")
    (tmp_path / "dir.glb").mkdir()
    with pytest.raises(AssetError, match="folder"):
        load_scene(tmp_path / "dir.glb")
    (tmp_path / "x.txt").write_text("v 0 0 0\n")
    with pytest.raises(AssetError, match=r"unsupported file type '\.txt'"):
        load_scene(str(tmp_path / "x.txt"))
    assert set(SUPPORTED_EXTENSIONS) == {".obj", ".ply", ".stl", ".gltf", ".glb", ".usd", ".usda", ".usdc"}


def test_obj_objects_uvs_normals(tmp_path):
    text = (
        "o first\n"
        + "".join(f"v {x} {y} {z}\n" for x, y, z in QUAD)
        + "vt 0 0\nvt 1 0\nvt 0 1\nvt 1 1\nvn 0 0 1\n"
        + "f 1/1/1 2/2/1 3/3/1\nf 2/2/1 4/4/1 3/3/1\n"
        + "o second\nv 5 5 5\nv 6 5 5\nv 5 6 5\nf 5 6 7\n"
    )
    path = tmp_path / "two.OBJ"
    path.write_text(text)
    scene = load_scene(path)
    assert scene.source == str(path) and scene.meters_per_unit is None and scene.up_axis == "Y"
    by_name = {m.name: m.primitives[0] for m in scene.meshes}
    assert set(by_name) == {"first", "second"}
    first, second = by_name["first"], by_name["second"]
    assert first.positions.dtype == np.float64 and first.faces.dtype == np.int64
    # trimesh may reorder corners per unique (v, vt, vn); compare the triangles' coordinates.
    np.testing.assert_allclose(np.sort(first.positions[first.faces].reshape(-1, 3), axis=0),
                               np.sort(QUAD[QUAD_FACES].reshape(-1, 3), axis=0))
    np.testing.assert_allclose(first.normals, np.tile([0.0, 0.0, 1.0], (len(first.positions), 1)))
    # OBJ's v points up; the scene stores glTF's v' = 1 - v, and QUAD's (x, y) is its (u, v).
    np.testing.assert_allclose(first.uvs[0], np.column_stack([first.positions[:, 0], 1 - first.positions[:, 1]]))
    assert second.normals is None and second.uvs == () and second.colors is None
    np.testing.assert_array_equal(second.faces, [[0, 1, 2]])
    assert len(scene.nodes) == 2 and scene.roots == (0, 1)
    for world in scene.world_matrices().values():
        np.testing.assert_array_equal(world, np.eye(4))


def test_obj_materials_and_vertex_colors(tmp_path):
    (tmp_path / "m.mtl").write_text("newmtl wax\nKd 0.8 0.6 0.4\n")
    (tmp_path / "m.obj").write_text(
        "mtllib m.mtl\nusemtl wax\n" + "".join(f"v {x} {y} {z}\n" for x, y, z in QUAD) + "f 1 2 3\nf 2 4 3\n"
    )
    scene = load_scene(tmp_path / "m.obj")
    assert [m.name for m in scene.materials] == ["wax"]
    np.testing.assert_allclose(scene.materials[0].base_color_factor, (0.8, 0.6, 0.4, 1.0), atol=1 / 255)
    assert scene.meshes[0].primitives[0].material == 0
    (tmp_path / "c.obj").write_text("v 0 0 0 1 0 0\nv 1 0 0 0 1 0\nv 0 1 0 0 0 1\nf 1 2 3\n")
    prim = load_scene(tmp_path / "c.obj").meshes[0].primitives[0]
    np.testing.assert_allclose(prim.colors, [[1, 0, 0, 1], [0, 1, 0, 1], [0, 0, 1, 1]])
    assert load_scene(tmp_path / "c.obj").materials == ()


def _ply_with_attributes() -> tuple[bytes, dict]:
    """Binary PLY with normals, UVs, uchar colours and an extra scanner property (like bunny.ply)."""
    n = len(QUAD)
    rng = np.random.default_rng(1)
    values = {
        "normals": rng.normal(size=(n, 3)),
        "uv": rng.uniform(size=(n, 2)),
        "rgba": rng.integers(0, 256, size=(n, 4)),
    }
    vertex = np.zeros(n, dtype=[("p", "<f4", 3), ("n", "<f4", 3), ("uv", "<f4", 2), ("c", "u1", 4), ("confidence", "<f4")])
    vertex["p"], vertex["n"], vertex["uv"], vertex["c"], vertex["confidence"] = (
        QUAD, values["normals"], values["uv"], values["rgba"], 0.5)
    face = np.zeros(len(QUAD_FACES), dtype=[("k", "u1"), ("v", "<i4", 3)])
    face["k"], face["v"] = 3, QUAD_FACES
    header = (
        f"ply\nformat binary_little_endian 1.0\nelement vertex {n}\n"
        + "".join(f"property float {p}\n" for p in ("x", "y", "z", "nx", "ny", "nz", "s", "t"))
        + "".join(f"property uchar {c}\n" for c in ("red", "green", "blue", "alpha"))
        + f"property float confidence\nelement face {len(QUAD_FACES)}\nproperty list uchar int vertex_indices\nend_header\n"
    )
    return header.encode() + vertex.tobytes() + face.tobytes(), values


def test_ply_binary_keeps_attributes(tmp_path):
    data, values = _ply_with_attributes()
    (tmp_path / "a.ply").write_bytes(data)
    scene = load_scene(tmp_path / "a.ply")
    prim = scene.meshes[0].primitives[0]
    np.testing.assert_allclose(prim.positions, QUAD)
    np.testing.assert_array_equal(prim.faces, QUAD_FACES)
    np.testing.assert_allclose(prim.normals, values["normals"].astype(np.float32), rtol=1e-6)
    uv = values["uv"].astype(np.float32)
    np.testing.assert_allclose(prim.uvs[0], np.column_stack([uv[:, 0], 1 - uv[:, 1]]), rtol=1e-6)
    np.testing.assert_allclose(prim.colors, values["rgba"] / 255.0)
    assert prim.uvs[0].dtype == prim.colors.dtype == prim.normals.dtype == np.float64


def test_ply_ascii_without_normals(tmp_path):
    header = ("ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\nproperty float z\n"
              "property float intensity\nelement face 2\nproperty list uchar int vertex_indices\nend_header\n")
    body = "".join(f"{x} {y} {z} 0.7\n" for x, y, z in QUAD) + "3 0 1 2\n3 1 3 2\n"
    (tmp_path / "a.ply").write_text(header + body)
    prim = load_scene(tmp_path / "a.ply").meshes[0].primitives[0]
    np.testing.assert_allclose(prim.positions, QUAD)
    np.testing.assert_array_equal(prim.faces, QUAD_FACES)
    assert prim.normals is None and prim.uvs == () and prim.colors is None


def test_stl_binary_and_ascii(tmp_path):
    records = np.zeros(2, dtype=[("n", "<f4", 3), ("v", "<f4", (3, 3)), ("a", "<u2")])
    records["v"] = QUAD[QUAD_FACES]
    (tmp_path / "b.stl").write_bytes(b"solid but binary".ljust(80, b" ") + struct.pack("<I", 2) + records.tobytes())
    facets = "".join(
        "facet normal 0 0 1\nouter loop\n" + "".join(f"vertex {x} {y} {z}\n" for x, y, z in QUAD[f]) + "endloop\nendfacet\n"
        for f in QUAD_FACES
    )
    (tmp_path / "a.stl").write_text(f"solid quad\n{facets}endsolid quad\n")
    for name in ("a.stl", "b.stl"):
        scene = load_scene(tmp_path / name)
        prim = scene.meshes[0].primitives[0]
        np.testing.assert_allclose(prim.positions[prim.faces], QUAD[QUAD_FACES], err_msg=name)
        assert prim.normals is None and scene.meters_per_unit is None


# Counts from /work/shared/assets/README.md: raw file vertices and faces, for OBJ/PLY per file,
# for glTF per primitive (accessor counts, indices / 3).
ASSET_COUNTS = {
    "teapot/teapot.obj": ([3644], [6320]),
    "hand/hand_closed.obj": ([7993], [15982]),
    "armadillo/armadillo.obj": ([14587], [29170]),
    "stanford_bunny/bunny.ply": ([35947], [69451]),
    "nefertiti/nefertiti-lowres.obj": ([35002], [70000]),
    "dragon/dragon.obj": ([50000], [100000]),
    "dragon/dragon_subdiv1.ply": ([200000], [400000]),
    "duck/Duck.glb": ([2399], [12636 // 3]),
    "damaged_helmet/DamagedHelmet.glb": ([14556], [46356 // 3]),
    "cesium_milk_truck/CesiumMilkTruck.glb": ([1856, 72, 464, 586], None),
}


@pytest.mark.skipif(not ASSETS.is_dir(), reason="shared test assets not present")
@pytest.mark.parametrize("rel", sorted(ASSET_COUNTS))
def test_shared_assets_match_readme(rel):
    scene = load_scene(ASSETS / rel)
    prims = [p for m in scene.meshes for p in m.primitives]
    vertices, faces = ASSET_COUNTS[rel]
    assert [len(p.positions) for p in prims] == vertices
    if faces is not None:
        assert [len(p.faces) for p in prims] == faces
    if rel.endswith(".glb"):
        assert scene.meters_per_unit == 1.0
    else:
        assert scene.meters_per_unit is None and len(scene.nodes) == 1


@pytest.mark.skipif(not ASSETS.is_dir(), reason="shared test assets not present")
def test_shared_gltf_scene_structure():
    truck = load_scene(ASSETS / "cesium_milk_truck/CesiumMilkTruck.glb")
    assert (len(truck.nodes), len(truck.meshes), len(truck.materials)) == (5, 2, 4)
    flattened = sum(len(worlds) * sum(len(p.positions) for p in truck.meshes[m].primitives)
                    for m, worlds in truck.mesh_instances().items())
    assert flattened == 3564
    duck = load_scene(ASSETS / "duck/Duck.glb")
    extent = np.ptp(np.concatenate([p.positions @ w[:3, :3].T + w[:3, 3]
                                    for m, ws in duck.mesh_instances().items() for w in ws
                                    for p in duck.meshes[m].primitives]), axis=0)
    np.testing.assert_allclose(extent, [1.655, 1.54, 1.153], atol=2e-3)
    helmet = load_scene(ASSETS / "damaged_helmet/DamagedHelmet.glb")
    assert len(helmet.images) == 5 and all(im.mime_type == "image/jpeg" for im in helmet.images)
