"""The report's reference: the clustered sum at every vertex, checked against the exact pair sum at
sampled vertices; the check's figures in the image's units with a bootstrap interval."""

from dataclasses import replace

import numpy as np
import trimesh
from fixtures import plane

from sssbake.pipeline.core.materials import preset
from sssbake.pipeline.core.reference import Light, reference_scattering
from sssbake.pipeline.core.surface import Surface, area_weighted_normals, vertex_areas
from sssbake.pipeline.verify.checked_reference import CHECK_MIN, ReferenceCheck, check_figures, checked_reference

LIGHT = Light("directional", (0.4, 0.8, 0.45))


def surface_of(mesh: trimesh.Trimesh) -> Surface:
    x, f = np.asarray(mesh.vertices, dtype=np.float64), np.asarray(mesh.faces)
    return Surface(x, f, area_weighted_normals(x, f), vertex_areas(x, f), (np.arange(len(x)),))


def test_clustered_everywhere_and_exact_at_every_sampled_vertex():
    # a flat square of marble 60 mm across: no source sends out more than R_d (its energy scales are 1),
    # and the radius reaches over many cells, so clusters serve far sources
    x, f, _ = plane(1.0, 12)
    surface = Surface(x, f, np.tile([0.0, 0.0, 1.0], (len(x), 1)), vertex_areas(x, f), (np.arange(len(x)),))
    q, check = checked_reference(surface, 2.5, preset("marble"), LIGHT)
    np.testing.assert_allclose(q, reference_scattering(surface, 2.5, preset("marble"), LIGHT, clustered=True),
                               rtol=1e-12, atol=1e-15)
    assert check.of == len(x) and len(check.vertices) == check.of  # small: every vertex
    np.testing.assert_array_equal(check.clustered, q[:, check.vertices])
    exact = reference_scattering(surface, 2.5, preset("marble"), LIGHT)
    np.testing.assert_allclose(check.exact, exact[:, check.vertices], rtol=1e-9, atol=1e-12 * exact.max())
    assert 0 < np.abs(check.clustered - check.exact).max() < 1e-2 * exact.max()  # the clusters' error, measured
    assert check.sources == len(x) and np.all(check.scale_error == 0.0)  # no source over R_d, either way


def test_a_small_pair_budget_samples_fewer_vertices_round_a_sphere():
    # marble round a sphere 30 mm across: chords are shorter than the surface's paths, so sources send out
    # more than R_d and are scaled (by the clustered sums: the check is exact to their ~1e-3)
    surface = surface_of(trimesh.creation.icosphere(subdivisions=3, radius=1.0))
    material = replace(preset("marble"), back_gain=(0.5, 0.6, 0.7))  # light from behind scaled as the reference does
    q, check = checked_reference(surface, 15.0, material, LIGHT, pairs=1)
    assert len(check.vertices) == CHECK_MIN and len(np.unique(check.vertices)) == CHECK_MIN
    assert check.sources == CHECK_MIN
    np.testing.assert_allclose(q, reference_scattering(surface, 15.0, material, LIGHT, clustered=True),
                               rtol=1e-12, atol=1e-15)
    exact = reference_scattering(surface, 15.0, material, LIGHT)
    again = checked_reference(surface, 15.0, material, LIGHT, pairs=1)[1]
    np.testing.assert_array_equal(again.vertices, check.vertices)  # the same mesh and light: the same sample
    # every source and receiver sampled: the exact reference lies within scale_error · exact of the
    # check's exact pair sum, and the scales were off (by the clustered sums' error)
    _, full = checked_reference(surface, 15.0, material, LIGHT, pairs=10**9)
    assert len(full.vertices) == full.of and full.of / 3 < full.sources < full.of  # every lit source (about half)
    truth = exact[:, full.vertices]
    assert np.all(np.abs(truth - full.exact) <= full.scale_error[:, None] * full.exact + 1e-12 * truth.max())
    assert 0 < full.scale_error.max() < 1e-2 and np.abs(truth - full.exact).max() > 1e-6 * truth.max()


def test_check_figures_in_image_units():
    exact = np.linspace(0.0, 0.5, 3 * 400).reshape(3, 400)
    one = ReferenceCheck(np.arange(400), exact + 0.01, exact, np.zeros(3), 50, 1000, 1.5)
    figures = check_figures([one], exposure=0.5)
    # a shift of 0.01 everywhere is 0.005 at exposure 0.5, clipped nowhere (values up to 0.255)
    np.testing.assert_allclose([figures["rms"], figures["max"]], [0.005, 0.005], rtol=1e-9)
    lo, hi = figures["rms_ci95"]
    assert lo <= figures["rms"] <= hi and hi - lo < 1e-9  # the same difference at every vertex
    np.testing.assert_allclose(figures["relative"], 0.01 / np.sqrt(np.mean(exact**2)), rtol=1e-9)
    assert (figures["vertices"], figures["of"], figures["sources"], figures["seconds"]) == (400, 1000, 50, 1.5)
    # the sources' scales off by 10 %: the exact reference is within 0.1 · exact more
    scaled = check_figures([ReferenceCheck(np.arange(400), exact + 0.01, exact, np.full(3, 0.1), 50, 1000, 1.5)], 0.5)
    np.testing.assert_allclose(scaled["rms"], 0.5 * np.sqrt(np.mean((0.01 + 0.1 * exact) ** 2)), rtol=1e-9)
    assert scaled["scale_error"] == 0.1
    # a difference at one vertex of many: the interval is wide and holds the estimate
    spiky = ReferenceCheck(np.arange(400), exact + np.where(np.arange(400) == 7, 0.2, 0.0), exact, np.zeros(3), 50,
                           400, 0.0)
    figures = check_figures([spiky, one], exposure=1.0)
    lo, hi = figures["rms_ci95"]
    assert figures["vertices"] == 800 and lo < figures["rms"] < hi and hi > 1.5 * lo
    np.testing.assert_allclose(figures["rms"], np.sqrt((0.2**2 + 400 * 0.01**2) / 800), rtol=1e-9)
