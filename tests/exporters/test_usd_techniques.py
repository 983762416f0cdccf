"""USD output of a real bake with every technique: typed primvars and tables, read back equal to the
glTF data, the thickness texture on the material, and stale data refused with one line."""

import dataclasses
import json
import math
import shutil
from dataclasses import replace

import numpy as np
import pytest
import trimesh
from fixtures import FALLBACK
from pxr import Sdf, Usd, UsdGeom, UsdShade
from test_usd import icosphere_asset

from sssbake.exporters.gltf_tables import load_sssbake_gltf
from sssbake.exporters.gltf_tables import technique_tables as gltf_tables
from sssbake.exporters.inspect_usd import inspect_usdc
from sssbake.exporters.usd import (
    PREVIEW_SURFACE_NOTE,
    primvar_values,
    technique_data,
    uv_primvar,
    write_usdc,
)
from sssbake.exporters.usd_validator import validate_usd
from sssbake.pipeline.bake.asset import bake_asset
from sssbake.pipeline.bake.cache import StageCache
from sssbake.pipeline.core.errors import StaleDataError
from sssbake.pipeline.core.materials import preset
from sssbake.pipeline.mesh.baked import ScatteringMaterial, VertexAttribute
from sssbake.pipeline.mesh.scene import Image, Texture, TextureRef
from sssbake.pipeline.options import BakeOptions
from sssbake.pipeline.techniques.prt.reader import read_prt_usd
from sssbake.pipeline.techniques.registry import NAMES, TECHNIQUES

#: The primvar types Blender 4.5's USD importer keeps with their values (benchmarks/blender_usd_import.py).
BLENDER_KEEPS = {"float[]", "float2[]", "float3[]", "normal3f[]", "uchar[]", "int[]"}


@pytest.fixture(scope="module")
def baked(tmp_path_factory):
    """A marble ball baked with all five techniques: (glb, usdc)."""
    folder = tmp_path_factory.mktemp("usd_techniques")
    trimesh.creation.icosphere(subdivisions=2, radius=5.0).export(folder / "ball.obj")
    options = BakeOptions(material="marble", scale_mm=1.0, techniques=tuple(NAMES), atlas_resolution=64)
    report = bake_asset(folder / "ball.obj", options, folder / "ball", StageCache(None)).report
    assert report["validation"]["usd"]["errors"] == 0 and report["validation"]["usd"]["warnings"] == 0
    return folder / "ball.glb", folder / "ball.usdc"


def assert_equal(a, b, where="data", squeeze=False):
    """`a` and `b` hold exactly the same values (arrays compared as float64 values and shapes; with
    `squeeze`, shapes but for length-1 axes: a glTF SCALAR table reads back (n,), USD keeps (n, 1))."""
    if dataclasses.is_dataclass(a):
        assert type(a) is type(b), where
        for f in dataclasses.fields(a):
            assert_equal(getattr(a, f.name), getattr(b, f.name), f"{where}.{f.name}", squeeze)
    elif isinstance(a, dict):
        assert a.keys() == b.keys(), where
        for k in a:
            assert_equal(a[k], b[k], f"{where}.{k}", squeeze)
    elif isinstance(a, (tuple, list)) and not np.isscalar(a):
        assert len(a) == len(b), where
        for i, (x, y) in enumerate(zip(a, b)):
            assert_equal(x, y, f"{where}[{i}]", squeeze)
    elif isinstance(a, np.ndarray):
        if squeeze:
            a, b = np.squeeze(a), np.squeeze(b)
        assert np.shape(a) == np.shape(b), where
        np.testing.assert_array_equal(np.asarray(a, np.float64), np.asarray(b, np.float64), err_msg=where)
    else:
        assert a == b, where


@pytest.mark.parametrize("technique", TECHNIQUES, ids=NAMES)
def test_each_technique_reads_back_equal_to_the_gltf(baked, technique):
    glb, usdc = baked
    from_glb, from_usd = technique.read(glb), technique.read_usd(usdc)
    assert len(from_glb) == len(from_usd) == 1
    assert_equal(next(iter(from_glb.values())), next(iter(from_usd.values())), technique.name)


def test_tables_and_primvars_equal_the_gltf_ones(baked):
    glb, usdc = baked
    gltf = load_sssbake_gltf(glb)
    stage = Usd.Stage.Open(str(usdc))
    (mesh,) = [p for p in stage.Traverse() if p.IsA(UsdGeom.Mesh)]
    techniques = json.loads(mesh.GetAttribute("sss:extras").Get())  # spectral's data is its primvar alone
    assert set(techniques) == {"prt", "kernels", "lpv"}
    for name in techniques:
        tables, per_vertex = technique_data(mesh, name)
        assert_equal(gltf_tables(gltf, "meshes", 0, name), tables, name, squeeze=True)
        for attribute, values in per_vertex.items():  # decoded as a glTF reader decodes them
            np.testing.assert_array_equal(values, gltf.attribute(0, 0, attribute).reshape(len(values), -1))
    (material,) = [p for p in stage.Traverse() if p.IsA(UsdShade.Material)]
    screen, _ = technique_data(material, "screen")
    assert_equal(gltf_tables(gltf, "materials", 0, "screen"), screen, "screen", squeeze=True)


def test_primvars_are_typed_vectors_blender_keeps(baked):
    _, usdc = baked
    stage = Usd.Stage.Open(str(usdc))
    (mesh,) = [p for p in stage.Traverse() if p.IsA(UsdGeom.Mesh)]
    n = len(UsdGeom.Mesh(mesh).GetPointsAttr().Get())
    primvars = {pv.GetPrimvarName(): pv for pv in UsdGeom.PrimvarsAPI(mesh).GetPrimvarsWithAuthoredValues()
                if pv.GetPrimvarName().startswith("sss:")}
    assert {"sss:normal", "sss:prt:ref", "sss:kernels:vertex", "sss:thickness"} <= set(primvars)
    for name, pv in primvars.items():
        assert str(pv.GetTypeName()) in BLENDER_KEEPS and not pv.HasAuthoredElementSize(), name
        assert pv.GetInterpolation() == UsdGeom.Tokens.vertex and len(pv.Get()) == n, name
        assert pv.GetAttr().GetCustomData()["gltfName"].startswith("_"), name
    assert str(primvars["sss:normal"].GetTypeName()) == "normal3f[]"
    normals = primvar_values(primvars["sss:normal"])
    np.testing.assert_allclose(np.linalg.norm(normals, axis=1), 1.0, atol=1e-6)
    # every JSON names primvars, never glTF attributes
    for prim in (stage.GetDefaultPrim(), mesh):
        text = prim.GetAttribute("sss:extras").Get()
        assert "_SSS_" not in text and '"_THICKNESS"' not in text
    assert "primvars:sss:prt:ref" in mesh.GetAttribute("sss:extras").Get()


def test_tables_are_typed_by_their_shapes(baked):
    _, usdc = baked
    stage = Usd.Stage.Open(str(usdc))
    (mesh,) = [p for p in stage.Traverse() if p.IsA(UsdGeom.Mesh)]
    extras = json.loads(mesh.GetAttribute("sss:extras").Get())
    expected = {("kernels", "kernelCodes"): ("int[]", "int8"), ("prt", "directions"): ("float3[]", "float32"),
                ("prt", "directionTriangles"): ("int[]", "uint16"), ("prt", "refCodes"): ("int[]", "uint8"),
                ("lpv", "matrices"): ("matrix4d[]", "float32"), ("lpv", "occupancy"): ("float[]", "float32")}
    for (technique, key), (type_name, dtype) in expected.items():
        ref = extras[technique][key]
        attribute = mesh.GetAttribute(ref["attribute"])
        assert ref["attribute"] == f"sss:{technique}:{key}" and len(ref["crc32"]) == 8
        assert (str(attribute.GetTypeName()), attribute.GetCustomData()["dtype"]) == (type_name, dtype), key
        assert list(attribute.GetCustomData()["shape"]) == ref["shape"]
    codes = extras["kernels"]["kernelCodes"]
    info = inspect_usdc(usdc)["meshes"][0]["techniques"]["kernels"]["tables"]["kernelCodes"]
    # int[] in the file, counted at the int8 a .glb stores: one figure for both containers
    assert info["dtype"] == "int8" and info["bytes"] == math.prod(codes["shape"])


def test_thickness_texture_and_surfaces(baked):
    glb, usdc = baked
    png = usdc.with_name("ball.thickness0.png")
    data = load_sssbake_gltf(glb)
    gltf = data.gltf
    volume = gltf.materials[0].extensions["KHR_materials_volume"]
    image = gltf.images[gltf.textures[volume["thicknessTexture"]["index"]].source]
    view = gltf.bufferViews[image.bufferView]
    assert png.read_bytes() == data.blob[view.byteOffset: view.byteOffset + view.byteLength]

    stage = Usd.Stage.Open(str(usdc))
    (material,) = [UsdShade.Material(p) for p in stage.Traverse() if p.IsA(UsdShade.Material)]
    prim = material.GetPrim()
    assert prim.GetCustomDataByKey("sssbake:previewSurface") == PREVIEW_SURFACE_NOTE
    output = material.GetOutput("sss:thickness")
    (source,) = output.GetConnectedSources()[0]
    texture = UsdShade.Shader(source.source.GetPrim())
    assert texture.GetIdAttr().Get() == "UsdUVTexture" and source.sourceName == "g"
    asset = texture.GetInput("file").Get()
    assert asset.path == "./ball.thickness0.png" and asset.resolvedPath == str(png.resolve())
    assert texture.GetInput("sourceColorSpace").Get() == "raw"
    factor = prim.GetAttribute("sss:fallback:thicknessFactor").Get()
    assert tuple(texture.GetInput("scale").Get()) == (factor, factor, factor, 1.0)
    (reader,) = texture.GetInput("st").GetConnectedSources()[0]
    reader = UsdShade.Shader(reader.source.GetPrim())
    varname = reader.GetInput("varname").Get()
    texcoord = volume["thicknessTexture"].get("texCoord", 0)
    assert reader.GetIdAttr().Get() == "UsdPrimvarReader_float2" and varname == uv_primvar(texcoord)
    (mesh,) = [p for p in stage.Traverse() if p.IsA(UsdGeom.Mesh)]
    assert UsdGeom.PrimvarsAPI(mesh).GetPrimvar(varname).HasAuthoredValue()

    surface = material.ComputeSurfaceSource()[0]
    assert surface.GetInput("opacity").Get() == 1.0
    assert surface.GetInput("ior").Get() == prim.GetAttribute("sss:fallback:ior").Get()
    mfp = preset("marble").mean_free_path_mm  # 1 mm per unit
    assert prim.GetAttribute("sss:openpbr:subsurfaceRadius").Get() == pytest.approx(mfp.max(), rel=1e-6)
    np.testing.assert_allclose(prim.GetAttribute("sss:openpbr:subsurfaceRadiusScale").Get(), mfp / mfp.max(),
                               rtol=1e-6)
    assert validate_usd(usdc).ok


@pytest.fixture
def copy(baked, tmp_path):
    """A private copy of the baked .usdc (and its texture) to break."""
    _, usdc = baked
    for path in (usdc, usdc.with_name("ball.thickness0.png")):
        shutil.copy(path, tmp_path / path.name)
    return tmp_path / "ball.usdc"


def edit(usdc, change):
    layer = Sdf.Layer.FindOrOpen(str(usdc))
    change(layer)
    layer.Save()


def mesh_path(layer):
    stage = Usd.Stage.Open(layer)
    return next(p.GetPath() for p in stage.Traverse() if p.IsA(UsdGeom.Mesh))


def test_a_changed_table_is_refused_with_one_line(copy):
    def change(layer):
        attribute = layer.GetAttributeAtPath(mesh_path(layer).AppendProperty("sss:prt:directions"))
        values = list(attribute.default)
        values[0] = (0.0, 0.0, 1.0)
        attribute.default = values
    edit(copy, change)
    with pytest.raises(StaleDataError, match=r"ball\.usdc: .* table prt\.directions \(sss:prt:directions\) fails "
                                             r"its CRC-32 .*likely broken by a tool that rewrote"):
        read_prt_usd(copy)
    with pytest.raises(StaleDataError, match="CRC-32"):
        inspect_usdc(copy)


def test_a_dropped_primvar_or_table_names_the_tool(copy):
    def change(layer):
        path = mesh_path(layer)
        prim = layer.GetPrimAtPath(path)
        del prim.properties["primvars:sss:prt:ref"]
        layer.customLayerData = {"creator": "Blender v4.5.15 LTS"}
    edit(copy, change)
    with pytest.raises(StaleDataError, match=r"lacks primvars:sss:prt:ref, .*likely broken by Blender v4\.5\.15 LTS"):
        read_prt_usd(copy)

    def drop_table(layer):
        del layer.GetPrimAtPath(mesh_path(layer)).properties["sss:prt:lut"]
    edit(copy, drop_table)
    with pytest.raises(StaleDataError, match=r"table prt\.lut \(sss:prt:lut\) is missing"):
        read_prt_usd(copy)


def test_schema_1_files_are_refused(copy):
    def change(layer):
        layer.GetAttributeAtPath("/ball.sss:schemaVersion").default = "1.8.0"
    edit(copy, change)
    for read in (read_prt_usd, inspect_usdc):
        with pytest.raises(StaleDataError, match=r"ball\.usdc: written by sssbake schema 1\.x; rebake it with this "
                                                 r"version$"):
            read(copy)


def textured_asset():
    """The test icosphere whose marble material has a thickness texture on TEXCOORD_1."""
    asset = icosphere_asset()
    png = b"\x89PNG\r\n\x1a\n" + bytes(range(40))  # written byte for byte, never decoded
    scene = replace(asset.scene, images=(Image("t", "image/png", png),), textures=(Texture(0, wrap_s=33071),))
    fallback = replace(FALLBACK, thickness_texture=TextureRef(0, tex_coord=1))
    return replace(asset, scene=scene, scattering={0: ScatteringMaterial(preset("marble"), fallback, "Marble")})


def test_texture_written_next_to_the_usdc_or_not_at_all(tmp_path):
    asset = textured_asset()
    summary = write_usdc(asset, tmp_path / "a.usdc")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.thickness0.png", "a.usdc"]
    assert summary["textures"] == [str(tmp_path / "a.thickness0.png")]
    assert (tmp_path / "a.thickness0.png").read_bytes() == asset.scene.images[0].data
    stage = Usd.Stage.Open(str(tmp_path / "a.usdc"))
    texture = UsdShade.Shader(stage.GetPrimAtPath("/a/Materials/Marble/ThicknessTexture"))
    assert (texture.GetInput("wrapS").Get(), texture.GetInput("wrapT").Get()) == ("clamp", "repeat")
    reader = UsdShade.Shader(stage.GetPrimAtPath("/a/Materials/Marble/ThicknessUV"))
    assert reader.GetInput("varname").Get() == "st1"
    assert validate_usd(tmp_path / "a.usdc").ok

    bad = replace(asset, vertex_attributes={(0, 0): (VertexAttribute("t", np.full(42, np.nan)),)})
    with pytest.raises(ValueError, match="non-finite"):
        write_usdc(bad, tmp_path / "b.usdc")
    (tmp_path / "c.thickness0.png").mkdir()  # the texture cannot be renamed into place
    with pytest.raises(OSError):
        write_usdc(asset, tmp_path / "c.usdc")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.thickness0.png", "a.usdc", "c.thickness0.png"]


def test_a_missing_texture_is_a_validation_error(baked, tmp_path):
    _, usdc = baked
    shutil.copy(usdc, tmp_path / usdc.name)
    report = validate_usd(tmp_path / usdc.name)
    assert [e for e in report.errors if "MissingReferenceValidator" in e and "ball.thickness0.png" in e]
