"""Direction sets: even spread, a closed hull triangulation, exact and runtime-style interpolation."""

import numpy as np
import pytest

from sssbake.pipeline.core.directions import (
    LOOKUP_SIZE,
    direction_set,
    fibonacci_sphere,
    interpolation_weights,
    lookup_weights,
    octahedral_decode,
    octahedral_texel,
)


def random_directions(m: int, seed: int = 0) -> np.ndarray:
    w = np.random.default_rng(seed).normal(size=(m, 3))
    return w / np.linalg.norm(w, axis=1, keepdims=True)


@pytest.mark.parametrize("k", [4, 7, 200, 513])
def test_hull_is_a_closed_outward_triangulation(k):
    ds = direction_set(k, lookup_size=16)
    np.testing.assert_allclose(np.linalg.norm(ds.directions, axis=1), 1.0)
    assert ds.triangles.shape == (2 * k - 4, 3)  # Euler: V - E + F = 2 with E = 3F/2
    edges = np.sort(np.concatenate([ds.triangles[:, [0, 1]], ds.triangles[:, [1, 2]], ds.triangles[:, [2, 0]]]), axis=1)
    _, counts = np.unique(edges, axis=0, return_counts=True)
    assert np.all(counts == 2)
    a, b, c = (ds.directions[ds.triangles[:, i]] for i in range(3))
    assert np.all(np.einsum("ij,ij->i", np.cross(b - a, c - a), a) > 0)
    # neighbours share the edge opposite each corner
    for t in range(0, len(ds.triangles), max(1, len(ds.triangles) // 20)):
        for corner in range(3):
            edge = set(ds.triangles[t]) - {ds.triangles[t, corner]}
            assert edge <= set(ds.triangles[ds.neighbours[t, corner]])


def test_fibonacci_points_are_evenly_spread():
    d = fibonacci_sphere(2000)
    np.testing.assert_allclose(d.mean(axis=0), 0.0, atol=2e-3)
    # each equal-area band holds its share of points
    counts, _ = np.histogram(d[:, 2], bins=10, range=(-1, 1))
    assert counts.min() >= 199 and counts.max() <= 201


def test_interpolation_is_exact_at_the_set_and_convex():
    ds = direction_set(50)
    index, weights = interpolation_weights(ds, ds.directions)
    picked = index[np.arange(50), weights.argmax(axis=1)]
    np.testing.assert_array_equal(picked, np.arange(50))
    np.testing.assert_allclose(weights.max(axis=1), 1.0, atol=1e-12)
    index, weights = interpolation_weights(ds, random_directions(1000) * 3.0)
    assert np.all(weights >= 0) and np.allclose(weights.sum(axis=1), 1.0)


def test_interpolation_reproduces_the_containing_cone_exactly():
    ds = direction_set(100, lookup_size=8)
    w = random_directions(3000, seed=3)
    index, weights = interpolation_weights(ds, w)
    # the weights are the barycentrics of the ray through w on the flat hull triangle
    hit = np.einsum("mk,mkj->mj", weights, ds.directions[index])
    np.testing.assert_allclose(np.cross(hit, w), 0.0, atol=1e-12)
    assert np.all(np.einsum("ij,ij->i", hit, w) > 0)


def test_interpolation_error_falls_as_k_grows():
    w = random_directions(2000)
    f = lambda d: np.exp(2.0 * d @ np.array([0.3, 0.5, 0.8]))  # noqa: E731
    errors = []
    for k in (20, 80, 320, 1280):
        ds = direction_set(k, lookup_size=16)
        index, weights = interpolation_weights(ds, w)
        errors.append(np.sqrt(np.mean(((f(ds.directions)[index] * weights).sum(axis=1) - f(w)) ** 2)))
    assert all(b < 0.5 * a for a, b in zip(errors, errors[1:])), errors  # second order: ~1/K


def test_lookup_texels_hold_the_triangle_containing_their_centre():
    ds = direction_set(200)
    size = ds.lookup.shape[0]
    assert size == LOOKUP_SIZE == 32
    uv = (np.stack(np.meshgrid(np.arange(size), np.arange(size)), -1).reshape(-1, 2) + 0.5) / size
    centres = octahedral_decode(uv)
    beta = np.einsum("mij,mj->mi", ds.inverse[ds.lookup.ravel()], centres)  # row-major: lookup[v, u]
    assert beta.min() >= -1e-12


@pytest.mark.parametrize("k, size", [(200, LOOKUP_SIZE), (200, 16), (1000, 32), (64, 8)])
def test_lookup_walk_matches_the_exact_triangle(k, size):
    ds = direction_set(k, lookup_size=size)
    w = random_directions(20000 if k <= 200 else 4000, seed=k)
    i1, b1 = interpolation_weights(ds, w)
    i2, b2 = lookup_weights(ds, w)
    values = np.random.default_rng(1).random(k)
    np.testing.assert_allclose((values[i1] * b1).sum(axis=1), (values[i2] * b2).sum(axis=1), atol=1e-12)


def test_octahedral_map_round_trips_texel_centres():
    size = 32
    uv = (np.stack(np.meshgrid(np.arange(size), np.arange(size)), -1).reshape(-1, 2) + 0.5) / size
    texel = octahedral_texel(octahedral_decode(uv), size)
    np.testing.assert_array_equal(texel, np.floor(uv * size).astype(np.int64))


def test_bad_input_is_refused():
    with pytest.raises(ValueError, match="at least 4"):
        direction_set(3)
    with pytest.raises(ValueError, match="non-zero"):
        interpolation_weights(direction_set(8), np.zeros((1, 3)))
