"""The random walk behind the Monte Carlo profile, against Chandrasekhar's exact albedo of an
isotropically scattering half-space with a matched boundary (η = 1): a beam at normal incidence is
reflected in all with r = 1 - H(1) sqrt(1 - α), H the H-function of
H(μ) = 1 + (α/2) μ H(μ) ∫_0^1 H(μ') / (μ + μ') dμ' (Radiative Transfer, 1950, §26, §47)."""

import numpy as np
import pytest

import sssbake.pipeline.core.random_walk as rw
from sssbake.pipeline.core.random_walk import exit_weights, random_walk, walk_total


def chandrasekhar_h(alpha: float, mu: float, nodes: int = 128) -> float:
    x, w = np.polynomial.legendre.leggauss(nodes)
    m, w = 0.5 * (x + 1.0), 0.5 * w
    h = np.ones(nodes)
    for _ in range(2000):  # the iteration H ← 1 / (1 - (α/2) μ ∫ H/(μ+μ')) converges for α <= 1
        new = 1.0 / (1.0 - 0.5 * alpha * m * np.sum(w * h / (m[:, None] + m[None, :]), axis=1))
        if np.max(np.abs(new - h)) < 1e-14:
            break
        h = new
    return float(1.0 / (1.0 - 0.5 * alpha * mu * np.sum(w * h / (mu + m))))


@pytest.fixture(scope="module")
def matched():
    # σ'_s = 1, absorption 0.01 as the walk's own; any a >= 0.01 reweights its exits
    return random_walk(1.0, 200_000, 0.01, 1e6, 3)


@pytest.mark.parametrize("alpha", [0.3, 0.8, 0.95, 0.99])
def test_matched_half_space_reflects_chandrasekhars_albedo(matched, alpha):
    a = (1.0 - alpha) / alpha  # σ_a / σ_s for single-scattering albedo α
    total, error = walk_total(matched, a)
    want = 1.0 - chandrasekhar_h(alpha, 1.0) * np.sqrt(1.0 - alpha)
    assert abs(total - want) < 4.0 * error + 1e-4, (alpha, total, want, error)


def test_without_absorption_every_photon_comes_back_and_the_boundary_is_lambertian():
    exits = random_walk(1.0, 50_000, 0.0, 1e5, 9)
    # a 1-D random walk in depth returns: all but the few still walking at the cut
    assert len(exits.radius) / exits.photons > 0.99
    # deep in a matched half-space the light leaving is diffuse: cos θ distributed as 2 cos θ
    # (Milne's problem leaves it slightly peaked: H(μ) grows with μ; still within a few %)
    counts, _ = np.histogram(exits.cos_out, bins=5, range=(0.0, 1.0))
    lambert = np.diff(np.linspace(0.0, 1.0, 6) ** 2) * len(exits.cos_out)
    assert np.all(np.abs(counts / lambert - 1.0) < 0.2)


def test_the_walk_is_the_same_whatever_its_chunks(monkeypatch):
    whole = random_walk(1.3, 5000, 0.1, 1e6, 11)
    monkeypatch.setattr(rw, "CHUNK", 777)
    chunked = random_walk(1.3, 5000, 0.1, 1e6, 11)
    np.testing.assert_array_equal(whole.radius, chunked.radius)
    np.testing.assert_array_equal(whole.length, chunked.length)
    other = random_walk(1.3, 5000, 0.1, 1e6, 12)
    assert not np.array_equal(whole.radius[:100], other.radius[:100])


def test_reweighting_needs_at_least_the_walks_absorption():
    exits = random_walk(1.0, 100, 0.1, 1e6, 1)
    with pytest.raises(ValueError, match="cannot describe less"):
        exit_weights(exits, 0.05)
    with pytest.raises(ValueError, match="random walk"):
        random_walk(0.9, 10)
