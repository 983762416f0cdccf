"""Image metrics on images with known answers."""

import numpy as np
import pytest
from PIL import Image

from sssbake.pipeline.render.image_metrics import (
    best_fit_scale,
    rmse,
    shared_exposure,
    write_comparison_png,
    write_difference_png,
)


def test_rmse_of_known_images():
    a = np.zeros((4, 6, 3))
    assert rmse(a, np.full_like(a, 0.5), 1.0) == pytest.approx(0.5)
    # values are clipped to [0, 1] after exposure: 0.75 · 2 counts as 1
    assert rmse(a, np.full_like(a, 0.75), 2.0) == pytest.approx(1.0)
    b = a.copy()
    mask = np.zeros((4, 6), bool)
    mask[:2] = True
    b[mask] = 0.2
    assert rmse(a, b, 1.0) == pytest.approx(np.sqrt(0.5 * 0.04))  # half the pixels differ by 0.2
    assert rmse(a, b, 1.0, mask) == pytest.approx(0.2)
    assert rmse(a, b, 1.0, ~mask) == 0.0
    assert rmse(a, b, 1.0, np.zeros_like(mask)) == 0.0


def test_best_fit_scale_recovers_a_known_scale():
    rng = np.random.default_rng(0)
    image = rng.uniform(0.1, 1.0, (8, 8, 3))
    image[..., 2] = 0.0  # a black channel has no scale
    mask = rng.uniform(size=(8, 8)) > 0.3
    reference = image * np.array([2.0, 0.5, 3.0])
    reference[~mask] = 7.0  # outside the mask nothing counts
    np.testing.assert_allclose(best_fit_scale(image, reference, mask), [2.0, 0.5, 0.0], rtol=1e-12)


def test_exposure_maps_the_percentile_to_one():
    reference = np.zeros((10, 10, 3))
    reference[..., 1] = np.arange(1.0, 101.0).reshape(10, 10)  # the brightest channel
    mask = np.ones((10, 10), bool)
    assert shared_exposure(reference, mask, 50.0) == pytest.approx(1.0 / 50.5)
    assert shared_exposure(reference, mask, 100.0) == pytest.approx(1.0 / 100.0)
    mask[5:] = False  # values 1..50 only
    assert shared_exposure(reference, mask, 100.0) == pytest.approx(1.0 / 50.0)
    assert shared_exposure(np.zeros((2, 2, 3)), np.ones((2, 2), bool)) == 1.0


def test_pngs_are_written_whole(tmp_path):
    a = np.full((5, 4, 3), 0.5)
    b = a.copy()
    b[0, 0] = 0.0
    write_comparison_png(tmp_path / "c.png", [a, b, a], exposure=2.0)
    write_difference_png(tmp_path / "d.png", a, b, exposure=1.0)
    c = np.asarray(Image.open(tmp_path / "c.png"))
    assert c.shape == (5, 12, 3) and np.all(c[1, 1] == 255) and np.all(c[0, 4] == 0)
    d = np.asarray(Image.open(tmp_path / "d.png"))
    assert d.shape == (5, 4, 3) and d[0, 0].sum() > 3 * 200 and d[1, 1].sum() < 30
    assert sorted(p.name for p in tmp_path.iterdir()) == ["c.png", "d.png"]


def test_mismatched_images_are_refused():
    with pytest.raises(ValueError, match="differ in shape"):
        rmse(np.zeros((2, 2, 3)), np.zeros((2, 3, 3)), 1.0)
    with pytest.raises(ValueError, match="mask must be"):
        best_fit_scale(np.zeros((2, 2, 3)), np.zeros((2, 2, 3)), np.ones((3, 2), bool))
    with pytest.raises(ValueError, match="finite"):
        shared_exposure(np.full((2, 2, 3), np.nan), np.ones((2, 2), bool))
