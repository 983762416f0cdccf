import numpy as np
from fixtures import plane

from sssbake.pipeline.core.naive_normals import naive_normals, unit_or_original


def test_matches_the_sum_of_eq_3_brute_force():
    rng = np.random.default_rng(3)
    x = rng.uniform(-2.0, 2.0, (60, 3))
    n = rng.normal(size=(60, 3))
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    sigma, alpha, radius = 0.7, 0.4, 1.5
    out = naive_normals(x, n, sigma, alpha, radius)
    d = np.linalg.norm(x[:, None] - x[None], axis=2)
    w = np.where((d <= radius) & (d > 0), np.exp(-sigma * d), 0.0)
    expected = alpha * n + w @ n
    expected /= np.linalg.norm(expected, axis=1, keepdims=True)
    assert np.abs(out - expected).max() < 1e-12


def test_a_plane_keeps_its_normal_and_cancelling_sums_fall_back():
    x, _, _ = plane(1.0, 3)
    up = np.tile([0.0, 0.0, 1.0], (len(x), 1))
    assert np.abs(naive_normals(x, up, 0.0, 0.5, 2.5) - up).max() < 1e-12  # σ_tr = 0 too
    # two sides of a zero-thickness sheet: the sum cancels, each keeps its own normal
    pts, nrm = np.zeros((2, 3)), np.array([[0.0, 0.0, 1.0], [0.0, 0.0, -1.0]])
    assert np.array_equal(naive_normals(pts, nrm, 0.5, 1.0, 1.0), nrm)
    assert np.array_equal(unit_or_original(np.array([[np.nan, 0.0, 0.0]]), nrm[:1]), nrm[:1])
