"""The lpv runtime on the GPU against its numpy reference: the injection from a rasterised shadow
map equals `lpv_inject` cell by cell (directional and point light), the propagation and
accumulation equal `lpv_propagate` on a heterogeneous (veined) grid, and the final draw is the
calibrated area-light radiance times the exit Fresnel."""

import numpy as np
import pytest
import trimesh

from sssbake.pipeline.core.materials import preset
from sssbake.pipeline.core.reference import Light
from sssbake.pipeline.mesh.clean import weld_surface
from sssbake.pipeline.mesh.scene import Primitive
from sssbake.pipeline.render.renderer import Renderer, RenderLight, fit_camera
from sssbake.pipeline.techniques.lpv.calibrate import render_scales
from sssbake.pipeline.techniques.lpv.grid import LpvGridOptions, voxelise
from sssbake.pipeline.techniques.lpv.inject import inject, light_samples
from sssbake.pipeline.techniques.lpv.marble_field import MarbleOptions, marble_field
from sssbake.pipeline.techniques.lpv.matrices import propagation_matrices
from sssbake.pipeline.techniques.lpv.propagate import propagate, radiance

DIALECTS = ["glsl330", "essl300"]
MM = 10.0
MARBLE = preset("marble")


@pytest.fixture(scope="module")
def renderers():
    made = {d: Renderer((96, 96), d) for d in DIALECTS}
    yield made
    for r in made.values():
        r.release()


@pytest.fixture(scope="module")
def ball():
    """A veined marble ball of radius 20 mm in a 14-cell grid."""
    mesh = trimesh.creation.icosphere(subdivisions=4, radius=2.0)
    surface = weld_surface([Primitive(positions=np.asarray(mesh.vertices, float), faces=np.asarray(mesh.faces))], 1e-9)
    grid = voxelise(surface, MM, marble_field(MM, MarbleOptions(vein_mm=12.0, base=MARBLE)), MARBLE.eta,
                    LpvGridOptions(resolution=12))
    return surface, grid


def item_of(surface, grid, steps=6):
    return dict(positions=surface.positions, normals=surface.normals, faces=surface.faces, model=np.eye(4),
                eta=grid.eta, lpv=grid, lpv_matrices=propagation_matrices(), lpv_scales=render_scales(grid, 16, "montecarlo"),
                lpv_steps=steps, lpv_shadow_size=192)


@pytest.mark.parametrize("dialect", DIALECTS)
def test_gpu_propagation_equals_the_numpy_reference(renderers, ball, dialect):
    surface, grid = ball
    towards = np.array([0.4, 0.8, 0.45]) / np.linalg.norm([0.4, 0.8, 0.45])
    injected = inject(grid, light_samples(surface, MM, Light("directional", tuple(towards)), 192))
    expected, _ = propagate(grid, injected, 6)
    out = renderers[dialect].passes(item_of(surface, grid), RenderLight(False, tuple(towards), 1.0),
                                    given=injected[..., 0, :])
    # float32 on the GPU, float64 in numpy
    np.testing.assert_allclose(out["accumulated"], expected, rtol=0, atol=1e-5 * np.abs(expected).max())
    assert np.ptp(grid.sigma_t[grid.occupancy > 0][:, 0]) > 0  # the veins make it heterogeneous


@pytest.mark.parametrize("light", [Light("directional", (0.3, -0.5, 0.8)), Light("point", position=(5.0, 4.0, 6.0),
                                                                                   intensity=30.0)])
def test_gpu_injection_equals_the_numpy_reference(renderers, ball, light):
    surface, grid = ball
    render_light = (RenderLight(False, light.direction, light.intensity) if light.kind == "directional"
                    else RenderLight(True, light.position, light.intensity, MM))
    out = renderers["glsl330"].passes(item_of(surface, grid), render_light)
    expected = inject(grid, light_samples(surface, MM, light, 192))[..., 0, :]
    # the rasterised map and the cast rays see the same texel centres; a texel on the silhouette
    # (measured: 6e-5 of the largest cell) may fall either side of it
    np.testing.assert_allclose(out["injected"], expected, rtol=0, atol=2e-4 * np.abs(expected).max())
    np.testing.assert_allclose(out["injected"][..., 0].sum(), expected[..., 0].sum(), rtol=1e-5)
    assert expected[..., 0].sum() > 0


def test_the_final_draw_is_the_calibrated_radiance_through_the_exit_fresnel(renderers, ball):
    surface, grid = ball
    towards = (0.4, 0.8, 0.45)
    renderer = renderers["glsl330"]
    item = item_of(surface, grid)
    camera, light = fit_camera(surface.positions), RenderLight(False, towards, 1.0)
    image, mask = renderer.render([item], camera, light)
    # the numpy radiance at the vertices, drawn through the same exit Fresnel
    injected = inject(grid, light_samples(surface, MM, Light("directional", towards), 192))
    q = radiance(grid, propagate(grid, injected, 6)[0], surface.positions, surface.normals) * item["lpv_scales"][5]
    base = {k: v for k, v in item.items() if not k.startswith("lpv")}
    expected, same = renderer.render([{**base, "q": q}], camera, light)
    assert np.array_equal(mask, same)
    # per pixel against per vertex interpolated: equal on average, channel by channel
    np.testing.assert_allclose(image[mask].mean(axis=0), expected[mask].mean(axis=0), rtol=0.02)
    assert np.all(np.isfinite(image)) and image[mask].min() >= 0


def test_bad_lpv_items_are_refused(renderers, ball):
    surface, grid = ball
    item = item_of(surface, grid)
    light = RenderLight()
    camera = fit_camera(surface.positions)
    for change, needle in (({"lpv": "grid"}, "LpvGrid"), ({"lpv_matrices": np.eye(4)}, "lpv_matrices"),
                           ({"lpv_steps": 40}, "tabulated for 1..16")):
        with pytest.raises(ValueError, match=needle):
            renderers["glsl330"].render([{**item, **change}], camera, light)
