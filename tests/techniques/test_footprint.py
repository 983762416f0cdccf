"""footprint: bytes per render vertex of each technique, attributes and tables, as a file holds them."""

from dataclasses import replace

import numpy as np
import pytest

from sssbake.exporters.gltf import write_glb
from sssbake.exporters.inspect_gltf import inspect_glb
from sssbake.exporters.inspect_usd import inspect_usdc
from sssbake.exporters.usd import write_usdc
from sssbake.pipeline.mesh.baked import VertexAttribute
from sssbake.pipeline.techniques.footprint import footprint


def _asset():
    """The exporters' icosphere (42 vertices, material 0) and plate (3 vertices, material 1) with a prt
    attribute and table on the sphere, a kernels table on the plate's mesh and screen tables on the
    sphere's material."""
    from test_gltf import icosphere_asset

    asset = icosphere_asset()
    n = 42
    ref = VertexAttribute("sss:prt:ref", np.zeros((n, 3)), "", "float32")  # 12 B a vertex
    return replace(asset, vertex_attributes={(0, 0): (*asset.vertex_attributes[(0, 0)], ref)},
                   mesh_extras={0: {"prt": {"codes": np.arange(10, dtype=np.uint16).reshape(5, 2)}},  # 20 B
                                1: {"kernels": {"texels": np.zeros(6, np.float32)}}},  # 24 B
                   material_extras={0: {"screen": {"weights": np.zeros((4, 3), np.float32)}}})  # 48 B


def test_closed_form_bytes_per_vertex_in_both_formats(tmp_path):
    asset = _asset()
    write_glb(asset, tmp_path / "a.glb")
    write_usdc(asset, tmp_path / "a.usdc")
    used = footprint(inspect_glb(tmp_path / "a.glb"))
    per = used["techniques"]
    assert list(per) == ["prt", "kernels", "screen", "fallback"]
    assert per["prt"] == {"vertices": 42, "attributeBytes": 42 * 12, "tableBytes": 20,
                          "attributes": 12.0, "tables": 20 / 42, "total": pytest.approx(12 + 20 / 42)}
    assert per["kernels"] == {"vertices": 3, "attributeBytes": 0, "tableBytes": 24,
                              "attributes": 0.0, "tables": 8.0, "total": 8.0}
    assert per["screen"]["vertices"] == 42 and per["screen"]["tables"] == 48 / 42 > 0
    # the exporters' test attributes (_THICKNESS, _SSS_W, _SSS_U16, _SSS_REF: 28 B) belong to no technique
    assert per["fallback"]["attributes"] == 28.0 and per["fallback"]["tableBytes"] == 0
    assert used["file"] == {"vertices": 45, "attributeBytes": 42 * 40, "tableBytes": 92,
                            "attributes": 42 * 40 / 45, "tables": 92 / 45, "total": pytest.approx((42 * 40 + 92) / 45)}
    sphere, plate = used["meshes"]
    assert sphere["vertices"] == 42 and list(sphere["techniques"]) == ["prt", "screen", "fallback"]
    assert plate["techniques"]["kernels"]["tables"] == 8.0 and "screen" not in plate["techniques"]
    # USD packs the exporters' snorm8 test attributes into ints of its own size: the techniques' alike
    usd = footprint(inspect_usdc(tmp_path / "a.usdc"))
    assert {t: f for t, f in usd["techniques"].items() if t != "fallback"} == {
        t: f for t, f in per.items() if t != "fallback"}
