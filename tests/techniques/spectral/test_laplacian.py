import numpy as np
import scipy.linalg
from fixtures import plane

from sssbake.pipeline.techniques.spectral.laplacian import cotangent_laplacian


def test_regular_grid_reproduces_the_plane_laplacian():
    # on a regular right-triangle grid the cotangent stencil is the 5-point one: exact for quadratics
    x, f, centre = plane(0.5, 4)
    lap = cotangent_laplacian(x, f)
    w = lap.stiffness
    assert abs(w - w.T).max() < 1e-12
    assert np.abs(np.asarray(w.sum(axis=1))).max() < 1e-12  # constants are in the kernel
    interior = (np.abs(x[:, 0]) < 1.9) & (np.abs(x[:, 1]) < 1.9)
    assert np.abs((w @ (3.0 * x[:, 0] - x[:, 1]))[interior]).max() < 1e-12  # linear: harmonic
    # W f = -M Δf with Δ(x² + y²) = 4
    assert np.allclose((w @ (x[:, 0] ** 2 + x[:, 1] ** 2))[interior] / lap.mass[interior], -4.0)
    assert np.isclose(lap.mass.sum(), 16.0)  # the square's area
    assert np.isclose(lap.mass[centre], 0.25)  # a third of six triangles of 1/8


def test_slivers_stay_finite_and_positive_semi_definite():
    x = np.array([[0, 0, 0], [1, 0, 0], [0.5, 1e-9, 0], [0.5, -1, 0], [2, 2, 0], [2, 2, 0], [2, 2, 0], [5, 5, 5]], float)
    f = np.array([[0, 1, 2], [0, 3, 1], [4, 5, 6]])  # a sliver, a good triangle, a point-triangle; 7 isolated
    lap = cotangent_laplacian(x, f)
    dense = lap.stiffness.toarray()
    assert np.all(np.isfinite(dense)) and lap.slivers == 1
    assert np.abs(dense).max() <= 2 * 2500.0  # cotangents bounded by 1 / (4 SLIVER)
    assert scipy.linalg.eigvalsh(dense).min() > -1e-9 * np.abs(dense).max()
    assert np.all(dense[4:, :] == 0.0) and np.all(lap.mass > 0)  # the point-triangle and the isolated vertex
    assert lap.mass[7] < 1e-6 * lap.mass[:4].mean()
