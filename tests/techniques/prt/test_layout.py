"""prt data survives export: glTF and USD round trips give exactly the in-memory codes and tables."""

import json
from dataclasses import replace
from importlib import resources

import jsonschema
import numpy as np
import pygltflib
import pytest
from test_gltf import icosphere_asset

from sssbake.exporters.gltf import to_glb, write_glb
from sssbake.exporters.gltf_validator import validate_glb
from sssbake.exporters.usd import write_usdc
from sssbake.pipeline.mesh.baked import index_table
from sssbake.pipeline.techniques.prt.data import PrtData
from sssbake.pipeline.techniques.prt.layout import dq_attribute_count, prt_tables, prt_vertex_attributes
from sssbake.pipeline.techniques.prt.reader import PrtReadError, read_prt_glb, read_prt_usd


def random_prt(n: int, k: int = 14, refs: int = 9, order: int = 3, seed: int = 0, channels: int = 3,
               weight_bits: int = 16, detail_order: int = 0, triangles: int | None = None) -> PrtData:
    """Codes and tables of the right dtypes and shapes with random contents (decode is not the point);
    RGB (`channels` 3) or shared (1) reference tables, 16- or 8-bit weights, detail terms (shared),
    `triangles` reference triangles (default 2 · refs - 4) that the vertices index."""
    rng = np.random.default_rng(seed)
    top = (1 << (weight_bits - 1)) - 1
    c = order * order
    d = detail_order * detail_order
    f = (max(2 * refs - 4, 1) if refs else 0) if triangles is None else triangles
    return PrtData(
        directions=rng.normal(size=(k, 3)).astype(np.float32),
        direction_triangles=rng.integers(0, k, (2 * k - 4, 3)).astype(np.int32),
        direction_inverse=rng.normal(size=(2 * k - 4, 3, 3)).astype(np.float32),
        direction_lookup=rng.integers(0, 2 * k - 4, (8, 8)).astype(np.int32),
        direction_neighbours=rng.integers(0, 2 * k - 4, (2 * k - 4, 3)).astype(np.int32),
        lut=np.sort(rng.random((3, 256)), axis=1).astype(np.float32),
        ref_vertices=np.arange(refs, dtype=np.int64),
        ref_codes=rng.integers(0, 256, (refs, k, channels)).astype(np.uint8),
        ref_scale=rng.random((refs if channels == 1 else 0, 3)).astype(np.float32),
        ref_triangles=rng.integers(0, max(refs, 1), (f, 3)).astype(np.int32),
        # 0 without reference points; past 16 bits with `triangles` > 65536: float32 holds them exactly
        vertex_triangle=rng.integers(0, max(f, 1), n).astype(np.int32),
        weight_codes=rng.integers(-top, top + 1, (n, 2)).astype(np.int16),
        weight_scale=1.5,
        weight_bits=weight_bits,
        dq_codes=rng.integers(-127, 128, (n, 3, c)).astype(np.int8),
        dq_scale=rng.random((3, c)).astype(np.float32),
        sh_order=order,
        eta=1.3,
        detail_order=detail_order,
        detail_codes=rng.integers(-127, 128, (refs if d else 0, d)).astype(np.int8),
        detail_colour=rng.integers(-127, 128, (refs if d else 0, 3)).astype(np.int8),
        detail_scale=rng.random(d).astype(np.float32),
    )


def prt_asset(prt: PrtData):
    asset = icosphere_asset()
    n = len(asset.scene.meshes[0].primitives[0].positions)
    assert prt.vertex_count == n
    return replace(asset, vertex_attributes={(0, 0): prt_vertex_attributes(prt, np.arange(n))},
                   mesh_extras={0: {"prt": prt_tables(prt)}})


def assert_same(a: PrtData, b: PrtData) -> None:
    for field in ("directions", "direction_triangles", "direction_inverse", "direction_lookup", "direction_neighbours", "lut", "ref_codes",
                  "ref_scale", "ref_triangles", "vertex_triangle", "weight_codes", "dq_codes", "dq_scale",
                  "detail_codes", "detail_colour", "detail_scale"):
        x, y = getattr(a, field), getattr(b, field)
        assert x.dtype == y.dtype and x.shape == y.shape, field
        np.testing.assert_array_equal(x, y, err_msg=field)
    assert (a.weight_scale, a.weight_bits, a.sh_order, a.eta, a.detail_order) == \
        (b.weight_scale, b.weight_bits, b.sh_order, b.eta, b.detail_order)


@pytest.mark.parametrize("refs, order, channels, bits, detail, triangles", [
    (9, 3, 3, 16, 0, 70000), (0, 8, 3, 16, 0, None), (5, 0, 3, 16, 0, None), (7, 2, 1, 8, 0, None),
    (6, 0, 1, 8, 4, None), (8, 1, 1, 16, 2, None)])
def test_glb_and_usd_round_trip_exactly(tmp_path, refs, order, channels, bits, detail, triangles):
    n = len(icosphere_asset().scene.meshes[0].primitives[0].positions)
    prt = random_prt(n, refs=refs, order=order, channels=channels, weight_bits=bits, detail_order=detail,
                     triangles=triangles)
    asset = prt_asset(prt)
    write_glb(asset, tmp_path / "a.glb")
    write_usdc(asset, tmp_path / "a.usdc")
    assert_same(read_prt_glb(tmp_path / "a.glb")[(0, 0)], prt)
    assert_same(read_prt_usd(tmp_path / "a.usdc")["/a/root/sphere"], prt)


def test_layout_is_valid_gltf_and_counts_attributes(tmp_path):
    n = len(icosphere_asset().scene.meshes[0].primitives[0].positions)
    for bits in (16, 8):
        write_glb(prt_asset(random_prt(n, weight_bits=bits)), tmp_path / "a.glb")
        report = validate_glb(tmp_path / "a.glb")
        assert (report.num_errors, report.num_warnings) == (0, 0), report.to_json()
        gltf = pygltflib.GLTF2.load(tmp_path / "a.glb")
        attributes = {k: v for k, v in vars(gltf.meshes[0].primitives[0].attributes).items()
                      if k.startswith("_") and v is not None}
        # one VEC3 float32 per SH coefficient (order 3) after the reference: the widths Blender needs
        assert sorted(attributes) == ["_SSS_PRT_DQ0", "_SSS_PRT_DQ1", "_SSS_PRT_DQ2", "_SSS_PRT_DQ3", "_SSS_PRT_DQ4",
                                      "_SSS_PRT_DQ5", "_SSS_PRT_DQ6", "_SSS_PRT_DQ7", "_SSS_PRT_DQ8", "_SSS_PRT_REF"]
        for index in attributes.values():
            acc = gltf.accessors[index]
            assert (acc.type, acc.componentType, acc.normalized) == ("VEC3", 5126, False)
    # float32 holds the triangle exactly below 2^24
    with pytest.raises(ValueError, match="reference triangles at most"):
        prt_vertex_attributes(replace(random_prt(n), vertex_triangle=np.full(n, 1 << 24, np.int32)), np.arange(n))
    assert [dq_attribute_count(o) for o in (0, 1, 2, 3, 8)] == [0, 1, 4, 9, 64]
    # index tables: 16 bits while every index fits, else 32 (written as UNSIGNED_INT)
    assert index_table(np.array([[0, 65535]])).dtype == np.uint16
    assert index_table(np.array([[0, 65536]])).dtype == np.int64


def test_files_without_prt_say_how_to_get_it(tmp_path):
    write_glb(icosphere_asset(), tmp_path / "plain.glb")
    with pytest.raises(PrtReadError, match="bake with --techniques prt"):
        read_prt_glb(tmp_path / "plain.glb")


def test_prt_extras_match_the_documented_schema():
    schema = json.loads(resources.files("sssbake.exporters").joinpath("schema/sssbake.schema.json").read_text())
    n = len(icosphere_asset().scene.meshes[0].primitives[0].positions)
    sub = {"$schema": schema["$schema"], "$defs": schema["$defs"]}
    for channels, bits, detail in ((1, 8, 4), (3, 16, 0)):
        prt = random_prt(n, channels=channels, weight_bits=bits, detail_order=detail)
        gltf = pygltflib.GLTF2.load_from_bytes(to_glb(prt_asset(prt))[0])
        mesh = gltf.meshes[0].extensions["SSSBAKE_subsurface"]
        jsonschema.Draft202012Validator({**sub, "$ref": "#/$defs/mesh"}).validate(mesh)
    with pytest.raises(jsonschema.ValidationError):
        jsonschema.Draft202012Validator({**sub, "$ref": "#/$defs/mesh"}).validate(
            {**mesh, "prt": {**mesh["prt"], "tableChannels": 2}})
    with pytest.raises(jsonschema.ValidationError):
        jsonschema.Draft202012Validator({**sub, "$ref": "#/$defs/mesh"}).validate(
            {**mesh, "prt": {**mesh["prt"], "directionCount": 2}})
