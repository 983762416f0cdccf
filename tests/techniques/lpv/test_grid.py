import numpy as np
import pytest
import trimesh
from fixtures import cylinder, hemisphere

from sssbake.pipeline.core.materials import preset
from sssbake.pipeline.core.surface import Surface, area_weighted_normals, vertex_areas
from sssbake.pipeline.techniques.lpv.grid import (LpvGridError, LpvGridOptions, cell_centres, cell_of, homogeneous,
                                                  voxelise)

MARBLE = homogeneous(preset("marble"))


def surface(mesh: trimesh.Trimesh) -> Surface:
    v, f = np.asarray(mesh.vertices, dtype=np.float64), np.asarray(mesh.faces, dtype=np.int64)
    return Surface(v, f, area_weighted_normals(v, f), vertex_areas(v, f), (np.arange(len(v)),))


@pytest.mark.parametrize("supersample", [1, 3, 4])
def test_a_box_on_cell_boundaries_fills_its_cells_exactly(supersample):
    # 2 × 1 × 0.5 at resolution 8: cell 0.25, 8 × 4 × 2 cells, faces on cell boundaries
    box = trimesh.creation.box(extents=(2.0, 1.0, 0.5))
    grid = voxelise(surface(box), 10.0, MARBLE, 1.5, LpvGridOptions(resolution=8, padding=2, supersample=supersample))
    assert grid.cell == 0.25
    assert grid.shape == (12, 8, 6) and grid.occupancy.shape == (6, 8, 12)
    assert np.array_equal(grid.origin, [-1.5, -1.0, -0.75])
    expected = np.zeros((6, 8, 12), dtype=np.float32)
    expected[2:4, 2:6, 2:10] = 1.0
    assert np.array_equal(grid.occupancy, expected)


def test_rows_through_vertices_and_edges_count_each_crossing_once():
    # octahedron |x| + |y| + |z| = 3.75, cell 1.5, samples every 0.5 on multiples of 0.5: sample
    # rows run through its vertices and along its projected edges, no sample lies on it
    octahedron = trimesh.Trimesh(3.75 * np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]],
                                                 dtype=np.float64),
                                 [[0, 2, 4], [2, 1, 4], [1, 3, 4], [3, 0, 4], [2, 0, 5], [1, 2, 5], [3, 1, 5], [0, 3, 5]],
                                 process=False)
    assert octahedron.volume > 0
    grid = voxelise(surface(octahedron), 1.0, MARBLE, 1.5, LpvGridOptions(resolution=5, supersample=3))
    assert grid.cell == 1.5 and np.array_equal(grid.origin, [-5.25] * 3)
    sub = -5.0 + 0.5 * np.arange(21)
    z, y, x = np.meshgrid(sub, sub, sub, indexing="ij")
    share = (np.abs(x) + np.abs(y) + np.abs(z) < 3.75).reshape(7, 3, 7, 3, 7, 3).mean(axis=(1, 3, 5))
    assert np.allclose(grid.occupancy[share > 0], share[share > 0], rtol=0, atol=1e-7)
    assert np.all(np.isin(grid.occupancy[share == 0], np.float32([0.0, 1.0 / 27])))


@pytest.mark.parametrize("padding", [0, 1, 3])
def test_shape_follows_resolution_and_padding(padding):
    box = trimesh.creation.box(extents=(3.0, 1.0, 2.0))
    grid = voxelise(surface(box), 1.0, MARBLE, 1.5, LpvGridOptions(resolution=12, padding=padding))
    assert grid.shape == (12 + 2 * padding, 4 + 2 * padding, 8 + 2 * padding)
    assert np.isclose(grid.cell, 0.25)
    assert np.allclose(grid.origin, np.array([-1.5, -0.5, -1.0]) - padding * grid.cell)
    if padding:
        inner = grid.occupancy[padding:-padding, padding:-padding, padding:-padding]
        assert inner.sum() == grid.occupancy.sum() and np.all(inner == 1.0)


def test_sphere_volume_occupancy_range_and_surface_cells():
    sphere = trimesh.creation.icosphere(subdivisions=4, radius=1.0)
    errors = {}
    for ss in (2, 4, 8):
        grid = voxelise(surface(sphere), 1.0, MARBLE, 1.5, LpvGridOptions(resolution=16, supersample=ss))
        assert grid.occupancy.min() >= 0.0 and grid.occupancy.max() <= 1.0
        errors[ss] = abs(grid.occupancy.sum() * grid.cell**3 / sphere.volume - 1.0)
    assert errors[2] < 0.04 and errors[4] < 0.01 and errors[8] < 0.005
    assert errors[8] < errors[2]


@pytest.mark.parametrize("supersample", [1, 4])
def test_every_cell_holding_surface_has_medium(supersample):
    # with one sample per cell, most surface cells have their centre outside: the floor must fill them
    sphere = trimesh.creation.icosphere(subdivisions=2, radius=1.0)
    grid = voxelise(surface(sphere), 1.0, MARBLE, 1.5, LpvGridOptions(resolution=12, supersample=supersample))
    v, f = sphere.vertices, sphere.faces
    on_surface = np.concatenate([
        trimesh.sample.sample_surface(sphere, 20000, seed=1)[0],
        v,
        0.5 * (v[f[:, 0]] + v[f[:, 1]]),
        v[f].mean(axis=1),
    ])
    ijk = cell_of(grid, on_surface)
    assert np.all(ijk >= 0)
    occupancy = grid.occupancy[ijk[:, 2], ijk[:, 1], ijk[:, 0]]
    assert np.all(occupancy > 0)
    # and the floor is the smallest share the supersampling resolves
    assert occupancy.min() >= 1.0 / supersample**3


def test_homogeneous_coefficients_in_occupied_cells_zeros_elsewhere():
    material = preset("skin1")
    sphere = trimesh.creation.icosphere(subdivisions=3, radius=2.0)
    grid = voxelise(surface(sphere), 5.0, homogeneous(material), material.eta, LpvGridOptions(resolution=10))
    grid.check()
    occupied = grid.occupancy > 0
    assert 0 < occupied.sum() < occupied.size
    assert np.allclose(grid.sigma_t[occupied], material.s + material.a, rtol=1e-6)
    assert np.allclose(grid.albedo[occupied], material.s / (material.s + material.a), rtol=1e-6)
    assert np.all(grid.sigma_t[~occupied] == 0) and np.all(grid.albedo[~occupied] == 0)
    assert np.all(grid.g == 0)
    for name in ("occupancy", "sigma_t", "albedo", "g"):
        assert getattr(grid, name).dtype == np.float32
    assert grid.eta == material.eta and grid.mm_per_unit == 5.0 and np.isclose(grid.cell_mm, 5.0 * 4.0 / 10)


def test_a_field_is_read_at_the_cell_centres():
    # σ'_s grows with x: each occupied cell holds the value at its centre
    def field(p):
        s = np.column_stack([1.0 + p[:, 0] ** 2, np.ones(len(p)), np.ones(len(p))])
        return s, np.full((len(p), 3), 0.01)

    sphere = trimesh.creation.icosphere(subdivisions=3)
    grid = voxelise(surface(sphere), 1.0, field, 1.3, LpvGridOptions(resolution=8))
    occupied = grid.occupancy > 0
    x = cell_centres(grid)[..., 0]
    assert np.allclose(grid.sigma_t[occupied, 0], 1.01 + x[occupied] ** 2, rtol=1e-6)


def test_translating_by_whole_cells_moves_only_the_origin():
    # integer vertices, cell 1 and samples at quarters: every coordinate is exact (rows through
    # vertices and edges included), so the arrays must match bit for bit
    rng = np.random.default_rng(3)
    hull = trimesh.convex.convex_hull(rng.integers(-8, 9, (40, 3)).astype(np.float64))
    options = LpvGridOptions(resolution=16, supersample=4)
    grid = voxelise(surface(hull), 1.0, MARBLE, 1.5, options)
    assert grid.cell == 1.0 and 0 < grid.occupancy.mean() < 1
    shift = np.array([3.0, -2.0, 5.0])
    moved = voxelise(surface(trimesh.Trimesh(hull.vertices + shift, hull.faces, process=False)), 1.0, MARBLE, 1.5,
                     options)
    assert np.array_equal(moved.origin, grid.origin + shift) and moved.cell == grid.cell
    assert np.array_equal(moved.occupancy, grid.occupancy)
    # a sphere with inexact coordinates, shifted by 7 cells: same occupancy, origin up to rounding
    sphere = trimesh.creation.icosphere(subdivisions=3)
    a = voxelise(surface(sphere), 1.0, MARBLE, 1.5, options)
    shift = 7 * a.cell * np.array([1.0, -1.0, 0.5])
    b = voxelise(surface(trimesh.Trimesh(sphere.vertices + shift, sphere.faces, process=False)), 1.0, MARBLE, 1.5,
                 options)
    assert np.allclose(b.origin, a.origin + shift, rtol=0, atol=1e-12)
    assert np.array_equal(b.occupancy, a.occupancy)


def test_cell_of_and_cell_centres_round_trip():
    sphere = trimesh.creation.icosphere(subdivisions=2)
    grid = voxelise(surface(sphere), 1.0, MARBLE, 1.5, LpvGridOptions(resolution=6, padding=2))
    nx, ny, nz = grid.shape
    centres = cell_centres(grid)
    assert centres.shape == (nz, ny, nx, 3)
    k, j, i = np.meshgrid(np.arange(nz), np.arange(ny), np.arange(nx), indexing="ij")
    expected = np.stack([i, j, k], axis=-1).reshape(-1, 3)
    assert np.array_equal(cell_of(grid, centres.reshape(-1, 3)), expected)
    # any point maps to the cell whose centre is within half a cell of it
    rng = np.random.default_rng(0)
    lo, hi = grid.origin, grid.origin + grid.cell * np.array(grid.shape)
    points = rng.uniform(lo, hi, (5000, 3))
    ijk = cell_of(grid, points)
    assert np.all(np.abs(centres[ijk[:, 2], ijk[:, 1], ijk[:, 0]] - points) <= 0.5 * grid.cell * (1 + 1e-12))
    # the far corner belongs to the last cell; points outside get -1
    assert np.array_equal(cell_of(grid, hi[None]), [[nx - 1, ny - 1, nz - 1]])
    outside = np.array([lo - 1e-9, hi + [0.0, 1e-9, 0.0], [np.nan, 0.0, 0.0]])
    assert np.array_equal(cell_of(grid, outside), -np.ones((3, 3), dtype=np.int64))


def _good():
    return surface(trimesh.creation.box(extents=(1.0, 1.0, 1.0)))


def _field(s, a):
    return lambda p: (np.broadcast_to(s, (len(p), 3)) if np.ndim(s) == 1 else s, np.full((len(p), 3), a))


@pytest.mark.parametrize(
    ("change", "message"),
    [
        (dict(options=LpvGridOptions(resolution=1)), "resolution"),
        (dict(options=LpvGridOptions(resolution=513)), "resolution"),
        (dict(options=LpvGridOptions(padding=-1)), "padding"),
        (dict(options=LpvGridOptions(padding=9)), "padding"),
        (dict(options=LpvGridOptions(supersample=0)), "supersample"),
        (dict(options=LpvGridOptions(supersample=9)), "supersample"),
        (dict(options=LpvGridOptions(resolution=8.0)), "resolution"),
        (dict(surface=Surface(np.zeros((0, 3)), np.zeros((0, 3), np.int64), np.zeros((0, 3)), np.zeros(0), ())),
         "no triangles"),
        (dict(mm_per_unit=0.0), "mm_per_unit"),
        (dict(mm_per_unit=-1.0), "mm_per_unit"),
        (dict(mm_per_unit=float("nan")), "mm_per_unit"),
        (dict(eta=0.0), "eta"),
        (dict(material_field=lambda p: np.ones((len(p), 3))), "pair"),
        (dict(material_field=lambda p: (np.ones((len(p), 2)), np.ones((len(p), 3)))), "shape"),
        (dict(material_field=lambda p: (np.ones(3), np.ones(3))), "shape"),
        (dict(material_field=_field(np.array([1.0, -0.5, 1.0]), 0.1)), "sigma_s_prime"),
        (dict(material_field=_field(np.array([1.0, 1.0, 1.0]), np.nan)), "sigma_a"),
    ],
)
def test_bad_inputs_raise(change, message):
    args = dict(surface=_good(), mm_per_unit=1.0, material_field=MARBLE, eta=1.5, options=LpvGridOptions(resolution=4))
    args.update(change)
    with pytest.raises(ValueError, match=f"^lpv grid: .*{message}"):
        voxelise(**args)


def test_bad_surfaces_raise():
    box = trimesh.creation.box()
    v, f = np.array(box.vertices), np.array(box.faces)
    bad = v.copy()
    bad[0, 0] = np.inf
    with np.errstate(invalid="ignore"), pytest.raises(LpvGridError, match="^lpv grid: .*non-finite"):
        voxelise(surface(trimesh.Trimesh(bad, f, process=False)), 1.0, MARBLE, 1.5)
    # a sheet encloses nothing: its winding number is at most 1/2 everywhere off it
    square = trimesh.Trimesh([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 1.0, 0.0], [0.0, 1.0, 0.0]],
                             [[0, 1, 2], [0, 2, 3]], process=False)
    with pytest.raises(LpvGridError, match="^lpv grid: no sample point lies inside the surface"):
        voxelise(surface(square), 1.0, MARBLE, 1.5)


def _voxel_volume(grid) -> float:
    return float(grid.occupancy.sum(dtype=np.float64)) * grid.cell**3


@pytest.mark.parametrize("whole_face", [False, True])
def test_a_box_missing_a_triangle_or_a_face_fills_the_closed_box(whole_face):
    # planar openings: the inside ends on their planes (x = -1), which the sub-cell points straddle
    box = trimesh.creation.box(extents=(2.0, 1.0, 0.5))
    faces = np.asarray(box.faces)
    side = np.flatnonzero(np.all(np.asarray(box.vertices)[faces][:, :, 0] == -1.0, axis=1))
    assert len(side) == 2
    opened = trimesh.Trimesh(box.vertices, np.delete(faces, side if whole_face else side[:1], axis=0), process=False)
    options = LpvGridOptions(resolution=8, padding=2, supersample=4)
    closed = voxelise(surface(box), 10.0, MARBLE, 1.5, options)
    assert _voxel_volume(closed) == 1.0
    assert np.array_equal(voxelise(surface(opened), 10.0, MARBLE, 1.5, options).occupancy, closed.occupancy)


def test_an_open_hemisphere_fills_the_closed_hemisphere():
    # the rim is a planar loop, so the inside ends on the base's plane, which the sub-cell points
    # straddle at h/2: the same points are in as in the closed one (counted exactly by scanline)
    options = LpvGridOptions(resolution=16)
    closed = voxelise(surface(trimesh.Trimesh(*hemisphere(1.0), process=False)), 1.0, MARBLE, 1.5, options)
    opened = voxelise(surface(trimesh.Trimesh(*hemisphere(1.0, base=False), process=False)), 1.0, MARBLE, 1.5, options)
    volume = trimesh.Trimesh(*hemisphere(1.0), process=False).volume
    assert _voxel_volume(closed) == pytest.approx(volume, rel=0.005)
    assert np.array_equal(opened.occupancy, closed.occupancy)


def test_a_cylinder_without_caps_is_the_capped_one_but_near_its_ends():
    # w over an opening of a tube is 1/2 minus the far opening's solid angle / 4π (0.026 here on the
    # axis): the inside is recessed into each end, by 0.051 R on the axis, where
    # (1 - s / sqrt(s² + R²)) / 2 = 1/2 - 0.026; away from the ends the cells are the capped ones'
    radius, height = 1.0, 3.0
    options = LpvGridOptions(resolution=16)
    capped = voxelise(surface(trimesh.Trimesh(*cylinder(radius, height), process=False)), 1.0, MARBLE, 1.5, options)
    tube = voxelise(surface(trimesh.Trimesh(*cylinder(radius, height, caps=False), process=False)), 1.0, MARBLE,
                    1.5, options)
    volume = trimesh.Trimesh(*cylinder(radius, height), process=False).volume
    assert _voxel_volume(capped) == pytest.approx(volume, rel=0.002)
    z = cell_centres(capped)[:, 0, 0, 2]
    middle = np.abs(z) < 0.5 * height - radius
    assert np.array_equal(tube.occupancy[middle], capped.occupancy[middle])
    # the recess: a cone-like dimple of depth ~0.05 R over each end's disc of area π R², under 3 %
    assert 0.97 < _voxel_volume(tube) / volume < 1.0


def test_a_folded_triangle_disturbs_only_the_cells_around_it():
    # one triangle of a 5120-face sphere wound against its neighbours: the scanline count would run on
    # from it to the grid's end; the winding number flips the inside only within ~its own size
    sphere = trimesh.creation.icosphere(subdivisions=4, radius=1.0)
    faces = np.array(sphere.faces)
    faces[100] = faces[100, ::-1]
    options = LpvGridOptions(resolution=16)
    intact = voxelise(surface(sphere), 1.0, MARBLE, 1.5, options)
    folded = voxelise(surface(trimesh.Trimesh(sphere.vertices, faces, process=False)), 1.0, MARBLE, 1.5, options)
    assert _voxel_volume(folded) == pytest.approx(sphere.volume, rel=0.005)
    changed = np.argwhere(folded.occupancy != intact.occupancy)
    centre = sphere.vertices[sphere.faces[100]].mean(axis=0)
    near = np.linalg.norm(cell_centres(intact)[tuple(changed.T)] - centre, axis=1) < 2.0 * intact.cell
    assert len(changed) <= 8 and near.all()


def test_inward_winding_fills_the_same_cells():
    # the non-zero rule: a consistently inward-wound surface is still closed, with the same inside
    sphere = trimesh.creation.icosphere(subdivisions=2)
    out = voxelise(surface(sphere), 1.0, MARBLE, 1.5, LpvGridOptions(resolution=8))
    inward = voxelise(surface(trimesh.Trimesh(sphere.vertices, sphere.faces[:, ::-1], process=False)), 1.0, MARBLE,
                      1.5, LpvGridOptions(resolution=8))
    assert np.array_equal(out.occupancy, inward.occupancy)


def test_a_material_with_no_extinction_in_a_channel_has_zero_albedo_there():
    # Material forbids σ'_t = 0, but a field may give it: α' is 0 there, not NaN
    field = _field(np.array([1.0, 0.0, 1.0]), 0.0)
    grid = voxelise(_good(), 1.0, field, 1.5, LpvGridOptions(resolution=4))
    occupied = grid.occupancy > 0
    assert np.all(grid.albedo[occupied][:, 1] == 0) and np.all(grid.albedo[occupied][:, 0] == 1)
