"""inspect_glb reports the sssbake content and bytes per vertex of a written file."""

from test_gltf import icosphere_asset

from sssbake.exporters.gltf import EXTENSION, write_glb
from sssbake.exporters.inspect_gltf import inspect_glb
from sssbake.pipeline.mesh.baked import SCHEMA_VERSION


def test_inspect_reports_attributes_and_bytes_per_vertex(tmp_path):
    asset = icosphere_asset()
    summary = write_glb(asset, tmp_path / "a.glb")
    info = inspect_glb(tmp_path / "a.glb")

    assert info["schemaVersion"] == SCHEMA_VERSION
    assert info["bytes"] == summary["bytes"]
    assert info["generator"].startswith("sssbake ")
    assert {EXTENSION, "KHR_materials_volume", "KHR_materials_diffuse_transmission",
            "KHR_materials_ior"} <= set(info["extensionsUsed"])
    assert info["extensionsRequired"] == []
    assert info["asset"]["scaleMm"] == {"sphere": 10.0}

    sphere, plate = info["meshes"]
    assert sphere["name"] == "sphere" and sphere["sssbake"]["scaleMm"] == 10.0 and sphere["vertexCountsMatch"]
    prim = sphere["primitives"][0]
    assert prim["vertices"] == 42 and prim["material"] == 0
    attrs = prim["attributes"]
    assert sorted(attrs) == ["_SSS_REF", "_SSS_U16", "_SSS_W", "_THICKNESS"]
    assert attrs["_SSS_W"] == {"accessor": attrs["_SSS_W"]["accessor"], "count": 42, "type": "VEC3",
                               "componentType": "BYTE", "normalized": True, "bytes": 42 * 4, "bytesPerVertex": 4.0}
    assert {k: a["bytesPerVertex"] for k, a in attrs.items()} == {
        "_THICKNESS": 4.0, "_SSS_W": 4.0, "_SSS_U16": 4.0, "_SSS_REF": 16.0,
    }
    assert attrs["_SSS_U16"]["componentType"] == "UNSIGNED_SHORT"
    assert prim["bytesPerVertex"] == 28.0
    assert plate["primitives"][0]["attributes"] == {} and plate["sssbake"] is None
    assert plate["vertexCountsMatch"] is None

    assert info["bytesPerVertex"]["_SSS_REF"] == 16.0
    assert info["bytesPerVertex"]["total"] == 28.0 * 42 / 45
    for key in ("_THICKNESS", "_SSS_W", "_SSS_U16", "_SSS_REF"):
        assert info["bytesPerVertex"][key] == summary["bytes_per_vertex"][key]

    (material,) = info["materials"]
    assert material["index"] == 0 and material["name"] == "Marble"
    assert material["sssbake"]["material"]["units"] == "1/mm"
    assert "KHR_materials_volume" in material["extensions"]


def test_inspect_lists_each_table_with_its_name_and_checksum(tmp_path):
    from dataclasses import replace

    import numpy as np
    import pygltflib

    table = np.arange(10, dtype=np.uint16).reshape(5, 2)
    write_glb(replace(icosphere_asset(), mesh_extras={0: {"prt": {"codes": table}}}), tmp_path / "a.glb")
    info = inspect_glb(tmp_path / "a.glb")
    entry = info["meshes"][0]["techniques"]["prt"]["tables"]["codes"]
    ref = pygltflib.GLTF2.load(str(tmp_path / "a.glb")).meshes[0].extensions[EXTENSION]["prt"]["codes"]
    assert entry == {"accessor": ref["accessor"], "name": "sssbake/mesh0/prt/codes", "crc32": ref["crc32"], "count": 5,
                     "type": "VEC2", "componentType": "UNSIGNED_SHORT", "normalized": False, "bytes": 20}
    assert info["meshes"][0]["techniques"]["prt"]["bytes"] == 20
