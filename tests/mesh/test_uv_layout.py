"""The input's UVs checked and reused, a proxy's charts carried back (pipeline/mesh/uv_check.py,
pipeline/mesh/proxy_atlas.py)."""

import json
from dataclasses import replace

import numpy as np
import pytest
import trimesh
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from test_tangents import uv_sphere

from sssbake.pipeline.mesh.proxy_atlas import layout_atlas
from sssbake.pipeline.mesh.uv_check import check_uvs


def _grid(n: int = 16) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """An n × n quad grid on the unit square (z = 0), split in triangles; its UVs are (x, y)."""
    x, y = np.meshgrid(np.linspace(0.0, 1.0, n + 1), np.linspace(0.0, 1.0, n + 1))
    positions = np.column_stack([x.ravel(), y.ravel(), np.zeros(x.size)])
    i, j = np.meshgrid(np.arange(n), np.arange(n))
    a = (j * (n + 1) + i).ravel()
    faces = np.concatenate([np.column_stack([a, a + 1, a + n + 2]), np.column_stack([a, a + n + 2, a + n + 1])])
    return positions, faces, positions[:, :2].copy()


def test_valid_input_uvs_are_reused_as_they_are():
    positions, faces, uvs = _grid()
    check = check_uvs([(uvs, faces, positions)], 64, 64)
    assert check.ok and check.reason == ""
    assert check.coverage == pytest.approx(1.0)  # the grid fills the unit square
    assert check.overlap == 0.0 and check.uniformity == pytest.approx(1.0)
    atlas = layout_atlas([(positions, faces, (uvs,))], 62, 2)
    assert atlas.source == "TEXCOORD_0" and atlas.input_uv_set == 0 and atlas.notes == ()
    assert (atlas.width, atlas.height) == (64, 64)  # the resolution in whole 4x4 blocks
    part = atlas.parts[0]
    np.testing.assert_array_equal(part.vmapping, np.arange(len(positions)))
    np.testing.assert_array_equal(part.faces, faces)
    np.testing.assert_array_equal(part.uvs, uvs)


def test_the_first_valid_set_is_taken_and_the_refusals_named():
    positions, faces, uvs = _grid()
    atlas = layout_atlas([(positions, faces, (uvs * 2.0, uvs))], 64, 2)
    assert atlas.source == "TEXCOORD_1"
    assert len(atlas.notes) == 1 and atlas.notes[0].startswith("input TEXCOORD_0: UVs outside [0, 1]")


def test_mirrored_uvs_overlap_and_are_refused():
    positions, faces, uvs = _grid()
    folded = uvs.copy()
    folded[:, 0] = 0.5 - np.abs(uvs[:, 0] - 0.5)  # the right half mirrored onto the left
    check = check_uvs([(folded, faces, positions)], 64, 64)
    assert not check.ok and "overlap" in check.reason
    assert check.overlap > 0.95  # every covered texel is covered by both halves


def test_uvs_whose_areas_exceed_the_texture_are_refused_unrasterised():
    positions, faces, uvs = _grid()
    stacked = np.concatenate([faces, faces[:20]])  # 20 triangles twice: 1 + 20 / 512 of the texture
    check = check_uvs([(uvs, stacked, positions)], 64, 64)
    assert not check.ok and "add up to 1.04 times" in check.reason
    assert check.coverage == pytest.approx(1.0 + 20 / 512)


def test_out_of_range_uvs_are_refused_and_the_mesh_charted():
    positions, faces, uvs = _grid()
    check = check_uvs([(uvs + 0.5, faces, positions)], 64, 64)
    assert not check.ok and "outside [0, 1]" in check.reason and "0.5 .. 1.5" in check.reason
    atlas = layout_atlas([(positions, faces, (uvs + 0.5,))], 64, 2)
    assert atlas.source == "charted" and atlas.chart_count >= 1
    assert "outside [0, 1]" in atlas.notes[0]


def test_too_little_texel_density_is_refused():
    positions, faces, uvs = _grid()
    check = check_uvs([(uvs * 0.4, faces, positions)], 64, 64)
    assert not check.ok and "cover" in check.reason
    assert check.coverage == pytest.approx(0.16)  # 0.4² of the texture


def test_uneven_density_is_refused():
    positions, faces, uvs = _grid()
    squeezed = uvs.copy()
    squeezed[:, 0] = uvs[:, 0] ** 4  # columns near x = 0 get a tiny share of u
    check = check_uvs([(squeezed, faces, positions)], 64, 64)
    assert not check.ok and "median texel density" in check.reason
    assert check.uniformity < 0.25


def test_collapsed_uvs_are_degenerate():
    positions, faces, uvs = _grid()
    collapsed = uvs.copy()
    collapsed[positions[:, 0] < 0.3] = 0.0  # a third of the surface on one UV point
    check = check_uvs([(collapsed, faces, positions)], 64, 64)
    assert not check.ok and "degenerate" in check.reason


def test_kernels_get_a_charted_atlas_even_with_valid_uvs():
    positions, faces, uvs = _grid()
    atlas = layout_atlas([(positions, faces, (uvs,))], 64, 2, reuse_input=False)
    assert atlas.source == "charted" and atlas.input_uv_set is None


def test_a_proxys_charts_carried_back_to_a_sphere_do_not_fold():
    sphere = trimesh.creation.icosphere(4)  # 5120 triangles
    positions, faces = np.asarray(sphere.vertices), np.asarray(sphere.faces, dtype=np.int64)
    atlas = layout_atlas([(positions, faces, ())], 128, 2, proxy_faces=400, proxy_min_faces=1000)
    assert atlas.source == "proxy", atlas.notes
    assert atlas.notes == ("input UVs: none",)
    part = atlas.parts[0]
    np.testing.assert_array_equal(part.vmapping[part.faces], faces)  # same triangles, seams split
    assert part.uvs.min() >= 0.0 and part.uvs.max() <= 1.0
    # independent of the checker: within each chart every UV triangle turns the same way, and the
    # charts' UV areas are proportional to their surface areas within a factor of 2
    n = len(part.uvs)
    edges = coo_matrix((np.ones(2 * len(faces)), (part.faces[:, [0, 1]].ravel(), part.faces[:, [1, 2]].ravel())),
                       shape=(n, n))
    charts, label = connected_components(edges, directed=False)
    chart = label[part.faces[:, 0]]
    assert charts > 1
    uv = part.uvs[part.faces]
    e0, e1 = uv[:, 1] - uv[:, 0], uv[:, 2] - uv[:, 0]
    signed = e0[:, 0] * e1[:, 1] - e0[:, 1] * e1[:, 0]
    orientation = np.sign(np.bincount(chart, weights=signed))
    assert (signed * orientation[chart] > 0).mean() > 0.999
    surface = trimesh.triangles.area(positions[faces])
    ratio = np.bincount(chart, weights=np.abs(signed) / 2) / np.bincount(chart, weights=surface)
    big = np.bincount(chart, weights=surface) > 0.01 * surface.sum()
    assert ratio[big].max() / ratio[big].min() < 2.0


def test_a_cached_atlas_may_name_only_a_uv_set_the_input_has():
    from sssbake.pipeline.bake.invariants import BrokenInvariant
    from sssbake.pipeline.bake.stages import AtlasParams, _atlas_holds

    positions, faces, uvs = _grid()
    parts = [(positions, faces, (uvs,))]
    atlas = layout_atlas(parts, 64, 2)
    _atlas_holds(atlas, parts, AtlasParams(64, 2, True))
    for source, params in (("TEXCOORD_1", AtlasParams(64, 2, True)), ("TEXCOORD_x", AtlasParams(64, 2, True)),
                           ("TEXCOORD_0", AtlasParams(64, 2, False))):
        with pytest.raises(BrokenInvariant, match="atlas.source"):
            _atlas_holds(replace(atlas, source=source), parts, params)


def test_a_folded_carry_back_falls_back_to_charting_the_mesh(monkeypatch):
    import sssbake.pipeline.mesh.proxy_atlas as proxy_atlas

    carried = proxy_atlas.carry_back

    def folded(*args):
        part = carried(*args)
        return replace(part, uvs=np.abs(part.uvs - 0.5) + 0.25)  # every quadrant onto one: overlaps

    monkeypatch.setattr(proxy_atlas, "carry_back", folded)
    sphere = trimesh.creation.icosphere(4)
    positions, faces = np.asarray(sphere.vertices), np.asarray(sphere.faces, dtype=np.int64)
    atlas = layout_atlas([(positions, faces, ())], 128, 2, proxy_faces=400, proxy_min_faces=1000)
    assert atlas.source == "charted" and atlas.chart_count >= 1
    assert atlas.notes[1].startswith("proxy charts: UV triangles overlap on")
    assert atlas.notes[1].endswith("the whole mesh was charted")
    np.testing.assert_array_equal(atlas.parts[0].vmapping[atlas.parts[0].faces], faces)


def _glb_json(path) -> dict:
    data = path.read_bytes()
    length = int.from_bytes(data[12:16], "little")
    return json.loads(data[20:20 + length])


def _bake_ball(tmp_path, techniques: tuple[str, ...]) -> tuple[dict, dict, np.ndarray]:
    """A UV sphere with valid UVs written as .glb and baked with `techniques`: the report, the
    output's glTF JSON and the sphere's triangles."""
    from sssbake.exporters.gltf import write_glb
    from sssbake.pipeline.bake.asset import bake_asset
    from sssbake.pipeline.bake.cache import StageCache
    from sssbake.pipeline.mesh.baked import BakedAsset
    from sssbake.pipeline.mesh.scene import Mesh, Node, Primitive, Scene, SourceMaterial
    from sssbake.pipeline.options import BakeOptions

    positions, faces, uvs = uv_sphere(12, 24)
    prim = Primitive(positions, faces, positions.copy(), (uvs,), material=0)
    scene = Scene("s.glb", (Mesh("ball", (prim,)),), (Node("n", np.eye(4), 0),), (0,),
                  materials=(SourceMaterial("wax"),))
    write_glb(BakedAsset(scene), tmp_path / "ball.glb")
    (tmp_path / "out").mkdir()
    result = bake_asset(tmp_path / "ball.glb", BakeOptions(scale_mm=20.0, atlas_resolution=64, validate=False,
                                                           techniques=techniques),
                        tmp_path / "out" / "ball", StageCache(tmp_path / "cache"))
    return result.report, _glb_json(tmp_path / "out" / "ball.glb"), faces


def test_a_bake_keeps_the_inputs_uvs_for_the_thickness_texture(tmp_path):
    report, gltf, faces = _bake_ball(tmp_path, ())
    block = report["atlas"]["ball"]
    assert block["uvs"] == "TEXCOORD_0" and block["refused"] == [] and block["charts"] == 0
    attributes = gltf["meshes"][0]["primitives"][0]["attributes"]
    assert "TEXCOORD_0" in attributes and "TEXCOORD_1" not in attributes  # no second set for the atlas
    thickness_refs = [t for m in gltf["materials"] for t in _texture_refs(m)]
    assert thickness_refs and all(ref.get("texCoord", 0) == 0 for ref in thickness_refs)
    # the input's vertices kept as they are: as many as its triangles use (no seam duplicates added)
    accessor = gltf["accessors"][attributes["TEXCOORD_0"]]
    assert accessor["count"] == len(np.unique(faces))


def test_kernels_chart_their_own_atlas_beside_valid_uvs(tmp_path):
    report, gltf, _ = _bake_ball(tmp_path, ("kernels",))
    assert report["atlas"]["ball"]["uvs"] == "charted" and report["atlas"]["ball"]["charts"] >= 1
    attributes = gltf["meshes"][0]["primitives"][0]["attributes"]
    assert "TEXCOORD_1" in attributes  # the input's set kept, the atlas's added after it
    thickness_refs = [t for m in gltf["materials"] for t in _texture_refs(m)]
    assert thickness_refs and all(ref.get("texCoord", 0) == 1 for ref in thickness_refs)


def _texture_refs(node) -> list[dict]:
    """Every textureInfo object ({"index": ...}) under a glTF JSON node."""
    if isinstance(node, dict):
        own = [node] if "index" in node and isinstance(node["index"], int) else []
        return own + [r for v in node.values() for r in _texture_refs(v)]
    if isinstance(node, list):
        return [r for v in node for r in _texture_refs(v)]
    return []


def _hexagon_with_needle(gap: float) -> tuple[np.ndarray, np.ndarray]:
    """A unit hexagon fanned around a centre split into two vertices `gap` apart on the x axis
    (8 triangles, two of them needles along the split), plus a cap on edge h0-h1: a vertex at its
    midpoint and the zero-area triangle (h0, m, h1). Vertices: h0..h5, c0, c1, m."""
    angle = np.radians(60.0 * np.arange(6))
    hexagon = np.column_stack([np.cos(angle), np.sin(angle), np.zeros(6)])
    c0, c1, m = [-gap / 2, 0.0, 0.0], [gap / 2, 0.0, 0.0], (hexagon[0] + hexagon[1]) / 2
    positions = np.vstack([hexagon, c0, c1, m])
    faces = np.array([[7, 5, 0], [7, 0, 1], [7, 1, 6], [6, 1, 2], [6, 2, 3], [6, 3, 4], [6, 4, 7], [7, 4, 5],
                      [0, 8, 1]])
    return positions, faces


def test_a_proxys_needles_are_collapsed_and_its_caps_dropped():
    from sssbake.pipeline.mesh.proxy_atlas import _clean_proxy
    from sssbake.pipeline.mesh.simplify import Simplified

    positions, faces = _hexagon_with_needle(1e-4)
    none = np.zeros(0, dtype=np.int64)
    cleaned, kept = _clean_proxy(Simplified(positions, faces, none, none))
    # the split centre merges at its mean (the origin), both needles and the cap go, the cap's
    # vertex with it: the hexagon's 6-triangle fan, winding kept
    np.testing.assert_allclose(cleaned, np.vstack([positions[:6], [[0.0, 0.0, 0.0]]]), atol=1e-15)
    fan = {tuple(np.roll(t, -int(np.argmin(t)))) for t in kept.tolist()}
    assert fan == {(0, 1, 6), (1, 2, 6), (2, 3, 6), (3, 4, 6), (4, 5, 6), (0, 6, 5)}
    # a split wider than SLIVER_EDGE of the median edge (1) stays; only the cap goes
    positions, faces = _hexagon_with_needle(0.2)
    cleaned, kept = _clean_proxy(Simplified(positions, faces, none, none))
    np.testing.assert_array_equal(cleaned, positions[:8])
    np.testing.assert_array_equal(kept, faces[:8])


def test_a_proxy_without_slivers_is_kept_as_it_is():
    from sssbake.pipeline.mesh.proxy_atlas import _clean_proxy
    from sssbake.pipeline.mesh.simplify import Simplified

    sphere = trimesh.creation.icosphere(3)
    none = np.zeros(0, dtype=np.int64)
    positions, faces = _clean_proxy(Simplified(np.asarray(sphere.vertices), np.asarray(sphere.faces), none, none))
    np.testing.assert_array_equal(positions, sphere.vertices)
    np.testing.assert_array_equal(faces, sphere.faces)


def test_a_subdivided_meshs_proxy_has_no_slivers_and_charts_at_the_asked_density():
    from sssbake.pipeline.mesh import proxy_atlas
    from sssbake.pipeline.mesh.simplify import simplify

    # midpoint subdivision leaves every quadric flat where the triangles were: the simplifier
    # stacks vertices there (as on the subdivided dragons: benchmarks/README.md#proxy-slivers)
    sphere = trimesh.creation.icosphere(3)
    bump = 1.0 + 0.05 * np.sin(7.0 * sphere.vertices[:, 0]) * np.cos(5.0 * sphere.vertices[:, 1])
    positions, faces = trimesh.remesh.subdivide(sphere.vertices * bump[:, None], sphere.faces)
    positions, faces = trimesh.remesh.subdivide(positions, faces)
    faces = np.asarray(faces, dtype=np.int64)

    def slivers(p: np.ndarray, f: np.ndarray) -> int:
        edges = np.unique(np.sort(f[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1), axis=0)
        length = np.linalg.norm(p[edges[:, 0]] - p[edges[:, 1]], axis=1)
        return int((length < 0.05 * np.median(length)).sum()
                   + (trimesh.triangles.angles(p[f]).min(axis=1) < np.radians(1.0)).sum())

    raw = simplify(positions, faces, target_count=400, snap=False)
    assert slivers(raw.positions, raw.faces) > 0  # else this test tests nothing
    proxy_positions, proxy_faces = proxy_atlas._proxy(positions, faces, 400)
    assert slivers(proxy_positions, proxy_faces) == 0
    assert len(proxy_faces) >= (1.0 - proxy_atlas.SLIVER_LOSS) * 400
    atlas = layout_atlas([(positions, faces, ())], 128, 2, proxy_faces=400, proxy_min_faces=1000)
    assert atlas.source == "proxy", atlas.notes
    # xatlas sizes the atlas by the proxy's triangles: with the slivers kept it grew to 784² for
    # 128 asked, without them 228²
    assert atlas.width <= 2 * 128
    part = atlas.parts[0]
    check = check_uvs([(part.uvs, part.faces, positions[part.vmapping])], atlas.width, atlas.height)
    assert check.ok and check.overlap == 0.0, check.reason
