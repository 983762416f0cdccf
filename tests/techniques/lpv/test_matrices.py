"""SSLPV propagation matrices: the paper's printed values, its permutation rule, the face integrator
against closed-form solid angles and whole-sphere integrals, and flux conservation."""

import numpy as np
import pytest

from sssbake.pipeline.core.sh import sh_basis
from sssbake.pipeline.techniques.lpv.matrices import (
    DIRECTIONS,
    cube_faces,
    face_projection,
    lpv_basis,
    propagation_matrices,
)

SQRT_4PI = np.sqrt(4.0 * np.pi)

# Børlum et al. 2011, matrix for s = d ± x (upper sign s = d + x); None where 0 is printed.
PRINTED_UPPER = np.array([[0.167, 0.0, 0.0, -0.240],
                          [0.0, 0.070, 0.0, 0.0],
                          [0.0, 0.0, 0.070, 0.0],
                          [-0.037, 0.0, 0.0, 0.062]])


def _k(direction):
    return int(np.flatnonzero((DIRECTIONS == direction).all(axis=1))[0])


def _triangle_solid_angle(a, b, c):
    """Van Oosterom & Strackee 1983: solid angle of the triangle with vertices a, b, c (from 0)."""
    la, lb, lc = (np.linalg.norm(v) for v in (a, b, c))
    numerator = abs(np.dot(a, np.cross(b, c)))
    denominator = la * lb * lc + np.dot(a, b) * lc + np.dot(a, c) * lb + np.dot(b, c) * la
    return 2.0 * np.arctan2(numerator, denominator)


def _rectangle_solid_angle(point, centre, edges):
    e0, e1 = edges
    p = [centre + s * e0 + t * e1 - point for s, t in ((-1, -1), (1, -1), (1, 1), (-1, 1))]
    return _triangle_solid_angle(p[0], p[1], p[2]) + _triangle_solid_angle(p[0], p[2], p[3])


def test_x_matrices_match_the_paper():
    m = propagation_matrices()
    # DIRECTIONS[k] is the offset source -> destination, so s = d + x is direction -x.
    for direction, sign in (((-1, 0, 0), 1.0), ((1, 0, 0), -1.0)):
        printed = PRINTED_UPPER.copy()
        printed[0, 3] *= sign
        printed[3, 0] *= sign
        derived = m[_k(direction)]
        zero = printed == 0.0
        np.testing.assert_allclose(derived[zero], 0.0, atol=1e-12)
        assert np.all(np.abs(derived - printed)[~zero] <= 0.0005), (direction, derived)


def test_x_matrices_derived_values():
    # Independent closed forms: M00 = (5 faces' solid angle)/(4π) = (2π/3)/(4π) = 1/6, and
    # M30 = -(1/π)(2π/3)√(3/(4π)) · Δω_back/√(4π) with Δω_back = 4 arctan(1/(6√(11/4)))
    # (unit square at distance 1.5).
    m = propagation_matrices()[_k((-1, 0, 0))]
    back = 4.0 * np.arctan(0.25 / (1.5 * np.sqrt(0.5 + 2.25)))
    assert m[0, 0] == pytest.approx(1.0 / 6.0, abs=1e-13)
    assert m[3, 0] == pytest.approx(-(2.0 / 3.0) * np.sqrt(3.0) * back / (4.0 * np.pi), abs=1e-13)


def test_quadrature_is_converged():
    np.testing.assert_allclose(propagation_matrices(32), propagation_matrices(64), rtol=0, atol=1e-12)
    # a crude rule is visibly off: the comparison above can see an unconverged integral
    assert np.abs(propagation_matrices(2) - propagation_matrices(64)).max() > 1e-5


def test_y_and_z_matrices_are_the_x_ones_permuted():
    m = propagation_matrices()
    for sign in (1, -1):
        mx = m[_k((sign, 0, 0))]
        for axis, slot in ((1, 1), (2, 2)):  # y: c11 <-> c1-1; z: c11 <-> c10
            perm = [0, 1, 2, 3]
            perm[3], perm[slot] = perm[slot], perm[3]
            direction = [0, 0, 0]
            direction[axis] = sign
            np.testing.assert_allclose(m[_k(direction)], mx[np.ix_(perm, perm)], rtol=0, atol=1e-13)


def test_face_solid_angles_match_the_closed_form():
    centres, _, edges = cube_faces()
    for direction in DIRECTIONS:
        source = -direction.astype(float)
        total = 0.0
        for f in range(6):
            if np.array_equal(DIRECTIONS[f], -direction):
                continue
            numeric = face_projection(source, centres[f], edges[f])[0] * SQRT_4PI
            closed = _rectangle_solid_angle(source, centres[f], edges[f])
            assert numeric == pytest.approx(closed, abs=1e-10)
            total += numeric
        shared = _k(-direction)
        # the five faces are seen through the shared face: together they cover its solid angle
        assert total == pytest.approx(_rectangle_solid_angle(source, centres[shared], edges[shared]), abs=1e-10)
        assert total == pytest.approx(2.0 * np.pi / 3.0, abs=1e-10)


@pytest.mark.parametrize("point", [(0.0, 0.0, 0.0), (0.31, -0.12, 0.27)])
def test_basis_integrates_over_the_sphere_from_inside_a_cube(point):
    # off centre the nearest face is 0.23 away, closer than in the matrices (0.5): more points
    centres, _, edges = cube_faces()
    total = sum(face_projection(np.array(point), centres[f], edges[f], quadrature=64) for f in range(6))
    np.testing.assert_allclose(total, [SQRT_4PI, 0.0, 0.0, 0.0], rtol=0, atol=1e-12)


def test_flux_is_conserved():
    # ∫ Σ c_lm y_lm dω = c00 √(4π). The five faces' tiles of each neighbour cover the sphere once and
    # each re-emitted lobe Φ/π max(0, n·ω) carries exactly Φ, so no flux is lost: the ratio is 1, not
    # below 1 (the scheme's loss is in direction, not in total flux).
    m = propagation_matrices()
    rng = np.random.default_rng(1)
    for c in (np.array([SQRT_4PI, 0.0, 0.0, 0.0]), np.array([SQRT_4PI, *rng.normal(size=3)])):
        moved = SQRT_4PI * (m @ c)[:, 0].sum()
        ratio = moved / (c[0] * SQRT_4PI)
        assert ratio == pytest.approx(1.0, abs=1e-12), f"flux ratio {ratio!r}"
    # the x neighbours carry the +-x lobe, the others none of it
    out = m @ np.array([SQRT_4PI, 0.0, 0.0, 0.0])
    assert out[_k((1, 0, 0)), 3] > 0 > out[_k((-1, 0, 0)), 3]
    np.testing.assert_allclose(out[_k((1, 0, 0)), 1:3], 0.0, atol=1e-12)


def test_matrices_are_cached_and_read_only():
    m = propagation_matrices()
    assert m.shape == (6, 4, 4) and m.dtype == np.float64
    assert propagation_matrices() is m
    with pytest.raises(ValueError):
        m[0, 0, 0] = 1.0


def test_basis_is_the_condon_shortley_one_with_band1_odd_m_flipped():
    w = np.random.default_rng(0).normal(size=(50, 3))
    w /= np.linalg.norm(w, axis=1, keepdims=True)
    np.testing.assert_allclose(lpv_basis(w), sh_basis(w, 2) * [1.0, -1.0, 1.0, -1.0], atol=1e-14)
    np.testing.assert_allclose(lpv_basis(np.array([[1.0, 0.0, 0.0]])), [[0.5 / np.sqrt(np.pi), 0, 0, np.sqrt(3 / (4 * np.pi))]])


@pytest.mark.parametrize("bad", [np.zeros(3), np.zeros((4, 2)), np.zeros((2, 3, 1)), np.array([[np.nan, 0.0, 1.0]]),
                                 np.array([[np.inf, 0.0, 0.0]])])
def test_bad_basis_input_raises(bad):
    with pytest.raises(ValueError, match="lpv_basis"):
        lpv_basis(bad)


def test_point_on_the_face_plane_raises():
    centres, _, edges = cube_faces()
    with pytest.raises(ValueError, match="plane"):
        face_projection(np.array([2.0, 0.0, 0.5]), centres[4], edges[4])
