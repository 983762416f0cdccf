import numpy as np
import pytest
import scipy.sparse as sp
import trimesh

import sssbake.pipeline.techniques.spectral.shifted_factor as shifted_factor
from sssbake.pipeline.techniques.spectral.laplacian import cotangent_laplacian
from sssbake.pipeline.techniques.spectral.shifted_factor import ShiftedFactor


def _sphere_operator():
    s = trimesh.creation.icosphere(subdivisions=3, radius=1.0)
    lap = cotangent_laplacian(np.asarray(s.vertices, float), np.asarray(s.faces))
    scale = 1.0 / np.sqrt(lap.mass)
    a = sp.diags(scale) @ lap.stiffness @ sp.diags(scale)
    return (0.5 * (a + a.T)).tocsc()


@pytest.mark.parametrize("metis", [True, False])
@pytest.mark.parametrize("shift", [-1e-3, 3.0, 13.7, 40.0])
def test_solves_match_a_dense_solve_below_and_inside_the_spectrum(monkeypatch, shift, metis):
    # -1e-3: positive definite; the others sit between the sphere's eigenvalues l(l+1), where
    # A - σI is indefinite and LDLᵀ without pivoting must still be exact. The subdivided sphere's
    # vertices nearly all have six neighbours (METIS's ordering is offered); with REGULAR at 1 only
    # AMD's is.
    if not metis:
        monkeypatch.setattr(shifted_factor, "REGULAR", 1.0)
    a = _sphere_operator()
    b = np.random.default_rng(1).standard_normal(a.shape[0])
    shifted = a.toarray() - shift * np.eye(a.shape[0])
    factor = ShiftedFactor(a)
    assert (factor._order is not None) == metis
    x = factor.solver(shift)(b)
    assert np.allclose(x, np.linalg.solve(shifted, b), rtol=1e-9, atol=1e-9 * np.abs(x).max())


def test_one_analysis_serves_successive_shifts():
    a = _sphere_operator()
    factor, b = ShiftedFactor(a), np.ones(a.shape[0])
    for shift in (-1e-3, 5.0, 21.0, -1e-3):
        x = factor.solver(shift)(b)
        assert np.linalg.norm(a @ x - shift * x - b) < 1e-9 * np.linalg.norm(b)


@pytest.mark.parametrize("tiny", [0.0, 1e-20])
def test_a_vanishing_pivot_falls_back_to_a_pivoted_factor(tiny):
    # [[tiny, 1], [1, 0]] blocks: LDLᵀ without pivoting meets a pivot of 0 or 1e-20 (growth 1e20)
    # in either order; the matrix itself is well conditioned (eigenvalues about ±1)
    a = sp.block_diag([np.array([[tiny, 1.0], [1.0, 0.0]])] * 50, format="csc")
    b = np.arange(100.0)
    x = ShiftedFactor(a).solver(0.0)(b)
    assert np.allclose(x, np.linalg.solve(a.toarray(), b))
