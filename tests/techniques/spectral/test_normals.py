import numpy as np
import pytest
import trimesh
from scipy.integrate import quad

from sssbake.pipeline.techniques.spectral.laplacian import cotangent_laplacian
from sssbake.pipeline.techniques.spectral.manifold_harmonics import manifold_harmonics
from sssbake.pipeline.techniques.spectral.normals import band_mean, low_pass, normal_spectrum
from sssbake.pipeline.techniques.spectral.precompute import nyquist_frequency


def _spectrum(mesh, count, normals=None):
    x, f = np.asarray(mesh.vertices, float), np.asarray(mesh.faces, np.int64)
    lap = cotangent_laplacian(x, f)
    h = manifold_harmonics(lap, count)
    n = np.asarray(mesh.vertex_normals, float) if normals is None else normals
    return normal_spectrum(h.vectors, h.values, nyquist_frequency(x, f), lap.mass, n), lap


def test_unfiltered_reconstruction_with_the_residual_returns_the_normals():
    box = trimesh.creation.box(extents=(2.0, 1.0, 0.5)).subdivide().subdivide()
    spectrum, _ = _spectrum(box, 30)
    out, gamma = spectrum.filtered(0.0)
    assert gamma == 1.0
    assert np.abs(out - spectrum.normals).max() < 1e-12
    assert np.abs(spectrum.residual).max() > 0.05  # the 30 harmonics alone do not hold a box's normals


def test_a_constant_field_passes_any_filter_unchanged():
    sphere = trimesh.creation.icosphere(subdivisions=2)
    constant = np.tile([0.6, 0.0, 0.8], (len(sphere.vertices), 1))
    spectrum, _ = _spectrum(sphere, 12, constant)
    assert np.abs(spectrum.residual).max() < 1e-12  # in the span of φ_0
    for width in (0.1, 1.0, 10.0):
        assert np.abs(spectrum.filtered(width)[0] - constant).max() < 1e-12


def test_a_spheres_normals_are_an_l1_harmonic_and_keep_their_direction():
    # n = x / R lies in the l = 1 eigenspace: filtering only scales it, and normalising undoes that
    sphere = trimesh.creation.icosphere(subdivisions=3, radius=3.0)
    radial = np.asarray(sphere.vertices) / 3.0
    spectrum, lap = _spectrum(sphere, 9, radial / np.linalg.norm(radial, axis=1, keepdims=True))
    weight = np.abs(spectrum.coefficients).sum(axis=1)
    assert np.all(weight[1:4] > 100 * max(weight[0], weight[4:].max()))
    out, _ = spectrum.filtered(2.0)
    assert np.einsum("ij,ij->i", out, spectrum.normals).min() > 0.999


def test_filter_and_its_band_mean():
    assert np.allclose(low_pass(np.array([0.0, 2.0, 8.0]), 0.5), np.exp(-0.5 * np.array([0.0, 2.0, 8.0]) * 0.25))
    lo, hi, s = 0.7, 5.0, 0.8
    numeric = quad(lambda w: np.exp(-0.5 * (w * s) ** 2), lo, hi)[0] / (hi - lo)
    assert band_mean(lo, hi, s) == pytest.approx(numeric, rel=1e-10)
    assert band_mean(2.0, 2.0, s) == pytest.approx(np.exp(-0.5 * (2.0 * s) ** 2))
    assert band_mean(lo, hi, 0.0) == 1.0
