"""kernels data survives export: glTF and USD round trips give the decoded kernels and every other
array exactly; the files validate; the byte counts are what the files spend."""

import json
from dataclasses import fields, replace
from importlib import resources

import jsonschema
import numpy as np
import pygltflib
import pytest
from fixtures import random_kernels
from test_gltf import icosphere_asset

from sssbake.exporters.gltf import FLOAT, write_glb
from sssbake.exporters.gltf_validator import ValidatorUnavailable, find_validator, validate_many
from sssbake.exporters.inspect_gltf import inspect_glb
from sssbake.exporters.inspect_usd import inspect_usdc
from sssbake.exporters.usd import write_usdc
from sssbake.exporters.usd_validator import validate_usd
from sssbake.pipeline.mesh.scene import Mesh
from sssbake.pipeline.techniques.kernels.data import KernelsData, KernelsDataError
from sssbake.pipeline.techniques.kernels.layout import (
    BLOCKS,
    VERTEX_ATTRIBUTE,
    decode_kernels,
    encode_kernels,
    kernel_error_bound,
    kernels_bytes,
    kernels_data_from_tables,
    kernels_tables,
    kernels_vertex_attributes,
)
from sssbake.pipeline.techniques.kernels.reader import KernelsReadError, read_kernels_glb, read_kernels_usd

#: Mesh prims of mesh 0 (two primitives) in the USD files written as ``a.usdc``.
USD_PRIMS = ("/a/root/sphere_0", "/a/root/sphere_1")


def widened(data: KernelsData, n: int) -> KernelsData:
    """`data` over n welded (and global) vertices, its vertex ids spread (monotonically) to reach
    beyond 16 bits; each surface vertex reads a different mix of global ones."""
    step = (n - 1) // (data.vertex_count - 1)
    rng = np.random.default_rng(n)
    out = replace(data, vertex_count=n, texel_vertices=data.texel_vertices * step, f_indices=data.f_indices * step,
                  border_vertices=data.border_vertices * step,
                  f_indptr=np.r_[data.f_indptr, np.full(n - data.vertex_count, data.f_indptr[-1])],
                  surface_vertex_count=n, surface_global=rng.integers(0, n, (n, 3)),
                  surface_weights=rng.dirichlet(np.ones(3), n).astype(np.float32))
    out.check()
    return out


def make(case: str) -> KernelsData:
    rng = np.random.default_rng(7)
    if case == "empty":  # no F entries, no border texels: their tables are left out
        return random_kernels(rng, per_row=0, borders=0)
    data = random_kernels(rng)
    # an all-zero channel has scale 0
    kernels = data.kernels.copy()
    kernels[3, :, 1] = 0.0
    data = replace(data, kernels=kernels)
    return widened(data, 70000) if case == "wide" else data


def kernels_asset(data: KernelsData, bits: int):
    """The test_gltf icosphere with a second primitive in mesh 0 (the plate's triangle) and kernels
    on mesh 0; returns the asset and the vertex ids of both primitives."""
    asset = icosphere_asset()
    sphere, plate = asset.scene.meshes
    prims = (sphere.primitives[0], plate.primitives[0])
    rng = np.random.default_rng(3)
    ids = [rng.integers(0, data.vertex_count, len(p.positions)) for p in prims]
    ids[0][0] = data.vertex_count - 1
    scene = replace(asset.scene, meshes=(Mesh("sphere", prims), plate))
    attributes = {(0, 0): asset.vertex_attributes[(0, 0)] + kernels_vertex_attributes(data, ids[0]),
                  (0, 1): kernels_vertex_attributes(data, ids[1])}
    return replace(asset, scene=scene, vertex_attributes=attributes,
                   mesh_extras={0: {"kernels": kernels_tables(data, bits)}}), ids


def assert_read_back(got: KernelsData, data: KernelsData, bits: int) -> None:
    """Every array as written; the kernels as their codes define them, within half a code step."""
    for field in fields(KernelsData):
        x, y = getattr(got, field.name), getattr(data, field.name)
        if field.name == "kernels":
            y = decode_kernels(*encode_kernels(data.kernels, bits), bits)
        if isinstance(y, np.ndarray):
            assert x.dtype == y.dtype and x.shape == y.shape, field.name
            np.testing.assert_array_equal(x, y, err_msg=field.name)
        else:
            assert x == y, field.name
    _, scales = encode_kernels(data.kernels, bits)
    error = np.abs(got.kernels.astype(np.float64) - data.kernels)
    bound = kernel_error_bound(scales, bits)[:, None, :] + 2.0**-24 * np.abs(got.kernels)
    assert np.all(error <= bound)


@pytest.mark.parametrize("bits", [8, 16])
@pytest.mark.parametrize("case", ["small", "wide", "empty"])
def test_glb_and_usd_round_trip(tmp_path, case, bits):
    data = make(case)
    asset, ids = kernels_asset(data, bits)
    write_glb(asset, tmp_path / "a.glb")
    write_usdc(asset, tmp_path / "a.usdc")

    glb = read_kernels_glb(tmp_path / "a.glb")
    assert set(glb) == {(0, 0), (0, 1)}
    assert glb[(0, 0)][0] is glb[(0, 1)][0]  # one atlas per mesh
    assert_read_back(glb[(0, 0)][0], data, bits)
    for j in (0, 1):
        assert glb[(0, j)][1].dtype == np.int64
        np.testing.assert_array_equal(glb[(0, j)][1], ids[j])

    gltf = pygltflib.GLTF2.load(tmp_path / "a.glb")
    vertex = gltf.accessors[getattr(gltf.meshes[0].primitives[0].attributes, VERTEX_ATTRIBUTE)]
    # VEC3 float32 (id, 0, 0) at any vertex count: what Blender, Bevy and Godot keep
    assert (vertex.type, vertex.componentType, vertex.normalized) == ("VEC3", FLOAT, False)
    codes = gltf.accessors[gltf.meshes[0].extensions["SSSBAKE_subsurface"]["kernels"]["kernelCodes"]["accessor"]]
    assert (codes.type, codes.componentType) == ("VEC3", 5120 if bits == 8 else 5122)
    assert ("fValues" in gltf.meshes[0].extensions["SSSBAKE_subsurface"]["kernels"]) == (case != "empty")

    usd = read_kernels_usd(tmp_path / "a.usdc")
    assert set(usd) == set(USD_PRIMS)
    for j, prim in enumerate(USD_PRIMS):
        assert_read_back(usd[prim][0], data, bits)
        np.testing.assert_array_equal(usd[prim][1], ids[j])
        primvar = inspect_usdc(tmp_path / "a.usdc")["meshes"][j]["primvars"]["primvars:sss:kernels:vertex"]
        assert primvar["elementSize"] == 1 and primvar["count"] == len(ids[j])  # one (id, 0, 0) per vertex


def test_files_pass_the_validators(tmp_path):
    paths = []
    for case, bits in (("small", 8), ("wide", 16), ("empty", 16)):
        asset, _ = kernels_asset(make(case), bits)
        paths.append(tmp_path / f"{case}.glb")
        write_glb(asset, paths[-1])
        write_usdc(asset, tmp_path / f"{case}.usdc")
        report = validate_usd(tmp_path / f"{case}.usdc")
        assert report.ok, report.to_json()
    try:
        find_validator()
    except ValidatorUnavailable as exc:
        pytest.skip(str(exc))
    for report in validate_many(paths):
        assert (report.num_errors, report.num_warnings) == (0, 0), report.to_json()


@pytest.mark.parametrize("case, bits", [("small", 8), ("wide", 16), ("empty", 16)])
def test_byte_counts_are_what_the_files_spend(tmp_path, case, bits):
    data = make(case)
    asset, ids = kernels_asset(data, bits)
    write_glb(asset, tmp_path / "a.glb")
    gltf = pygltflib.GLTF2.load(tmp_path / "a.glb")
    refs = gltf.meshes[0].extensions["SSSBAKE_subsurface"]["kernels"]
    written = {block: sum(gltf.bufferViews[gltf.accessors[refs[name]["accessor"]].bufferView].byteLength
                          for name in names if name in refs) for block, names in BLOCKS.items()}
    counted = kernels_bytes(data, bits)
    assert {block: counted[block] for block in BLOCKS} == written
    assert counted["total"] == sum(written.values())
    assert counted["perVertex"] == counted["total"] / data.vertex_count
    assert counted["perTexel"] == counted["total"] / len(data.texels)
    vertex = gltf.accessors[getattr(gltf.meshes[0].primitives[0].attributes, VERTEX_ATTRIBUTE)]
    assert counted["vertexIdsPerRenderVertex"] == gltf.bufferViews[vertex.bufferView].byteLength / len(ids[0])

    info = inspect_glb(tmp_path / "a.glb")["meshes"][0]
    assert info["sssbake"]["kernels"]["technique"] == "kernels"
    shown = info["techniques"]["kernels"]
    assert shown["bytes"] == counted["total"]
    assert shown["tables"]["kernelCodes"]["componentType"] == ("BYTE" if bits == 8 else "SHORT")
    assert info["primitives"][0]["attributes"][VERTEX_ATTRIBUTE]["bytesPerVertex"] == 12.0

    write_usdc(asset, tmp_path / "a.usdc")
    mesh = inspect_usdc(tmp_path / "a.usdc")["meshes"][0]
    assert mesh["extras"]["kernels"]["texelCount"] == len(data.texels)
    tables = mesh["techniques"]["kernels"]["tables"]
    assert set(tables) == {name for name in refs if isinstance(refs[name], dict) and "accessor" in refs[name]}
    # USD keeps integer tables as int[] (it has no 8- or 16-bit integers); their bytes count at the width
    # they were baked at, as the .glb stores them, so both files give one figure
    assert tables["kernelCodes"]["count"] == data.kernels.size
    assert tables["kernelCodes"]["bytes"] == bits // 8 * data.kernels.size
    assert mesh["techniques"]["kernels"]["bytes"] == counted["total"]


def test_meshes_of_either_width_share_the_attribute(tmp_path):
    asset, ids = kernels_asset(make("small"), 8)
    wide = make("wide")
    plate_ids = np.array([0, 65536, wide.vertex_count - 1])
    # a mesh under and one over 65536 welded vertices: one attribute description for both
    attributes = {**asset.vertex_attributes, (1, 0): kernels_vertex_attributes(wide, plate_ids)}
    asset = replace(asset, vertex_attributes=attributes,
                    mesh_extras={**asset.mesh_extras, 1: {"kernels": kernels_tables(wide)}})
    write_glb(asset, tmp_path / "a.glb")
    read = read_kernels_glb(tmp_path / "a.glb")
    assert set(read) == {(0, 0), (0, 1), (1, 0)}
    assert read[(1, 0)][0].vertex_count == wide.vertex_count
    np.testing.assert_array_equal(read[(1, 0)][1], plate_ids)
    np.testing.assert_array_equal(read[(0, 0)][1], ids[0])


def test_kernel_codes_and_bounds():
    kernels = np.array([[[0.5, 0.0, -2.0], [-1.0, 0.0, 1.0], [0.25, 0.0, 0.3]]], dtype=np.float32)
    codes, scales = encode_kernels(kernels, 8)
    np.testing.assert_array_equal(scales, [[1.0, 0.0, 2.0]])
    np.testing.assert_array_equal(codes[0, :, 0], [64, -127, 32])  # 63.5 rounds to even
    np.testing.assert_array_equal(codes[0, :, 2], [-127, 64, 19])
    assert codes.dtype == np.int8 and not codes[0, :, 1].any()
    np.testing.assert_array_equal(decode_kernels(codes, scales, 8)[0, :, 2],
                                  np.float32([-2.0, 128 / 127, 38 / 127]))
    np.testing.assert_array_equal(kernel_error_bound(scales, 16), scales.astype(np.float64) / 65534.0)
    with pytest.raises(ValueError, match="8 or 16"):
        kernels_tables(make("small"), kernel_bits=12)


def test_malformed_input_is_refused(tmp_path):
    data = make("small")
    with pytest.raises(ValueError, match="welded vertices"):
        kernels_vertex_attributes(data, np.array([0, data.vertex_count]))
    tables = kernels_tables(data)
    del tables["borderVertices"]
    with pytest.raises(KernelsDataError, match="borderVertices is missing"):
        kernels_data_from_tables(tables)
    with pytest.raises(KernelsDataError, match="fValues holds"):
        kernels_data_from_tables({**kernels_tables(data), "fValues": np.zeros((2, 3), np.float32)})
    write_glb(icosphere_asset(), tmp_path / "plain.glb")
    with pytest.raises(KernelsReadError, match="bake with --techniques kernels"):
        read_kernels_glb(tmp_path / "plain.glb")


def test_kernels_extras_match_the_documented_schema(tmp_path):
    schema = json.loads(resources.files("sssbake.exporters").joinpath("schema/sssbake.schema.json").read_text())
    sub = {"$schema": schema["$schema"], "$defs": schema["$defs"]}
    mesh_schema = jsonschema.Draft202012Validator({**sub, "$ref": "#/$defs/mesh"})
    for case, bits in (("wide", 8), ("empty", 16)):
        asset, _ = kernels_asset(make(case), bits)
        write_glb(asset, tmp_path / "a.glb")
        gltf = pygltflib.GLTF2.load(tmp_path / "a.glb")
        mesh = gltf.meshes[0].extensions["SSSBAKE_subsurface"]
        mesh_schema.validate(mesh)
        jsonschema.Draft202012Validator(schema).validate(gltf.extensions["SSSBAKE_subsurface"])
    for bad in ({"kernelBits": 12}, {"kernelSize": 1}, {"technique": "prt"}):
        with pytest.raises(jsonschema.ValidationError):
            mesh_schema.validate({**mesh, "kernels": {**mesh["kernels"], **bad}})


def test_subnormal_kernels_keep_their_codes():
    # M / 3e-40 overflows float32: the factor must be float64, or zeros became NaN codes (inf · 0)
    kernels = np.zeros((1, 9, 3), np.float32)
    kernels[0, :, 0] = 1e-40
    kernels[0, 4, 0] = -3e-40
    codes, scales = encode_kernels(kernels, 8)
    np.testing.assert_array_equal(codes[0, :, 0], [42, 42, 42, 42, -127, 42, 42, 42, 42])  # rint(127 / 3)
    assert not codes[0, :, 1:].any() and not scales[0, 1:].any()
    np.testing.assert_allclose(decode_kernels(codes, scales, 8)[0, :, 0], kernels[0, :, 0], rtol=0.01, atol=0)
