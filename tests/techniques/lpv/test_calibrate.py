"""The lpv rendering's scale: a wide block lit at normal incidence gives the dipole's radiance at
its centre, for each step count; the scale follows the medium and refuses an empty grid."""

import numpy as np
import pytest

from sssbake.pipeline.core.profile import profile_of, profile_total
from sssbake.pipeline.core.fresnel import fresnel_transmittance
from sssbake.pipeline.techniques.lpv.calibrate import render_scales
from sssbake.pipeline.techniques.lpv.data import LpvGrid
from sssbake.pipeline.techniques.lpv.inject import LOBE
from sssbake.pipeline.techniques.lpv.matrices import lpv_basis
from sssbake.pipeline.techniques.lpv.propagate import propagate, radiance


def block(shape, sigma_t, albedo, cell=0.5, mm=2.0, depth=None):
    """A grid whose lower `depth` cell layers hold one medium (all of them by default)."""
    nx, ny, nz = shape
    occupancy = np.ones((nz, ny, nx), np.float32)
    if depth is not None:
        occupancy[depth:] = 0.0
    per = lambda v: (occupancy[..., None] * np.asarray(v, np.float32)).astype(np.float32)
    return LpvGrid(origin=np.zeros(3), cell=cell, mm_per_unit=mm, occupancy=occupancy, sigma_t=per(sigma_t),
                   albedo=per(albedo), g=per((0.0, 0.0, 0.0)), eta=1.4)


def test_a_wide_block_under_uniform_light_gives_the_dipole_radiance():
    sigma_t, albedo = (2.0, 2.5, 3.0), (0.99, 0.95, 0.9)  # per mm; cells of 1 mm
    steps = 10
    grid = block((31, 31, 14), sigma_t, albedo, depth=13)
    nx, ny, nz = grid.shape
    transmitted = fresnel_transmittance(1.4, 1.0) * grid.cell_mm**2
    injected = np.zeros((nz, ny, nx, 3, 4))
    injected[12] = transmitted * LOBE[[0, 1, 1, 1]] * lpv_basis(np.array([[0.0, 0.0, -1.0]]))[0]
    accumulated, _ = propagate(grid, injected, steps)
    centre = np.array([[15.5 * grid.cell, 15.5 * grid.cell, 13 * grid.cell]])
    got = radiance(grid, accumulated, centre, np.array([[0.0, 0.0, 1.0]]))[0] * render_scales(grid, steps, "montecarlo")[-1]
    want = profile_total(profile_of(tuple(np.array(albedo)), tuple(1.0 - np.array(albedo)), 1.4, "montecarlo")) * fresnel_transmittance(1.4, 1.0) / np.pi
    # the block's sides are further from its centre than light moves in 10 steps: a slab there
    np.testing.assert_allclose(got, want, rtol=1e-6)
    # near a side, where light leaves sideways too, the scaled radiance is lower
    edge = radiance(grid, accumulated, np.array([[0.5 * grid.cell, 15.5 * grid.cell, 13 * grid.cell]]),
                    np.array([[0.0, 0.0, 1.0]]))[0] * render_scales(grid, steps, "montecarlo")[-1]
    assert np.all(edge < 0.95 * want)


def test_scales_per_step_count_and_medium():
    thin = render_scales(block((4, 4, 4), (2.0,) * 3, (0.9,) * 3), 20, "montecarlo")
    assert thin.shape == (20, 3) and np.all(np.isfinite(thin)) and np.all(thin > 0)
    # more steps accumulate more: the scale falls, and stops changing once light has died out
    assert np.all(np.diff(thin[:, 0]) <= 0) and abs(thin[-1, 0] - thin[-2, 0]) < 1e-3 * thin[-1, 0]
    # equal channels give equal scales
    assert np.allclose(thin[:, 0], thin[:, 2])
    with pytest.raises(ValueError, match="no medium"):
        render_scales(block((2, 2, 2), (1.0,) * 3, (0.5,) * 3, depth=0), 4, "montecarlo")
    with pytest.raises(ValueError, match="max_steps"):
        render_scales(block((2, 2, 2), (1.0,) * 3, (0.5,) * 3), 0, "montecarlo")
