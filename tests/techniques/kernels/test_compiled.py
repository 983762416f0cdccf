"""The kernels precompute's compiled loops against their numpy definitions."""

import numpy as np

from sssbake.pipeline.core.materials import preset
from sssbake.pipeline.core.profile import diffuse_reflectance_profile, profile_for
from sssbake.pipeline.core.profile_table import ProfileTable
from sssbake.pipeline.techniques.kernels.compiled import (grouped_products, local_transport, mix_global, near_table,
                                                            shared_hats)


def test_local_transport_is_the_table_times_the_source_area():
    rng = np.random.default_rng(5)
    for material in ("marble", "skin1"):
        params = profile_for(preset(material))
        table = ProfileTable.build(params, 12.0)
        # texel-like spacings from coincident to past the table's end
        near = np.sqrt(table.exact_below)
        x = np.r_[rng.uniform(-near, near, (200, 3)), rng.uniform(-6.0, 6.0, (200, 3)), np.zeros((1, 3)),
                  [[1e-9, 0.0, 0.0]], [[30.0, 0.0, 0.0]]]
        area = rng.uniform(0.01, 0.2, len(x))
        receiver, source = rng.integers(0, len(x), 20000), rng.integers(0, len(x), 20000)
        receiver[:3], source[:3] = len(x) - 3, [len(x) - 2, len(x) - 1, len(x) - 3]
        got = local_transport(table, near_table(table), x, area, receiver, source)
        d2 = np.einsum("ij,ij->i", x[receiver] - x[source], x[receiver] - x[source])
        expected = table(d2) * area[source, None]
        assert table.exact_below > 0 and 0.01 < (d2 < table.exact_below).mean() < 0.99  # both paths are tested
        np.testing.assert_allclose(got, expected, rtol=1e-8, atol=0)
        far = d2 >= table.exact_below
        # the table's own interpolation (d² summed in another order: float64 rounding)
        np.testing.assert_allclose(got[far], expected[far], rtol=1e-12)
        exact = diffuse_reflectance_profile(np.sqrt(d2[~far]), params) * area[source[~far], None]
        np.testing.assert_allclose(got[~far], exact, rtol=1e-8)


def test_shared_hats_and_grouped_products_equal_the_numpy_forms_bit_for_bit():
    rng = np.random.default_rng(6)
    corners = rng.integers(0, 12, (300, 3))
    bary = rng.dirichlet(np.ones(3), 300)
    receiver, source = rng.integers(0, 300, 5000), rng.integers(0, 300, 5000)
    expected = np.zeros((len(source), 3))
    for b in range(3):
        expected += (corners[source] == corners[receiver][:, b, None]) * bary[receiver][:, b, None]
    np.testing.assert_array_equal(shared_hats(corners, bary, receiver, source), expected)

    group = np.sort(rng.integers(0, 40, 5000))
    left, right, scale = rng.normal(size=(5000, 3)), rng.normal(size=(5000, 3)), rng.uniform(0, 1, 5000)
    sums = np.stack([np.bincount(group, weights=left[:, a] * right[:, b], minlength=41)
                     for a in range(3) for b in range(3)], axis=1).reshape(41, 3, 3)
    np.testing.assert_array_equal(grouped_products(group, left, right, 41), sums)
    scaled = np.stack([np.bincount(group, weights=left[:, a] * scale, minlength=41) for a in range(3)], axis=1)
    np.testing.assert_array_equal(grouped_products(group, left, np.ones((5000, 1)), 41, scale)[:, :, 0], scaled)


def test_mix_global_is_the_two_einsums():
    rng = np.random.default_rng(7)
    dual, bary = rng.normal(size=(50, 3)), rng.dirichlet(np.ones(3), 80)
    block = rng.normal(size=(30, 3, 3, 3))
    src, per_source = rng.integers(0, 50, 60), rng.integers(0, 30, 60)
    receiver, per_pair = rng.integers(0, 80, 400), rng.integers(0, 60, 400)
    mixed = np.einsum("va,vabc->vbc", dual[src], block[per_source])
    expected = np.einsum("pb,pbc->pc", bary[receiver], mixed[per_pair])
    np.testing.assert_allclose(mix_global(dual, src, block, per_source, bary, receiver, per_pair), expected,
                               rtol=1e-13, atol=1e-15)
