"""Valid extremes and hostile geometry (issue 19): lpv's scale at attenuations that keep no light
after a step, whole bakes at sigma_a = 1e4 and scale_mm = 1e5 without a RuntimeWarning, and
diagnoses that name the real cause for coordinates too large to compute with."""

import warnings

import numpy as np
import pytest
import trimesh
from test_extremes import small_ball

from sssbake.pipeline.core.profile import profile_of, profile_total
from sssbake.pipeline.core.fresnel import fresnel_transmittance
from sssbake.pipeline.core.materials import Material
from sssbake.pipeline.techniques.lpv.calibrate import render_scales
from sssbake.pipeline.techniques.lpv.grid import LpvGridOptions, homogeneous, voxelise
from sssbake.pipeline.techniques.lpv.inject import LOBE
from sssbake.pipeline.techniques.lpv.layout import lpv_tables
from sssbake.pipeline.techniques.lpv.matrices import DIRECTIONS, lpv_basis, propagation_matrices
from sssbake.pipeline.techniques.lpv.propagate import DECAY_LIMIT, RENDER_WEIGHTS, transport_factors

DENSE = {"sigma_s_prime": [1.0, 1.0, 1.0], "sigma_a": [1e4, 1e4, 1e4], "eta": 1.3}


def first_step_radiance(grid) -> np.ndarray:
    """(3,) radiance per unit attenuation a after one step of the calibration's slab (a 1 × 1
    periodic column lit at normal incidence), derived by hand: the top cell's injected lobe comes
    back to it from its four lateral neighbours (itself, periodic), scattered and attenuated
    sqrt(a) twice; what goes down returns only after a second step, O(a²)."""
    mean = {name: getattr(grid, name)[grid.occupancy > 0].astype(np.float64).mean(axis=0)
            for name in ("sigma_t", "albedo", "g")}
    scatter = -np.expm1(-mean["albedo"] * mean["sigma_t"] * grid.cell_mm)
    band1 = (1.0 - scatter) + scatter * mean["g"]
    lobe = fresnel_transmittance(grid.eta, 1.0) * grid.cell_mm**2 * LOBE[[0, 1, 1, 1]] \
        * lpv_basis(np.array([[0.0, 0.0, -1.0]]))[0]
    lateral = sum(m for m, d in zip(propagation_matrices(), DIRECTIONS) if d[2] == 0)
    back = np.stack([lateral @ (lobe * np.array([1.0, b, b, b])) for b in band1])  # (3, 4)
    return 2.0 / grid.cell_mm**2 * (RENDER_WEIGHTS[0] * back[:, 0] + RENDER_WEIGHTS[1] * back[:, 2])


@pytest.mark.parametrize("sigma_a, mm", [(1e4, 1.0), (0.0071, 1e5), (300.0, 1.0)])
def test_lpv_scale_meets_its_limit_where_a_step_keeps_no_light(sigma_a, mm):
    material = Material("dense", (1.0, 1.0, 1.0), (sigma_a,) * 3, 1.3)
    grid = voxelise(small_ball(), mm, homogeneous(material), material.eta, LpvGridOptions(resolution=8))
    _, attenuation = transport_factors(grid)
    a = attenuation[grid.occupancy > 0].max(axis=0)
    assert np.all(a < 1e-20)  # a step keeps nothing: the asymptotic regime
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        scales = render_scales(grid, 6, "montecarlo")
        tables = lpv_tables(grid, propagation_matrices(), scales, "homogeneous")
    # the slab's radiance is a R1 + O(a²), so every step count's scale tends to want / (a R1)
    albedo = grid.albedo[grid.occupancy > 0].astype(np.float64).mean(axis=0)
    want = profile_total(profile_of(tuple(albedo), tuple(1.0 - albedo), grid.eta, "montecarlo")) * fresnel_transmittance(grid.eta, 1.0) / np.pi
    limit = want / (a * first_step_radiance(grid))
    np.testing.assert_allclose(scales, np.broadcast_to(limit, scales.shape), rtol=1e-9)
    assert np.all(np.isfinite(tables["renderScale"])) and np.all(tables["renderScale"] > 0)


def test_lpv_attenuation_stops_falling_where_the_runtime_clamps_it():
    material = Material("dense", (1.0, 1.0, 1.0), (1e4,) * 3, 1.3)
    grid = voxelise(small_ball(), 1.0, homogeneous(material), material.eta, LpvGridOptions(resolution=8))
    _, attenuation = transport_factors(grid)
    # runtime_shaders/lpv_grid.glsl holds sigma_tr dx at 80, so the scale matches what the GPU keeps
    np.testing.assert_allclose(attenuation[grid.occupancy > 0], 3.0 / (2.0 + np.cosh(DECAY_LIMIT)), rtol=1e-12)
    assert DECAY_LIMIT == 80.0


@pytest.mark.parametrize("technique", ["lpv", "prt", "screen", "spectral", "kernels"])
@pytest.mark.parametrize("overrides", [{"material": DENSE, "scale_mm": 1.0}, {"material": "marble", "scale_mm": 1e5}],
                         ids=["sigma_a=1e4", "scale_mm=1e5"])
def test_a_bake_at_the_extremes_is_finite_and_quiet(tmp_path, technique, overrides):
    from sssbake.pipeline.bake.asset import bake_asset
    from sssbake.pipeline.bake.cache import StageCache
    from sssbake.pipeline.options import BakeOptions

    trimesh.creation.icosphere(subdivisions=2, radius=5.0).export(tmp_path / "ball.obj")
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        result = bake_asset(tmp_path / "ball.obj", BakeOptions(atlas_resolution=64, techniques=(technique,),
                                                                **overrides), tmp_path / "ball", StageCache(None))
    # the exporters refuse non-finite tables, so a written file is a finite one
    assert result.report[technique], f"{technique} baked nothing"
    assert result.report["validation"]["gltf"]["errors"] == 0 and result.report["validation"]["usd"]["errors"] == 0
    assert all(path.exists() for path in result.outputs)


def _obj(path, positions, faces):
    path.write_text("".join(f"v {x:.17g} {y:.17g} {z:.17g}\n" for x, y, z in positions)
                    + "".join(f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in faces))
    return path


def _clean(path):
    from sssbake.pipeline.mesh.clean import clean_scene
    from sssbake.pipeline.mesh.load import load_scene

    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        return clean_scene(load_scene(path))


def test_coordinates_beyond_float32_are_named_not_called_degenerate(tmp_path):
    from sssbake.pipeline.core.errors import AssetError

    tetra = trimesh.creation.icosphere(subdivisions=0)
    path = _obj(tmp_path / "huge.obj", np.asarray(tetra.vertices) * 1e308, tetra.faces)
    with pytest.raises(AssetError) as error:
        _clean(path)
    assert str(error.value) == (f"{path}: mesh 'huge.obj': coordinates reach 8.51e+307, too large to compute with (the "
                                "limit is 3.4e+38, float32's largest, which the outputs store positions in); "
                                "rescale the asset")
    # just below the limit the same mesh cleans, with finite areas and unit normals
    surface = _clean(_obj(tmp_path / "big.obj", np.asarray(tetra.vertices) * 1e38, tetra.faces)).surfaces[0]
    assert np.all(np.isfinite(surface.vertex_areas)) and surface.area > 0
    np.testing.assert_allclose(np.linalg.norm(surface.normals, axis=1), 1.0, rtol=1e-12)


def test_a_few_outlier_vertices_are_named_not_called_degenerate(tmp_path):
    from sssbake.pipeline.core.errors import AssetError

    ball = trimesh.creation.icosphere(subdivisions=3, radius=1.0)  # 642 vertices
    positions = np.asarray(ball.vertices).copy()
    positions[[5, 100]] *= 1e30  # bit-flipped exponents
    with pytest.raises(AssetError, match=r"mesh 'flip.obj': 2 of 642 vertices lie far outside the rest \(up to "
                                         r"1e\+30 from their median, 99% of them within 1; they fill 6.9e-31 of "
                                         r"the bounding box's diagonal\): corrupt positions\?"):
        _clean(_obj(tmp_path / "flip.obj", positions, ball.faces))
    # a long thin mesh is not an outlier: its vertices spread along the whole box
    rod = trimesh.creation.cylinder(radius=1e-3, height=1e3, sections=8)
    assert len(_clean(_obj(tmp_path / "rod.obj", rod.vertices, rod.faces)).surfaces) == 1


def test_a_tiny_sphere_bakes_its_atlas(tmp_path):
    from sssbake.pipeline.bake.asset import bake_asset
    from sssbake.pipeline.bake.cache import StageCache
    from sssbake.pipeline.options import BakeOptions

    # 1e-8 file units across, 10 mm at scale_mm = 1e9: xatlas once gave it a 0 x 0 atlas
    ball = trimesh.creation.icosphere(subdivisions=2, radius=5e-9)
    path = _obj(tmp_path / "tiny.obj", ball.vertices, ball.faces)
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        result = bake_asset(path, BakeOptions(atlas_resolution=64, material="marble", scale_mm=1e9),
                            tmp_path / "tiny", StageCache(None))
    atlas = result.report["atlas"]["tiny.obj"]
    assert atlas["width"] >= 64 and atlas["height"] >= 64 and atlas["charts"] >= 1
    assert result.report["validation"]["gltf"]["errors"] == 0
