"""The SSSBAKE_subsurface container: tables found by name and checked (count, type, componentType,
CRC-32), vertex attributes checked against their declaration, and the damage other tools do
(renumbered, deleted or rewritten accessors, a dropped extension, schema 1.x files) refused with
one line naming the file, the table and the likely tool."""

import struct
import zlib
from dataclasses import replace

import numpy as np
import pygltflib
import pytest
from test_gltf import icosphere_asset

from sssbake.exporters.gltf import EXTENSION, FLOAT, UNSIGNED_INT, write_glb
from sssbake.exporters.gltf_tables import load_sssbake_gltf, technique_tables
from sssbake.exporters.inspect_gltf import inspect_glb
from sssbake.pipeline.core.errors import AssetError, StaleDataError

TRANSFORM = "glTF-Transform v4.5.1"

#: Mesh 0's technique data: one table of each storage kind.
TABLES = {
    "floats": np.linspace(-1.0, 2.0, 21).reshape(7, 3),
    "codes": (np.arange(40) % 251).astype(np.uint8).reshape(10, 4),
    "signed": np.array([[-128, 127], [0, -1], [5, 6]], dtype=np.int8),
    "short": np.arange(9, dtype=np.uint16),
    "wide": np.array([0, 70000, 2**32 - 1], dtype=np.int64),
    "matrices": np.stack([np.arange(16.0).reshape(4, 4), np.eye(4)]),
}
SCREEN = {"offsets": np.array([[0.5, -0.25], [1.0, 2.0]]), "weights": np.array([0.25, 0.75])}


def stored(array: np.ndarray) -> np.ndarray:
    """What the writer stores for a table (float32 floats, 8/16-bit integers as they are, uint32)."""
    if array.dtype.kind == "f":
        return array.astype(np.float32)
    return array if array.dtype.itemsize <= 2 else array.astype(np.uint32)


@pytest.fixture
def glb(tmp_path):
    asset = icosphere_asset()
    asset = replace(asset, mesh_extras={0: {"prt": {"order": 3, **TABLES, "nested": [{"deep": np.arange(3.0)}]}}},
                    material_extras={0: {"screen": dict(SCREEN)}})
    path = tmp_path / "a.glb"
    write_glb(asset, path)
    return path


def edit(path, change, generator: str = TRANSFORM):
    """Rewrite `path` after `change(gltf, blob) -> blob or None`, as another tool would save it."""
    gltf = pygltflib.GLTF2.load(str(path))
    blob = bytearray(gltf.binary_blob())
    blob = change(gltf, blob) or blob
    gltf.asset.generator = generator
    gltf.set_binary_blob(bytes(blob))
    gltf.save_binary(str(path))


def renumber(gltf: pygltflib.GLTF2, order: list[int]) -> None:
    """Reorder the accessor list to `order` (old indices) and rewrite every glTF index to them, as
    glTF-Transform's weld does, but not the indices inside the extension."""
    new = {old: i for i, old in enumerate(order)}
    gltf.accessors = [gltf.accessors[i] for i in order]
    for mesh in gltf.meshes:
        for prim in mesh.primitives:
            for name, index in list(vars(prim.attributes).items()):
                if index is not None:
                    setattr(prim.attributes, name, new[index])
            prim.indices = new[prim.indices]


def mesh_refs(path) -> dict:
    return pygltflib.GLTF2.load(str(path)).meshes[0].extensions[EXTENSION]["prt"]


def test_every_table_kind_round_trips(glb):
    data = load_sssbake_gltf(glb)
    read = technique_tables(data, "meshes", 0, "prt")
    assert read["order"] == 3
    for key, value in TABLES.items():
        assert read[key].dtype == stored(value).dtype, key
        np.testing.assert_array_equal(read[key], stored(value))
    np.testing.assert_array_equal(read["nested"][0]["deep"], np.arange(3.0, dtype=np.float32))
    screen = technique_tables(data, "materials", 0, "screen")
    for key, value in SCREEN.items():
        np.testing.assert_array_equal(screen[key], value.astype(np.float32))
    assert technique_tables(data, "meshes", 1, "prt") is None


def test_references_name_describe_and_checksum_their_accessors(glb):
    gltf = pygltflib.GLTF2.load(str(glb))
    blob = gltf.binary_blob()
    refs = gltf.meshes[0].extensions[EXTENSION]["prt"]
    assert refs["matrices"]["type"] == "MAT4" and refs["wide"]["componentType"] == UNSIGNED_INT
    assert refs["nested"][0]["deep"]["name"] == "sssbake/mesh0/prt/nested/0/deep"
    screen = gltf.materials[0].extensions[EXTENSION]["screen"]["offsets"]
    assert screen["name"] == "sssbake/material0/screen/offsets" and screen["componentType"] == FLOAT
    for key, value in TABLES.items():
        ref = refs[key]
        acc = gltf.accessors[ref["accessor"]]
        assert (acc.name, acc.count, acc.type, acc.componentType) == (
            f"sssbake/mesh0/prt/{key}", ref["count"], ref["type"], ref["componentType"])
        # The CRC-32 another way: of the stored values' bytes (glTF's column-major order for MATk) ...
        elements = stored(value).transpose(0, 2, 1) if value.ndim == 3 else stored(value)
        assert ref["crc32"] == f"{zlib.crc32(elements.astype(elements.dtype.newbyteorder('<')).tobytes()):08x}", key
        # ... and of the buffer view's bytes (tables are tightly packed, no stride).
        view = gltf.bufferViews[acc.bufferView]
        assert view.byteStride is None
        assert ref["crc32"] == f"{zlib.crc32(blob[view.byteOffset:view.byteOffset + view.byteLength]):08x}", key


def test_renumbered_accessors_resolve_by_name(glb):
    before = technique_tables(load_sssbake_gltf(glb), "meshes", 0, "prt")
    edit(glb, lambda gltf, blob: renumber(gltf, list(range(len(gltf.accessors)))[::-1]))
    refs = mesh_refs(glb)
    gltf = pygltflib.GLTF2.load(str(glb))
    assert gltf.accessors[refs["floats"]["accessor"]].name != refs["floats"]["name"]  # the stale index
    data = load_sssbake_gltf(glb)
    after = technique_tables(data, "meshes", 0, "prt")
    for key in TABLES:
        np.testing.assert_array_equal(after[key], before[key])
    thickness = data.attribute(0, 0, "_THICKNESS")
    assert thickness.shape == (42,)
    assert inspect_glb(glb)["meshes"][0]["techniques"]["prt"]["tables"]["floats"]["accessor"] == (
        len(gltf.accessors) - 1 - refs["floats"]["accessor"])


def test_a_deleted_table_is_refused_naming_the_tool(glb):
    victim = mesh_refs(glb)["codes"]["accessor"]

    def delete(gltf, blob):
        renumber(gltf, [i for i in range(len(gltf.accessors)) if i != victim])

    edit(glb, delete)
    data = load_sssbake_gltf(glb)
    with pytest.raises(StaleDataError) as caught:
        technique_tables(data, "meshes", 0, "prt")
    message = str(caught.value)
    assert "\n" not in message and message.startswith(f"{glb}: ")
    assert "'sssbake/mesh0/prt/codes'" in message and "no accessor bears its name" in message
    assert f"likely broken by glTF-Transform (asset.generator '{TRANSFORM}')" in message
    assert message.endswith("run it with sssbake's extension class (--config js/gltf-transform/sssbake.config.mjs) "
                            "on the baked file")
    assert isinstance(caught.value, AssetError) and isinstance(caught.value, ValueError)
    with pytest.raises(StaleDataError, match="sssbake/mesh0/prt/codes"):
        inspect_glb(glb)


def test_overwritten_table_bytes_fail_the_checksum(glb):
    ref = mesh_refs(glb)["floats"]

    def overwrite(gltf, blob):
        view = gltf.bufferViews[gltf.accessors[ref["accessor"]].bufferView]
        blob[view.byteOffset:view.byteOffset + 4] = struct.pack("<f", 123.0)

    edit(glb, overwrite, generator="gltfpack 1.3")
    with pytest.raises(StaleDataError, match=r"sssbake/mesh0/prt/floats.*CRC-32 [0-9a-f]{8}, the reference "
                                             rf"{ref['crc32']}; likely broken by gltfpack"):
        technique_tables(load_sssbake_gltf(glb), "meshes", 0, "prt")


@pytest.mark.parametrize("field, value, needle", [
    ("count", 6, "count 6, the reference 7"),
    ("componentType", 5122, "componentType 5122, the reference 5126"),
    ("type", "VEC2", "type 'VEC2', the reference 'VEC3'"),
])
def test_changed_accessor_fields_are_refused(glb, field, value, needle):
    ref = mesh_refs(glb)["floats"]
    edit(glb, lambda gltf, blob: setattr(gltf.accessors[ref["accessor"]], field, value),
         generator="Khronos glTF Blender I/O v4.5.0")
    with pytest.raises(StaleDataError, match=f"{needle}; likely broken by Blender"):
        technique_tables(load_sssbake_gltf(glb), "meshes", 0, "prt")


def test_a_duplicated_name_or_a_bare_index_is_refused(glb):
    refs = mesh_refs(glb)
    edit(glb, lambda gltf, blob: setattr(gltf.accessors[refs["codes"]["accessor"]], "name", refs["floats"]["name"]),
         generator="some editor")
    data = load_sssbake_gltf(glb)
    # floats' own index still bears its name: found; codes' name is gone
    with pytest.raises(StaleDataError, match="'sssbake/mesh0/prt/codes'.*no accessor bears.*a tool that did not keep"):
        technique_tables(data, "meshes", 0, "prt")
    data.gltf.accessors[refs["floats"]["accessor"]].name = "renamed"
    data.gltf.accessors[refs["short"]["accessor"]].name = refs["floats"]["name"]
    with pytest.raises(StaleDataError, match=r"2 accessors \(\[\d+, \d+\]\) bear"):
        data.resolve(refs["floats"], "prt.floats")
    with pytest.raises(StaleDataError, match="is not a table reference"):
        data.resolve({"accessor": refs["floats"]["accessor"]}, "prt.floats")


def test_sparse_accessors_read_with_their_substitutions(glb):
    """A table a tool rewrote as sparse (zeros plus substitutions) reads and checks the same."""
    ref = mesh_refs(glb)["short"]
    values = stored(TABLES["short"])

    def sparsify(gltf, blob):
        acc = gltf.accessors[ref["accessor"]]
        rows = np.flatnonzero(values).astype(np.uint32)
        start = len(blob)
        blob += rows.astype("<u4").tobytes() + values[rows].astype("<u2").tobytes()
        blob += b"\0" * (-len(blob) % 4)
        gltf.bufferViews += [pygltflib.BufferView(buffer=0, byteOffset=start, byteLength=4 * len(rows)),
                             pygltflib.BufferView(buffer=0, byteOffset=start + 4 * len(rows), byteLength=2 * len(rows))]
        acc.bufferView = None
        acc.sparse = pygltflib.Sparse(
            count=len(rows), indices=pygltflib.AccessorSparseIndices(
                bufferView=len(gltf.bufferViews) - 2, componentType=5125),
            values=pygltflib.AccessorSparseValues(bufferView=len(gltf.bufferViews) - 1))
        gltf.buffers[0].byteLength = len(blob)
        return blob

    edit(glb, sparsify)
    np.testing.assert_array_equal(technique_tables(load_sssbake_gltf(glb), "meshes", 0, "prt")["short"], values)


def test_vertex_attributes_are_checked_against_their_declaration(glb):
    def retype(gltf, blob):
        index = gltf.meshes[0].primitives[0].attributes._SSS_W
        gltf.accessors[index].componentType = 5121  # snorm8 declared: BYTE

    edit(glb, retype)
    data = load_sssbake_gltf(glb)
    np.testing.assert_array_equal(data.attribute(0, 0, "_THICKNESS").shape, (42,))
    with pytest.raises(StaleDataError, match="attribute _SSS_W is componentType 5121, normalized True, VEC3 x 42; "
                                             "declared 5120, True, VEC3 x 42"):
        data.attribute(0, 0, "_SSS_W")
    with pytest.raises(StaleDataError, match="_SSS_W"):
        inspect_glb(glb)


def test_a_changed_position_count_is_refused_for_vertex_data(glb):
    """A simplify or weld that changed POSITION but not an attribute leaves the attribute
    describing other vertices: refused."""
    def shrink(gltf, blob):
        gltf.accessors[gltf.meshes[0].primitives[0].attributes.POSITION].count = 40

    edit(glb, shrink)
    data = load_sssbake_gltf(glb)
    with pytest.raises(StaleDataError, match=r"attribute _THICKNESS is .* x 42; declared .* x 40 \(POSITION\)"):
        data.attribute(0, 0, "_THICKNESS")
    with pytest.raises(StaleDataError):
        inspect_glb(glb)


def test_missing_or_undeclared_attributes_are_refused(glb):
    edit(glb, lambda gltf, blob: setattr(gltf.meshes[0].primitives[0].attributes, "_SSS_REF", None))
    data = load_sssbake_gltf(glb)
    with pytest.raises(StaleDataError, match="mesh 0 primitive 0 lacks vertex attribute _SSS_REF"):
        data.attribute(0, 0, "_SSS_REF")
    with pytest.raises(StaleDataError, match="_NOPE is not declared"):
        data.attribute(0, 0, "_NOPE")


def test_a_dropped_extension_is_refused_when_sssbake_attributes_remain(glb):
    def drop(gltf, blob):
        gltf.extensions = {}
        gltf.extensionsUsed = [e for e in gltf.extensionsUsed if e != EXTENSION]
        for obj in [*gltf.meshes, *gltf.materials]:
            obj.extensions.pop(EXTENSION, None)

    edit(glb, drop)
    with pytest.raises(StaleDataError, match=r"sssbake vertex attributes \[.*'_THICKNESS'\] without the root's "
                                             "SSSBAKE_subsurface object; likely broken by glTF-Transform"):
        load_sssbake_gltf(glb)


def test_schema_1_files_are_refused(glb):
    def downgrade(gltf, blob):
        gltf.extras = {"sssbake": {**gltf.extensions.pop(EXTENSION), "schemaVersion": "1.8.0"}}

    edit(glb, downgrade, generator="sssbake 0.1.0")
    with pytest.raises(StaleDataError, match=r"written by sssbake schema 1\.x \(extras\.sssbake\); rebake it"):
        load_sssbake_gltf(glb)
    with pytest.raises(StaleDataError, match="schema 1.x"):
        inspect_glb(glb)


def test_another_major_version_is_refused(glb):
    edit(glb, lambda gltf, blob: gltf.extensions[EXTENSION].update(schemaVersion="3.0.0"))
    with pytest.raises(StaleDataError, match="schemaVersion '3.0.0': this sssbake reads 2.x"):
        load_sssbake_gltf(glb)


def test_a_file_stripped_of_all_sssbake_data_is_refused_by_readers(glb):
    """gltfpack drops the extension and every `_` attribute: nothing stale is left to point at, but
    a reader asking for sssbake data names the tool."""
    from sssbake.pipeline.techniques.prt.reader import read_prt_glb

    def strip(gltf, blob):
        gltf.extensions = {}
        for mesh in gltf.meshes:
            mesh.extensions = {}
            for prim in mesh.primitives:
                for name in [n for n in vars(prim.attributes) if n.startswith("_")]:
                    setattr(prim.attributes, name, None)

    edit(glb, strip, generator="gltfpack 1.3")
    assert load_sssbake_gltf(glb).root is None  # inspect still summarises it
    assert inspect_glb(glb)["schemaVersion"] is None
    with pytest.raises(StaleDataError, match="no SSSBAKE_subsurface data .*; likely broken by gltfpack"):
        read_prt_glb(glb)
