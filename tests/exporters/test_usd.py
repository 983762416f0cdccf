"""USD export: geometry, sssbake primvars, materials and stage metadata survive a round trip."""

import json
from dataclasses import replace

import numpy as np
import pytest
import trimesh
from fixtures import FALLBACK
from pxr import Usd, UsdGeom, UsdShade

from sssbake.exporters.gltf import dequantize, quantize
from sssbake.exporters.usd import meters_per_unit, primvar_values, technique_data, write_usdc
from sssbake.pipeline.core.materials import preset
from sssbake.pipeline.mesh.baked import SCHEMA_VERSION, BakedAsset, ScatteringMaterial, VertexAttribute
from sssbake.pipeline.mesh.scene import Mesh, Node, Primitive, Scene, SourceMaterial


def icosphere_asset(subdivisions: int = 1, extras: dict | None = None) -> BakedAsset:
    """A marble icosphere (mesh 0, translucent material 0, attributes ``thickness`` (n,) and
    ``direction`` (n, 3)) under a scaled root node, and an opaque triangle (mesh 1, material 1) in a
    translated child node."""
    sphere = trimesh.creation.icosphere(subdivisions=subdivisions)
    v = np.asarray(sphere.vertices, dtype=np.float64)
    n = len(v)
    uv0 = np.c_[0.5 + np.arctan2(v[:, 1], v[:, 0]) / (2 * np.pi), 0.5 - np.arcsin(np.clip(v[:, 2], -1, 1)) / np.pi]
    sphere_prim = Primitive(v, np.asarray(sphere.faces), normals=np.asarray(sphere.vertex_normals) * 3.0,
                            uvs=(uv0, uv0 * 0.5 + 0.25), colors=np.c_[np.abs(v), np.linspace(0, 1, n)], material=0)
    tri = Primitive(np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]]), np.array([[0, 1, 2]]),
                    normals=np.array([[0.0, 0, 1]] * 3), uvs=(np.array([[0.0, 0], [1, 0], [0, 1]]),), material=1)
    child = np.eye(4)
    child[:3, 3] = (3.0, -1.0, 0.5)
    scene = Scene(
        source="memory",
        meshes=(Mesh("sphere", (sphere_prim,)), Mesh("plate", (tri,))),
        nodes=(Node("root", np.diag([2.0, 2.0, 2.0, 1.0]), mesh=0, children=(1,)), Node("plate", child, mesh=1)),
        roots=(0,),
        materials=(
            SourceMaterial("Marble", base_color_factor=(0.2, 0.3, 0.4, 1.0), roughness_factor=0.3),
            SourceMaterial("Steel", base_color_factor=(0.5, 0.5, 0.5, 0.8), metallic_factor=1.0,
                           emissive_factor=(0.1, 0.2, 0.3), double_sided=True, ior=1.4),
        ),
    )
    t = np.linspace(0.0, 1.0, n)
    attrs = (
        VertexAttribute("thickness", 2.0 * np.sin(7 * t) ** 2, "mm", "float32", "thickness along -n"),
        VertexAttribute("direction", np.c_[np.cos(5 * t), -np.sin(3 * t), t * 2 - 1], "", "snorm8", "unit vector"),
    )
    return BakedAsset(
        scene=scene,
        vertex_attributes={(0, 0): attrs},
        scattering={0: ScatteringMaterial(preset("marble"), FALLBACK, "Marble")},
        scale_mm={0: 10.0, 1: 10.0},
        extras={"scaleSource": "test", "thickness": {"unit": "mm"}} if extras is None else extras,
    )


def with_attributes(asset: BakedAsset, *attrs: VertexAttribute) -> BakedAsset:
    return replace(asset, vertex_attributes={(0, 0): attrs})


def test_geometry_and_primvars_round_trip_exactly(tmp_path):
    asset = icosphere_asset()
    summary = write_usdc(asset, tmp_path / "marble.usdc")
    stage = Usd.Stage.Open(str(tmp_path / "marble.usdc"))
    prim_in = asset.scene.meshes[0].primitives[0]
    n = len(prim_in.positions)
    mesh = UsdGeom.Mesh(stage.GetPrimAtPath("/marble/root/sphere"))
    assert mesh

    points = np.asarray(mesh.GetPointsAttr().Get())
    np.testing.assert_array_equal(points, prim_in.positions.astype(np.float32))
    np.testing.assert_array_equal(np.asarray(mesh.GetFaceVertexIndicesAttr().Get()), prim_in.faces.reshape(-1))
    np.testing.assert_array_equal(np.asarray(mesh.GetFaceVertexCountsAttr().Get()), np.full(len(prim_in.faces), 3))
    normals = prim_in.normals / np.linalg.norm(prim_in.normals, axis=1, keepdims=True)
    np.testing.assert_array_equal(np.asarray(mesh.GetNormalsAttr().Get()), normals.astype(np.float32))
    assert mesh.GetNormalsInterpolation() == UsdGeom.Tokens.vertex
    assert mesh.GetSubdivisionSchemeAttr().Get() == UsdGeom.Tokens.none
    np.testing.assert_array_equal(np.asarray(mesh.GetExtentAttr().Get()),
                                  [points.min(axis=0), points.max(axis=0)])

    api = UsdGeom.PrimvarsAPI(mesh)
    for name, uv in (("st", prim_in.uvs[0]), ("st1", prim_in.uvs[1])):
        pv = api.GetPrimvar(name)
        assert pv.GetInterpolation() == UsdGeom.Tokens.vertex and str(pv.GetTypeName()) == "texCoord2f[]"
        uv32 = uv.astype(np.float32)
        np.testing.assert_array_equal(np.asarray(pv.Get()), np.c_[uv32[:, 0], np.float32(1) - uv32[:, 1]])
    np.testing.assert_array_equal(np.asarray(api.GetPrimvar("displayColor").Get()),
                                  prim_in.colors[:, :3].astype(np.float32))

    thickness, direction = asset.vertex_attributes[(0, 0)]
    pv = api.GetPrimvar("sss:thickness")
    assert pv.GetName() == thickness.usd_name == "primvars:sss:thickness"
    assert str(pv.GetTypeName()) == "float[]" and pv.GetInterpolation() == UsdGeom.Tokens.vertex
    assert pv.GetElementSize() == 1 and not pv.HasAuthoredElementSize()
    np.testing.assert_array_equal(np.asarray(pv.Get()), thickness.data.astype(np.float32))
    assert pv.GetAttr().GetCustomData() == {"unit": "mm", "description": "thickness along -n", "encoding": "float32",
                                            "components": 1, "gltfName": "_THICKNESS"}
    assert pv.GetAttr().GetDocumentation() == "thickness along -n"
    np.testing.assert_array_equal(primvar_values(pv), thickness.data.astype(np.float32)[:, None])
    # three snorm8 codes packed into one int (what the glTF accessor stores), kept by Blender's importer
    pv = api.GetPrimvar("sss:direction")
    assert str(pv.GetTypeName()) == "int[]" and pv.GetElementSize() == 1 and len(pv.Get()) == n
    assert pv.GetAttr().GetCustomData()["packedBits"] == 8
    codes = np.round(direction.data * 127).astype(np.int64)
    first = np.asarray(pv.Get()).astype(np.int64) % 256
    np.testing.assert_array_equal(first, codes[:, 0] % 256)
    np.testing.assert_array_equal(primvar_values(pv), dequantize(quantize(direction.data, "snorm8"), True))
    assert mesh.GetPrim().GetAttribute("sss:scaleMm").Get() == 10.0

    assert summary["vertices"] == n + 3 and summary["faces"] == len(prim_in.faces) + 1
    assert summary["blocks"]["primvars:sss:thickness"] == 4 * n
    assert summary["blocks"]["primvars:sss:direction"] == 4 * n
    assert summary["bytes_per_vertex"]["primvars:sss:direction"] == 4.0
    assert summary["bytes_per_vertex"]["sssbake"] == pytest.approx(8 * n / (n + 3))
    assert summary["bytes"] == (tmp_path / "marble.usdc").stat().st_size
    assert (tmp_path / "marble.usdc").read_bytes()[:8] == b"PXR-USDC"


def test_stage_metadata_hierarchy_and_extras(tmp_path):
    asset = icosphere_asset(extras={"lut": np.arange(6.0).reshape(3, 2), "ids": np.array([1, 2]), "k": 1.5})
    write_usdc(asset, tmp_path / "a b-1.usdc")
    stage = Usd.Stage.Open(str(tmp_path / "a b-1.usdc"))
    root = stage.GetDefaultPrim()
    assert root.GetName() == "a_b_1" and root.IsA(UsdGeom.Xform)
    assert Usd.ModelAPI(root).GetKind() == "component"
    assert UsdGeom.GetStageUpAxis(stage) == UsdGeom.Tokens.y
    assert UsdGeom.StageHasAuthoredMetersPerUnit(stage) and UsdGeom.GetStageMetersPerUnit(stage) == 0.01
    assert root.GetAttribute("sss:schemaVersion").Get() == SCHEMA_VERSION

    extras = json.loads(root.GetAttribute("sss:extras").Get())
    assert extras["k"] == 1.5
    assert extras["lut"]["attribute"] == "sss:lut" and extras["lut"]["shape"] == [3, 2]
    lut = root.GetAttribute("sss:lut")
    assert str(lut.GetTypeName()) == "float2[]" and lut.GetCustomData()["dtype"] == "float32"
    np.testing.assert_array_equal(np.asarray(lut.Get()), np.arange(6.0).reshape(3, 2))
    assert str(root.GetAttribute(extras["ids"]["attribute"]).GetTypeName()) == "int[]"

    worlds = asset.scene.world_matrices()
    cache = UsdGeom.XformCache()
    for index, path in ((0, "/a_b_1/root"), (1, "/a_b_1/root/plate")):
        usd = np.array(cache.GetLocalToWorldTransform(stage.GetPrimAtPath(path)))
        np.testing.assert_array_equal(usd.T, worlds[index])
    assert stage.GetPrimAtPath("/a_b_1/root/plate/plate").IsA(UsdGeom.Mesh)


def test_materials_and_bindings(tmp_path):
    write_usdc(icosphere_asset(), tmp_path / "m.usdc")
    stage = Usd.Stage.Open(str(tmp_path / "m.usdc"))
    sphere = stage.GetPrimAtPath("/m/root/sphere")
    plate = stage.GetPrimAtPath("/m/root/plate/plate")
    assert sphere.HasAPI(UsdShade.MaterialBindingAPI) and plate.HasAPI(UsdShade.MaterialBindingAPI)
    marble = UsdShade.MaterialBindingAPI(sphere).ComputeBoundMaterial()[0]
    steel = UsdShade.MaterialBindingAPI(plate).ComputeBoundMaterial()[0]
    assert marble.GetPath() == "/m/Materials/Marble" and steel.GetPath() == "/m/Materials/Steel"

    shader = marble.ComputeSurfaceSource()[0]
    assert shader.GetIdAttr().Get() == "UsdPreviewSurface"
    np.testing.assert_array_equal(shader.GetInput("diffuseColor").Get(), np.float32(FALLBACK.base_color))
    assert shader.GetInput("roughness").Get() == np.float32(0.3) and shader.GetInput("ior").Get() == 1.5
    m = marble.GetPrim()
    mat = preset("marble")
    assert m.GetAttribute("sss:schemaVersion").Get() == SCHEMA_VERSION
    assert m.GetAttribute("sss:units").Get() == "1/mm"
    np.testing.assert_array_equal(m.GetAttribute("sss:sigmaSPrime").Get(), np.float32(mat.sigma_s_prime))
    np.testing.assert_array_equal(m.GetAttribute("sss:sigmaA").Get(), np.float32(mat.sigma_a))
    assert m.GetAttribute("sss:eta").Get() == np.float32(mat.eta)
    assert m.GetAttribute("sss:fallback:thicknessFactor").Get() == 2.0
    assert m.GetAttribute("sss:fallback:attenuationDistance").Get() == 4.0
    np.testing.assert_array_equal(m.GetAttribute("sss:fallback:attenuationColor").Get(), np.float32((0.9, 0.8, 0.7)))
    assert not UsdGeom.Mesh(sphere).GetDoubleSidedAttr().Get()

    s = steel.ComputeSurfaceSource()[0]
    np.testing.assert_array_equal(s.GetInput("diffuseColor").Get(), np.float32((0.5, 0.5, 0.5)))
    assert s.GetInput("opacity").Get() == np.float32(0.8) and s.GetInput("metallic").Get() == 1.0
    assert s.GetInput("ior").Get() == np.float32(1.4)
    assert not steel.GetPrim().GetAttribute("sss:sigmaA")
    assert UsdGeom.Mesh(plate).GetDoubleSidedAttr().Get()


def test_infinite_attenuation_distance_is_left_out(tmp_path):
    asset = icosphere_asset()
    fb = replace(FALLBACK, attenuation_distance=float("inf"))
    asset = replace(asset, scattering={0: ScatteringMaterial(preset("marble"), fb, "Marble")})
    write_usdc(asset, tmp_path / "a.usdc")
    stage = Usd.Stage.Open(str(tmp_path / "a.usdc"))
    m = stage.GetPrimAtPath("/a/Materials/Marble")
    assert not m.GetAttribute("sss:fallback:attenuationDistance").HasAuthoredValue()


def test_meters_per_unit_and_up_axis(tmp_path):
    asset = icosphere_asset()
    assert meters_per_unit(asset) == 0.01
    assert meters_per_unit(replace(asset, scene=replace(asset.scene, meters_per_unit=0.0254))) == 0.0254
    assert meters_per_unit(replace(asset, scale_mm={})) == 1.0
    z_up = replace(asset, scene=replace(asset.scene, up_axis="Z", meters_per_unit=1.0))
    write_usdc(z_up, tmp_path / "z.usdc")
    stage = Usd.Stage.Open(str(tmp_path / "z.usdc"))
    assert UsdGeom.GetStageUpAxis(stage) == UsdGeom.Tokens.z and UsdGeom.GetStageMetersPerUnit(stage) == 1.0


def test_names_are_made_valid_and_unique(tmp_path):
    asset = icosphere_asset()
    scene = asset.scene
    nodes = (replace(scene.nodes[0], name="1 bad name", children=(1, 2)), replace(scene.nodes[1], name="x"),
             replace(scene.nodes[1], name="x"))
    scene = replace(scene, nodes=nodes, materials=(replace(scene.materials[0], name="a"),
                                                   replace(scene.materials[1], name="a")))
    write_usdc(replace(asset, scene=scene), tmp_path / "n.usdc")
    stage = Usd.Stage.Open(str(tmp_path / "n.usdc"))
    assert stage.GetPrimAtPath("/n/_1_bad_name/x/plate") and stage.GetPrimAtPath("/n/_1_bad_name/x_1/plate")
    assert stage.GetPrimAtPath("/n/Materials/a") and stage.GetPrimAtPath("/n/Materials/a_1")


@pytest.mark.parametrize("data", [np.ones(5), np.ones((7, 3))], ids=["short", "long"])
def test_element_count_mismatch_raises(tmp_path, data):
    asset = with_attributes(icosphere_asset(), VertexAttribute("bad", data))
    with pytest.raises(ValueError, match=r"primvars:sss:bad has \d+ elements, expected 42 points"):
        write_usdc(asset, tmp_path / "a.usdc")
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("what", ["attribute", "position", "scale", "material", "overflow"])
def test_non_finite_raises_and_leaves_nothing(tmp_path, what):
    asset = icosphere_asset()
    n = len(asset.scene.meshes[0].primitives[0].positions)
    if what == "attribute":
        asset = with_attributes(asset, VertexAttribute("t", np.r_[np.nan, np.ones(n - 1)]))
    elif what == "overflow":
        asset = with_attributes(asset, VertexAttribute("t", np.r_[1e39, np.ones(n - 1)]))
    elif what == "position":
        prim = asset.scene.meshes[1].primitives[0]
        bad = replace(prim, positions=np.r_[prim.positions[:2], [[np.inf, 0, 0]]])
        asset = replace(asset, scene=replace(asset.scene, meshes=(asset.scene.meshes[0], Mesh("plate", (bad,)))))
    elif what == "scale":
        asset = replace(asset, scale_mm={0: float("nan")})
    else:
        fb = replace(FALLBACK, thickness_factor=float("inf"))
        asset = replace(asset, scattering={0: ScatteringMaterial(preset("marble"), fb, "Marble")})
    with pytest.raises(ValueError, match="not finite|non-finite"):
        write_usdc(asset, tmp_path / "a.usdc")
    assert list(tmp_path.iterdir()) == []


def test_failed_write_keeps_previous_file(tmp_path):
    target = tmp_path / "a.usdc"
    write_usdc(icosphere_asset(), target)
    before = target.read_bytes()
    with pytest.raises(ValueError):
        write_usdc(with_attributes(icosphere_asset(), VertexAttribute("t", np.full(42, np.nan))), target)
    assert target.read_bytes() == before and [p.name for p in tmp_path.iterdir()] == ["a.usdc"]


def test_bad_references_raise(tmp_path):
    asset = icosphere_asset()
    with pytest.raises(ValueError, match="mesh 5 primitive 0"):
        write_usdc(replace(asset, vertex_attributes={(5, 0): ()}), tmp_path / "a.usdc")
    with pytest.raises(ValueError, match=r"materials \[7\]"):
        write_usdc(replace(asset, scattering={7: asset.scattering[0]}), tmp_path / "a.usdc")
    prim = asset.scene.meshes[1].primitives[0]
    bad = replace(prim, faces=np.array([[0, 1, 3]]))
    with pytest.raises(ValueError, match="face indices outside"):
        write_usdc(replace(asset, scene=replace(asset.scene, meshes=(asset.scene.meshes[0], Mesh("p", (bad,))))),
                   tmp_path / "a.usdc")
    assert list(tmp_path.iterdir()) == []


def test_mesh_extras_tables_and_integer_primvars(tmp_path):
    asset = icosphere_asset()
    n = len(asset.scene.meshes[0].primitives[0].positions)
    codes = (np.arange(24) % 256).astype(np.uint8).reshape(8, 3)
    index = VertexAttribute("sss:prt:ref", np.c_[np.arange(n) % 5, np.full(n, 65535)], "", "uint16", "indices")
    asset = replace(asset, vertex_attributes={(0, 0): (index,)},
                    mesh_extras={0: {"prt": {"codes": codes, "scale": np.array([0.5, -2.0]), "order": 2}}})
    write_usdc(asset, tmp_path / "m.usdc")
    stage = Usd.Stage.Open(str(tmp_path / "m.usdc"))
    prim = stage.GetPrimAtPath("/m/root/sphere")
    extras = json.loads(prim.GetAttribute("sss:extras").Get())
    assert extras["prt"]["order"] == 2
    assert extras["prt"]["codes"]["attribute"] == "sss:prt:codes"
    table = prim.GetAttribute("sss:prt:codes")
    assert str(table.GetTypeName()) == "int[]"  # compressed on disk, unlike uchar[]
    np.testing.assert_array_equal(np.asarray(table.Get()).reshape(extras["prt"]["codes"]["shape"]), codes)
    tables, _ = technique_data(prim, "prt")
    assert tables["codes"].dtype == np.uint8
    np.testing.assert_array_equal(tables["codes"], codes)
    # two uint16 in one int (4 bytes, as glTF's VEC2 uint16): lo + 65536 hi
    primvar = UsdGeom.PrimvarsAPI(prim).GetPrimvar("sss:prt:ref")
    assert str(primvar.GetTypeName()) == "int[]" and primvar.GetElementSize() == 1
    np.testing.assert_array_equal(np.asarray(primvar.Get()).view(np.uint32), index.data[:, 0] + 65536 * index.data[:, 1])
    np.testing.assert_array_equal(primvar_values(primvar), index.data)


def test_spectral_normal_primvar_and_tables(tmp_path):
    from test_gltf import spectral_parts

    from sssbake.exporters.usd import technique_data, technique_tables

    asset = icosphere_asset()
    normals, attrs, tables = spectral_parts(asset.scene.meshes[0].primitives[0])
    write_usdc(replace(asset, vertex_attributes={(0, 0): attrs}, mesh_extras={0: {"spectral": tables}}),
               tmp_path / "s.usdc")
    stage = Usd.Stage.Open(str(tmp_path / "s.usdc"))  # held: its prims die with it
    prim = stage.GetPrimAtPath("/s/root/sphere")
    primvar = UsdGeom.PrimvarsAPI(prim).GetPrimvar("sss:normal")
    values = np.asarray(primvar.Get())
    assert str(primvar.GetTypeName()) == "normal3f[]" and primvar.GetElementSize() == 1
    assert primvar.GetInterpolation() == UsdGeom.Tokens.vertex and values.shape == (len(normals), 3)
    np.testing.assert_array_equal(values, normals.astype(np.float32))
    # the JSON names primvars; technique_data maps them back to the glTF names the layout uses
    assert technique_tables(prim, "spectral")["attributes"] == {"normal": "primvars:sss:normal",
                                                                "vertex": "primvars:sss:spectral:vertex"}
    read, per_vertex = technique_data(prim, "spectral")
    for name, value in tables.items():
        np.testing.assert_array_equal(read[name], value)
    np.testing.assert_array_equal(per_vertex["_SSS_NORMAL"], normals.astype(np.float32))


def test_screen_tables_are_attributes_of_the_material_prim(tmp_path):
    from fixtures import bake_screen_sphere, baked_material

    from sssbake.exporters.usd import technique_tables
    from sssbake.pipeline.techniques.screen.samples import screen_samples

    result, options = bake_screen_sphere(tmp_path, screen_uniform=0)
    stage = Usd.Stage.Open(str(tmp_path / "ball.usdc"))  # held: its prims die with it
    (material,) = [p for p in stage.Traverse() if p.IsA(UsdShade.Material) and p.GetAttribute("sss:extras")]
    expected = screen_samples(baked_material(result), options.technique_options("screen").samples_options())
    for name, value, type_name in (("offsets", expected.offsets, "float2[]"), ("weights", expected.weights, "float[]"),
                                   ("rdTable", expected.table.T, "float3[]")):
        attribute = material.GetAttribute("sss:screen:" + name)
        assert str(attribute.GetTypeName()) == type_name
        assert list(attribute.GetCustomData()["shape"]) == list(value.shape)
        np.testing.assert_array_equal(np.asarray(attribute.Get()), value.astype(np.float32))
    tables = technique_tables(material, "screen")
    assert (tables["technique"], tables["samples"], tables["uniform"]) == ("screen", options.screen_samples, 0)
    np.testing.assert_array_equal(tables["weights"], expected.weights.astype(np.float32))
    assert tables["tableError"] == expected.table_error
    assert material.GetAttribute("sss:materialName").Get() == "marble"


@pytest.mark.parametrize("encoding, k, usd_type, element_size, packed", [
    ("uint8", 1, "uchar[]", 1, None), ("uint8", 4, "int[]", 1, 8), ("snorm8", 3, "int[]", 1, 8),
    ("unorm8", 2, "int[]", 1, 8), ("uint16", 1, "int[]", 1, None), ("uint16", 2, "int[]", 1, 16),
    ("snorm16", 2, "int[]", 1, 16), ("uint16", 3, "int[]", 3, None), ("unorm16", 3, "float3[]", 1, None),
    ("snorm8", 6, "float[]", 6, None), ("float32", 2, "float2[]", 1, None), ("float32", 4, "float4[]", 1, None),
    ("float32", 5, "float[]", 5, None),
])
def test_each_encoding_reads_back_as_gltf_decodes_it(tmp_path, encoding, k, usd_type, element_size, packed):
    n = 42
    rng = np.random.default_rng(k)
    if encoding.startswith("uint"):
        top = 255 if encoding == "uint8" else 65535
        data = rng.integers(0, top + 1, size=(n, k)).astype(np.float64)
        data[0] = top  # the sign bit of a packed int
    else:
        data = rng.uniform(-1.0 if encoding.startswith("s") else 0.0, 1.0, size=(n, k))
        if encoding.startswith("snorm"):
            data[0] = -1.0
    attribute = VertexAttribute("x", data[:, 0] if k == 1 else data, "", encoding, "")
    write_usdc(with_attributes(icosphere_asset(), attribute), tmp_path / "a.usdc")
    stage = Usd.Stage.Open(str(tmp_path / "a.usdc"))
    pv = UsdGeom.PrimvarsAPI(stage.GetPrimAtPath("/a/root/sphere")).GetPrimvar("sss:x")
    assert (str(pv.GetTypeName()), pv.GetElementSize()) == (usd_type, element_size)
    assert pv.GetAttr().GetCustomData().get("packedBits") == packed
    expected = dequantize(quantize(data, encoding), encoding[1:5] == "norm")
    if usd_type.startswith("float"):  # float32 values: the decoded codes rounded once more
        expected = expected.astype(np.float32)
    np.testing.assert_array_equal(primvar_values(pv), expected)


def test_a_deep_hierarchy_is_cut_at_max_depth_and_keeps_world_transforms(tmp_path):
    """A 3,000-node chain with a mesh at nodes on both sides of the cut and at the leaf: no node level
    past `MAX_USD_DEPTH` (deeper nodes sit beside their ancestor at that level), every node written, and
    each mesh's world transform as USD composes it is the scene's, bit for bit (quarter-turns, halvings,
    doublings and quarter-unit translations: every product is exact, so a wrong order of composition shows)."""
    from sssbake.exporters.usd import MAX_USD_DEPTH

    n = 3000
    turn = np.array([[0.0, -1, 0, 0], [1, 0, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]])
    matrices = []
    for i in range(n):
        m = turn.copy() if i % 5 == 0 else np.eye(4)
        m[:3, :3] *= 2.0 if i % 11 == 0 else 0.5 if i % 11 == 5 else 1.0
        m[:3, 3] = (i % 7 - 3.0, 0.25 * (i % 2), -0.5 * (i % 3))
        matrices.append(m)
    with_mesh = {MAX_USD_DEPTH - 2, MAX_USD_DEPTH - 1, MAX_USD_DEPTH, MAX_USD_DEPTH + 1, 1000, 2500, n - 1}
    tri = Primitive(np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]]), np.array([[0, 1, 2]]))
    nodes = tuple(Node(f"link{i}", matrices[i], mesh=0 if i in with_mesh else None,
                       children=(i + 1,) if i + 1 < n else ()) for i in range(n))
    scene = Scene(source="memory", meshes=(Mesh("tri", (tri,)),), nodes=nodes, roots=(0,), materials=())
    write_usdc(BakedAsset(scene=scene, vertex_attributes={}, scattering={}, scale_mm={}, extras={}),
               tmp_path / "chain.usdc")

    stage = Usd.Stage.Open(str(tmp_path / "chain.usdc"))
    xforms = [p for p in stage.Traverse() if p.IsA(UsdGeom.Xform) and p != stage.GetDefaultPrim()]
    assert len(xforms) == n
    assert max(p.GetPath().pathElementCount for p in xforms) == 1 + MAX_USD_DEPTH  # the root prim's level, then nodes
    world = np.eye(4)
    worlds = []
    for m in matrices:
        world = world @ m
        worlds.append(world)
    meshes = [p for p in stage.Traverse() if p.IsA(UsdGeom.Mesh)]
    assert sorted(int(p.GetParent().GetName().removeprefix("link")) for p in meshes) == sorted(with_mesh)
    for prim in meshes:
        i = int(prim.GetParent().GetName().removeprefix("link"))
        usd = np.array(UsdGeom.Xformable(prim).ComputeLocalToWorldTransform(Usd.TimeCode.Default()))
        np.testing.assert_array_equal(usd.T, worlds[i], err_msg=f"node {i}")


def test_a_deep_chain_bakes_with_its_world_transform_in_both_outputs(tmp_path, capsys):
    """`sssbake bake` of a 3,000-node glTF chain (its mesh at the leaf): rc 0, and the mesh's world
    transform in the .usdc and the .glb is the sum of the translations."""
    from bad_inputs import node_chain_gltf
    from fixtures import FAST_DEFAULTS

    from sssbake.pipeline.cli import main
    from sssbake.pipeline.mesh.load import load_scene

    i = np.arange(3000)
    translations = np.column_stack([i % 7 - 3.0, 0.25 * (i % 2), -0.5 * (i % 3)])
    src, out = tmp_path / "in", tmp_path / "out"
    src.mkdir()
    (src / "chain.gltf").write_text(json.dumps(node_chain_gltf(translations)))
    (tmp_path / "fast.toml").write_text(FAST_DEFAULTS)
    assert main(["bake", str(src), "-o", str(out), "--config", str(tmp_path / "fast.toml"), "--no-cache", "-q"]) == 0
    expected = np.eye(4)
    expected[:3, 3] = translations.sum(axis=0)

    stage = Usd.Stage.Open(str(out / "chain.usdc"))
    (mesh,) = [p for p in stage.Traverse() if p.IsA(UsdGeom.Mesh)]
    usd = np.array(UsdGeom.Xformable(mesh).ComputeLocalToWorldTransform(Usd.TimeCode.Default()))
    np.testing.assert_array_equal(usd.T, expected)
    ((world,),) = load_scene(out / "chain.glb").mesh_instances().values()
    np.testing.assert_array_equal(world, expected)


def test_tampered_table_references_are_stale_data_in_one_line(tmp_path):
    """``sss:extras`` rewritten by another tool: each field of a table reference swapped for every JSON
    type or deleted, the JSON no object, the table's customData dtype no dtype. `technique_tables`
    refuses with a one-line StaleDataError naming the prim (or reads on, where the reference stays
    whole), never another exception."""
    from sssbake.exporters.usd import technique_tables
    from sssbake.pipeline.core.errors import StaleDataError

    asset = replace(icosphere_asset(), mesh_extras={0: {"prt": {"codes": np.arange(6).reshape(2, 3), "order": 2}}})
    write_usdc(asset, tmp_path / "m.usdc")
    stage = Usd.Stage.Open(str(tmp_path / "m.usdc"))
    prim = stage.GetPrimAtPath("/m/root/sphere")
    extras = prim.GetAttribute("sss:extras")
    good = json.loads(extras.Get())
    cases = {"a list": json.dumps([good]), "no JSON": "{", "a number": "7"}
    for field in good["prt"]["codes"]:
        for value in (None, True, -1, 2.5, 2**64, "x", "x y", [], [-1, 6], [[2, 3]], {}, "deleted"):
            changed = json.loads(json.dumps(good))
            if value == "deleted":
                del changed["prt"]["codes"][field]
            else:
                changed["prt"]["codes"][field] = value
            cases[f"{field} {value!r}"] = json.dumps(changed)
    read_on = []
    for case, text in cases.items():
        extras.Set(text)
        try:
            technique_tables(prim, "prt")
        except StaleDataError as e:
            assert "\n" not in str(e) and "/m/root/sphere" in str(e), str(e)
        else:
            read_on.append(case)
    # without its attribute or crc32 a reference is a plain object: the technique's reader refuses it
    assert read_on == ["attribute 'deleted'", "crc32 'deleted'"]
    extras.Set(json.dumps(good))
    prim.GetAttribute("sss:prt:codes").SetCustomDataByKey("dtype", "no such dtype")
    with pytest.raises(StaleDataError, match="customData dtype 'no such dtype'"):
        technique_tables(prim, "prt")
