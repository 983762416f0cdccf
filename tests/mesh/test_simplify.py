import numpy as np
import pytest
import trimesh

from sssbake.pipeline.mesh.simplify import SimplifyError, simplify


@pytest.fixture(scope="module")
def sphere():
    mesh = trimesh.creation.icosphere(4, radius=2.0)
    return np.asarray(mesh.vertices), np.asarray(mesh.faces, dtype=np.int64)


def test_counts_shapes_and_ranges(sphere):
    positions, faces = sphere
    result = simplify(positions, faces, 0.1)
    k = len(result.positions)
    assert result.positions.shape == (k, 3) and result.positions.dtype == np.float64
    assert result.faces.dtype == np.int64 and result.faces.shape[1] == 3
    assert 0.9 * 512 <= len(result.faces) <= 512
    assert result.faces.min() >= 0 and result.faces.max() == k - 1
    assert result.collapse_map.shape == (len(positions),) and result.collapse_map.dtype == np.int64
    assert result.collapse_map.min() == 0 and result.collapse_map.max() == k - 1
    assert result.kept.shape == (k,) and len(np.unique(result.kept)) == k


def test_kept_vertices_map_to_themselves_and_keep_their_positions(sphere):
    positions, faces = sphere
    result = simplify(positions, faces, 0.1)
    np.testing.assert_array_equal(result.collapse_map[result.kept], np.arange(len(result.kept)))
    np.testing.assert_array_equal(result.positions, positions[result.kept])


def test_vertices_collapse_into_a_nearby_kept_vertex(sphere):
    positions, faces = sphere
    result = simplify(positions, faces, 0.1)
    edges = result.positions[result.faces] - np.roll(result.positions[result.faces], 1, axis=1)
    mean_edge = np.linalg.norm(edges, axis=2).mean()
    travelled = np.linalg.norm(positions - result.positions[result.collapse_map], axis=1)
    assert travelled.max() < 2.0 * mean_edge


def test_sphere_keeps_its_radius(sphere):
    positions, faces = sphere
    snapped = simplify(positions, faces, 0.1)
    np.testing.assert_allclose(np.linalg.norm(snapped.positions, axis=1), 2.0, rtol=1e-12)
    moved = simplify(positions, faces, 0.1, snap=False)
    np.testing.assert_array_equal(moved.faces, snapped.faces)
    np.testing.assert_allclose(np.linalg.norm(moved.positions, axis=1), 2.0, rtol=0.02)
    volume = trimesh.Trimesh(moved.positions, moved.faces, process=False).volume
    assert volume == pytest.approx(4.0 / 3.0 * np.pi * 8.0, rel=0.03)


def test_target_count_and_no_op(sphere):
    positions, faces = sphere
    assert len(simplify(positions, faces, target_count=1000).faces) <= 1000
    whole = simplify(positions, faces, 1.0)
    assert len(whole.faces) == len(faces)
    np.testing.assert_array_equal(whole.collapse_map[whole.kept], np.arange(len(whole.kept)))


def test_unreferenced_vertex_maps_to_minus_one(sphere):
    positions, faces = sphere
    result = simplify(np.vstack([positions, [[9.0, 9.0, 9.0]]]), faces, 0.2)
    assert result.collapse_map[-1] == -1
    assert (result.collapse_map[:-1] >= 0).all()


@pytest.mark.parametrize(
    "kwargs, match",
    [({"target_fraction": 0.0}, "target_fraction"), ({"target_count": 0}, "target_count")],
)
def test_bad_targets_raise(sphere, kwargs, match):
    positions, faces = sphere
    with pytest.raises(SimplifyError, match=match):
        simplify(positions, faces, **kwargs)


def test_bad_mesh_raises(sphere):
    positions, faces = sphere
    with pytest.raises(ValueError, match="simplify: positions contain NaN"):
        simplify(np.where(np.arange(len(positions))[:, None] == 3, np.nan, positions), faces)
    with pytest.raises(ValueError, match="face indices"):
        simplify(positions, faces + len(positions))
