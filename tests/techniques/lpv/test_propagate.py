"""lpv propagation and rendering in numpy: flux never grows and decays by the closed-form factor in
a homogeneous medium, an empty grid stays empty, whole-cell translations commute with the steps,
fully scattered light decays over the material's diffusion length, and the area-light radiance
has its closed form."""

import numpy as np
import pytest

from sssbake.pipeline.techniques.lpv.data import LpvGrid
from sssbake.pipeline.techniques.lpv.propagate import (
    RENDER_WEIGHTS,
    LpvPropagateOptions,
    propagate,
    radiance,
    transport_factors,
)


def block_grid(shape=(15, 15, 15), sigma_t=(2.0, 2.0, 2.0), albedo=(0.99, 0.999, 1.0), g=0.0, cell=1.0, mm=1.0,
               medium=None):
    """A grid of one medium (`medium`: a (nz, ny, nx) bool mask; all cells by default)."""
    nx, ny, nz = shape
    occupancy = np.ones((nz, ny, nx), np.float32) if medium is None else medium.astype(np.float32)
    full = lambda v: np.where(occupancy[..., None] > 0, np.broadcast_to(np.asarray(v, np.float32), (nz, ny, nx, 3)),
                              0).astype(np.float32)
    grid = LpvGrid(origin=np.zeros(3), cell=cell, mm_per_unit=mm, occupancy=occupancy, sigma_t=full(sigma_t),
                   albedo=full(albedo), g=full(g), eta=1.3)
    grid.check()
    return grid


def point_source(grid, cell=(7, 7, 7), lobe=(1.0, 0.0, 0.0, 0.0)):
    nx, ny, nz = grid.shape
    injected = np.zeros((nz, ny, nx, 3, 4))
    i, j, k = cell
    injected[k, j, i] = lobe
    return injected


def test_flux_decays_by_the_attenuation_factor_and_never_grows():
    grid = block_grid()
    _, attenuation = transport_factors(grid)
    a = attenuation[0, 0, 0]
    # anisotropic input: the matrices move all flux whatever its direction
    _, flux = propagate(grid, point_source(grid, lobe=(1.0, 0.3, -0.2, 0.5)), 6)
    # six steps from the centre of a 15-cell grid never reach its border: per channel a^k exactly
    expected = np.sqrt(4 * np.pi) * np.sum(a[None, :] ** np.arange(7)[:, None], axis=1)
    np.testing.assert_allclose(flux, expected, rtol=1e-12)
    # without absorption, flux is kept until light reaches cells without medium, then lost there
    clear = block_grid(albedo=(1.0, 1.0, 1.0), medium=np.pad(np.ones((5, 5, 5), bool), 5))
    assert np.all(transport_factors(clear)[1][5:10, 5:10, 5:10] == 1.0)
    _, flux = propagate(clear, point_source(clear), 40)
    assert np.all(np.diff(flux) <= 1e-12 * flux[0])
    np.testing.assert_allclose(flux[:3], flux[0], rtol=1e-12)  # two steps stay inside the 5³ block
    assert flux[-1] < 0.05 * flux[0]  # most has left through the surface


def test_an_empty_grid_stays_empty_and_converged_light_stops_changing():
    grid = block_grid(albedo=(0.5, 0.6, 0.7), medium=np.pad(np.ones((5, 5, 5), bool), 5))
    accumulated, flux = propagate(grid, np.zeros((15, 15, 15, 3, 4)), 5)
    assert not accumulated.any() and not flux.any()
    short, _ = propagate(grid, point_source(grid), 60)
    long, flux = propagate(grid, point_source(grid), 90)
    assert flux[60] < 1e-10 * flux[0]
    np.testing.assert_allclose(long, short, rtol=1e-8, atol=1e-12 * np.abs(short).max())


def test_whole_cell_translations_commute_with_propagation():
    medium = np.zeros((15, 15, 15), bool)
    medium[3:9, 4:10, 2:11] = True
    grid = block_grid(albedo=(0.9, 0.95, 0.99), g=0.3, medium=medium)
    moved = block_grid(albedo=(0.9, 0.95, 0.99), g=0.3, medium=np.roll(medium, (2, -1, 3), axis=(0, 1, 2)))
    a, _ = propagate(grid, point_source(grid, (6, 6, 5), (1.0, 0.2, 0.1, -0.3)), 12)
    b, _ = propagate(moved, point_source(moved, (9, 5, 7), (1.0, 0.2, 0.1, -0.3)), 12)
    np.testing.assert_allclose(np.roll(a, (2, -1, 3), axis=(0, 1, 2)), b, rtol=1e-12, atol=1e-15)


def test_scattered_light_decays_over_the_diffusion_length():
    # σ'_t Δx = 8: every step scatters fully (s = 1 - e^-8), so the lattice walk holds the decay
    sigma_t, albedo = 8.0, np.array([0.999, 0.99, 0.97])
    grid = block_grid(shape=(41, 41, 41), sigma_t=(sigma_t,) * 3, albedo=tuple(albedo))
    accumulated, _ = propagate(grid, point_source(grid, (20, 20, 20)), 120)
    sigma_tr = sigma_t * np.sqrt(3 * (1 - albedo))
    along = accumulated[20, 20, 24:32, :, 0]  # 4 to 11 cells from the source along +x
    slope = -np.polyfit(np.arange(24, 32), np.log(along), 1)[0]
    # the far field of a point source falls as e^(-σ_tr r) / r: remove the 1/r before comparing
    slope_corrected = -np.polyfit(np.arange(24, 32), np.log(along * (np.arange(4, 12)[:, None])), 1)[0]
    np.testing.assert_allclose(slope_corrected, sigma_tr, rtol=0.08)
    assert np.all(slope > slope_corrected)


def test_radiance_is_the_area_light_of_the_outward_intensity():
    medium = np.pad(np.ones((4, 4, 2), bool), ((0, 0), (0, 0), (0, 2)))
    grid = block_grid(shape=(4, 4, 4), cell=0.5, mm=4.0, medium=medium)
    nx, ny, nz = grid.shape
    c = np.array([2.0, 0.3, -0.4, 0.7])  # (c00, c1-1 (y), c10 (z), c11 (x))
    accumulated = np.broadcast_to(c, (nz, ny, nx, 3, 4)).copy()
    accumulated[:, :, 2:] = 1e6  # cells x >= 2 have no medium: their values must not be read
    normal = np.array([[0.6, 0.0, 0.8]])
    area = (0.5 * 4.0) ** 2
    expected = 2 / area * (RENDER_WEIGHTS[0] * 2.0 + RENDER_WEIGHTS[1] * (0.6 * 0.7 + 0.8 * -0.4))
    # a point between the last medium cell and the first empty one reads the medium cell alone
    for x in (0.3, 0.9, 1.2):
        got = radiance(grid, accumulated, np.array([[x, 1.0, 1.0]]), normal)
        np.testing.assert_allclose(got, expected, rtol=1e-12)
    # a lobe pointing inwards gives no radiance, never a negative one
    inward = np.zeros_like(accumulated)
    inward[..., 0], inward[..., 3] = 1.0, -10.0
    assert np.all(radiance(grid, inward, np.array([[0.5, 1.0, 1.0]]), np.array([[1.0, 0, 0]])) == 0.0)


def test_options_are_checked():
    LpvPropagateOptions().check()
    for bad in (LpvPropagateOptions(steps=0), LpvPropagateOptions(shadow_size=0), LpvPropagateOptions(steps=2.5)):
        with pytest.raises(ValueError, match="lpv:"):
            bad.check()
    grid = block_grid(shape=(3, 3, 3))
    with pytest.raises(ValueError, match="injected intensity"):
        propagate(grid, np.zeros((3, 3, 3, 4)), 1)


def test_light_leaks_across_a_gap_narrower_than_a_cell():
    """The paper's named limitation: two slabs a gap apart, light on the top one only. Cells that
    the gap runs through hold medium (the surface passes through them), so light crosses a gap
    narrower than a cell; across a gap of several cells it cannot."""
    import trimesh

    from sssbake.pipeline.core.materials import preset
    from sssbake.pipeline.core.reference import Light
    from sssbake.pipeline.mesh.clean import weld_surface
    from sssbake.pipeline.mesh.scene import Primitive
    from sssbake.pipeline.techniques.lpv.grid import LpvGridOptions, cell_centres, homogeneous, voxelise
    from sssbake.pipeline.techniques.lpv.inject import inject, light_samples

    def leaked(gap: float) -> float:
        top = trimesh.creation.box(extents=(20.0, 4.0, 20.0))
        top.apply_translation((0.0, 2.0 + gap / 2, 0.0))
        bottom = trimesh.creation.box(extents=(20.0, 4.0, 20.0))
        bottom.apply_translation((0.0, -2.0 - gap / 2, 0.0))
        mesh = trimesh.util.concatenate([top, bottom])
        surface = weld_surface([Primitive(positions=np.asarray(mesh.vertices, float), faces=np.asarray(mesh.faces))],
                               1e-9)
        material = preset("skimmilk")
        grid = voxelise(surface, 1.0, homogeneous(material), material.eta, LpvGridOptions(resolution=20))
        injected = inject(grid, light_samples(surface, 1.0, Light("directional", (0.0, 1.0, 0.0)), 128))
        accumulated, _ = propagate(grid, injected, 24)
        below = cell_centres(grid)[..., 1] < -gap / 2
        return float(accumulated[below][..., 0].sum() / accumulated[..., 0].sum())

    thin, wide = leaked(0.3), leaked(4.0)  # cells are 1 mm: a gap of 0.3 mm sits inside one
    # measured 3.7 % of the accumulated light below the gap; none across four empty cells
    assert thin > 0.02 and wide == 0.0, (thin, wide)
