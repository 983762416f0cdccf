import numpy as np
import pytest
import scipy.linalg
import trimesh

import sssbake.pipeline.techniques.spectral.manifold_harmonics as mh
from sssbake.pipeline.techniques.spectral.laplacian import cotangent_laplacian


def _sphere(radius=2.0, subdivisions=3):
    s = trimesh.creation.icosphere(subdivisions=subdivisions, radius=radius)
    return np.asarray(s.vertices, float), np.asarray(s.faces, np.int64)


def test_sphere_spectrum_has_the_analytic_multiplicities():
    x, f = _sphere()
    lap = cotangent_laplacian(x, f)
    h = mh.manifold_harmonics(lap, 16)
    # l(l + 1) / R², multiplicities 1, 3, 5, 7
    expected = np.repeat([0.0, 2.0, 6.0, 12.0], [1, 3, 5, 7]) / 4.0
    assert np.allclose(h.values, expected, rtol=0.02, atol=1e-9)
    gram = h.vectors.T @ (lap.mass[:, None] * h.vectors)
    assert np.abs(gram - np.eye(16)).max() < 1e-10  # M-orthonormal


@pytest.mark.parametrize("band", [6, 11])
def test_bands_agree_with_the_dense_solution(monkeypatch, band):
    # Small bands force joins inside the sphere's near-multiplets (the jitter splits each of its
    # 5, 7, 9 equal eigenvalues by ~1e-3: exact repeats can lose members in any Lanczos solve).
    monkeypatch.setattr(mh, "DENSE", 10)
    monkeypatch.setattr(mh, "BAND", band)
    x, f = _sphere(subdivisions=2)
    x = x * (1.0 + 1e-3 * np.random.default_rng(band).normal(size=(len(x), 1)))
    lap = cotangent_laplacian(x, f)
    h = mh.manifold_harmonics(lap, 40)
    assert h.bands > 2
    scale = 1.0 / np.sqrt(lap.mass)
    dense = scipy.linalg.eigvalsh(scale[:, None] * lap.stiffness.toarray() * scale[None, :])
    assert np.allclose(h.values, np.maximum(dense[:40], 0.0), atol=1e-9)
    gram = h.vectors.T @ (lap.mass[:, None] * h.vectors)
    assert np.abs(gram - np.eye(40)).max() < 1e-8  # no pair twice, none missing


def test_two_components_give_two_zero_eigenvalues():
    x, f = _sphere(subdivisions=1)
    lap = cotangent_laplacian(np.r_[x, x + 10.0], np.r_[f, f + len(x)])
    h = mh.manifold_harmonics(lap, 4)
    assert np.allclose(h.values[:2], 0.0, atol=1e-10) and h.values[2] > 0.1


def test_count_must_be_positive():
    x, f = _sphere(subdivisions=1)
    with pytest.raises(ValueError, match="at least one eigenpair"):
        mh.manifold_harmonics(cotangent_laplacian(x, f), 0)


def test_banded_solve_is_a_function_of_its_input(monkeypatch):
    # ARPACK's own start vectors are unseeded: without `START_SEED` two solves differ in the last
    # bits of the eigenvalues and in the signs of the eigenvectors.
    monkeypatch.setattr(mh, "DENSE", 10)
    x, f = _sphere(subdivisions=2)
    x = x * (1.0 + 1e-3 * np.random.default_rng(7).normal(size=(len(x), 1)))
    lap = cotangent_laplacian(x, f)
    a, b = mh.manifold_harmonics(lap, 40), mh.manifold_harmonics(lap, 40)
    assert a.bands > 1
    assert np.array_equal(a.values, b.values) and np.array_equal(a.vectors, b.vectors)
