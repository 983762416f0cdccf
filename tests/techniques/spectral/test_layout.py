"""How spectral normals are laid out: the float32 attribute, the welded vertex ids, the viewer variant."""

from dataclasses import replace

import numpy as np
import pytest
from test_gltf import icosphere_asset

from sssbake.pipeline.mesh.baked import VertexAttribute
from sssbake.pipeline.techniques.spectral.layout import (
    NORMAL_KEY,
    VERTEX_KEY,
    normals_variant,
    spectral_bytes,
    spectral_vertex_attributes,
)


def test_attributes_of_a_primitive():
    normals = np.array([[1.0 + 1e-15, 0.0, 0.0], [0.0, -1.0, 0.0], [0.6, 0.0, 0.8]])
    vertices = np.array([2, 0, 0, 1])
    (normal,) = spectral_vertex_attributes(normals, vertices, with_vertex=False)
    assert (normal.key, normal.encoding, normal.gltf_name) == (NORMAL_KEY, "float32", "_SSS_NORMAL")
    assert normal.usd_name == "primvars:sss:normal"
    np.testing.assert_array_equal(normal.data, normals[vertices])
    _, vertex = spectral_vertex_attributes(normals, vertices, with_vertex=True)
    assert (vertex.key, vertex.encoding) == (VERTEX_KEY, "float32")
    # (id, 0, 0): the VEC3 width of every sssbake attribute; beyond 16 bits float32 stays exact
    np.testing.assert_array_equal(vertex.data, np.c_[vertices, np.zeros((4, 2))])
    _, wide = spectral_vertex_attributes(np.tile(normals, (30000, 1)), np.array([0, 70000]), with_vertex=True)
    np.testing.assert_array_equal(wide.data, [[0, 0, 0], [70000, 0, 0]])
    with pytest.raises(ValueError, match="welded vertices"):
        spectral_vertex_attributes(normals, np.array([3]), with_vertex=True)


def test_bytes_without_tables_count_only_the_normal():
    assert spectral_bytes(10, 4, False) == {"values": 0, "coefficients": 0, "residual": 0, "basis": 0, "total": 0,
                                            "perVertex": 0.0, "normalPerRenderVertex": 12,
                                            "vertexIdsPerRenderVertex": 0}
    assert spectral_bytes(10, 4, True)["total"] == 16 + 48 + 120 + 160


def test_variant_swaps_normals_and_drops_technique_data():
    asset = icosphere_asset()
    prim = asset.scene.meshes[0].primitives[0]
    n = len(prim.positions)
    tilted = prim.normals / np.linalg.norm(prim.normals, axis=1, keepdims=True) @ np.diag([1.0, 1.0, -1.0])
    extra = VertexAttribute("sss:kernels:vertex", np.arange(n, dtype=float), "", "float32", "ids")
    attrs = asset.vertex_attributes[(0, 0)] + spectral_vertex_attributes(tilted, np.arange(n), True) + (extra,)
    variant = normals_variant(replace(asset, vertex_attributes={(0, 0): attrs}, mesh_extras={0: {"kernels": {}}}))
    np.testing.assert_array_equal(variant.scene.meshes[0].primitives[0].normals, tilted)
    assert variant.scene.meshes[1] is asset.scene.meshes[1]
    assert [a.key for a in variant.vertex_attributes[(0, 0)]] == ["thickness", NORMAL_KEY]
    assert variant.mesh_extras == {} and variant.extras["variant"] == "sss_normals"
    assert variant.scattering == asset.scattering
