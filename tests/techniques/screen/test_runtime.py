"""The screen runtime on the GPU: its G-buffer holds the closed-form irradiance, its gather over a
flat half-lit plane reproduces the dipole's edge profile integrated in numpy, a uniformly lit plane
gives R_d, and missing surface is reported and filled."""

import dataclasses

import numpy as np
import pytest
from scipy.integrate import quad

from sssbake.pipeline.core.profile import profile_for, Profile, diffuse_reflectance_profile, profile_total
from sssbake.pipeline.core.fresnel import fresnel_transmittance
from sssbake.pipeline.core.materials import preset
from sssbake.pipeline.render.renderer import Renderer, RenderLight, fit_camera
from sssbake.pipeline.techniques.screen.data import table_total
from sssbake.pipeline.techniques.screen.runtime import ScreenRuntimeOptions
from sssbake.pipeline.techniques.screen.samples import ScreenSamplesOptions, screen_samples

DIALECTS = ["glsl330", "essl300"]
SKIN = preset("skin1")
#: Half-width of the test plane, mm: beyond skin1's table reach (28.5 mm) from the strip tested.
HALF = 34.0
STRIP = 3.0


@pytest.fixture(scope="module")
def renderers():
    made = {d: Renderer((384, 384), d, shadow_size=256) for d in DIALECTS}
    yield made
    for r in made.values():
        r.release()


def plane_item(samples, runtime=ScreenRuntimeOptions(), mm_per_unit=2.0, model=np.eye(4)):
    """A square of side 2 HALF mm on z = 0 (normal +z), in units of `mm_per_unit` mm."""
    h = HALF / mm_per_unit
    positions = np.array([[-h, -h, 0], [h, -h, 0], [h, h, 0], [-h, h, 0]], float)
    return dict(positions=positions, normals=np.tile([0.0, 0, 1], (4, 1)), faces=np.array([[0, 1, 2], [0, 2, 3]]),
                model=model, eta=SKIN.eta, screen=samples, mm_per_unit=mm_per_unit, screen_runtime=runtime)


def top_camera(item):
    world = item["positions"] @ item["model"][:3, :3].T + item["model"][:3, 3]
    return fit_camera(world, view_dir=(0.0, 0.0, -1.0))


def edge_profile(s: float, params: Profile, total: np.ndarray) -> np.ndarray:
    """(3,) B at signed distance `s` (mm) from the edge of a half-plane of unit E (s > 0: dark side):
    the lit part of the circle of radius r is 2 arccos(|s| / r) of it."""
    def dark(c, a):
        f = lambda r: diffuse_reflectance_profile(np.array([r]), params)[0, c] * 2.0 * r * np.arccos(a / r)
        return quad(f, a, np.inf, limit=400)[0] if a > 0 else total[c] / 2.0
    out = np.array([dark(c, abs(s)) for c in range(3)])
    return out if s >= 0 else total - out


@pytest.mark.parametrize("dialect", DIALECTS)
def test_gather_over_a_half_lit_plane_reproduces_the_edge_profile(renderers, dialect):
    renderer = renderers[dialect]
    params = profile_for(SKIN)
    total = profile_total(params)
    samples = screen_samples(SKIN, ScreenSamplesOptions(samples=768, uniform=32))
    # fill off: every sample lands on the plane, so this is the plain balance-heuristic estimate
    item = plane_item(samples, ScreenRuntimeOptions(fill=False, resolve=False))
    camera, light = top_camera(item), RenderLight(False, (0.0, 0.0, 1.0), 1.0)
    first = renderer.passes(item, light, camera)
    x_mm = first["position"][..., 0] * item["mm_per_unit"]
    lit = np.where(first["covered"], (x_mm < 0).astype(float), 0.0)
    out = renderer.passes(item, light, camera, given=lit)
    y_mm = out["position"][..., 1] * item["mm_per_unit"]
    near = out["covered"] & (np.abs(x_mm) < STRIP) & (np.abs(y_mm) < 6.0)
    columns = np.unique(np.round(x_mm[near] / 0.5).astype(int))
    assert len(columns) >= 11
    for col in columns:
        sel = near & (np.round(x_mm / 0.5).astype(int) == col)
        got = out["scattered"][sel].mean(axis=0)
        want = edge_profile(float(x_mm[sel].mean()), params, total)
        # 1 % of each channel's R_d: the quadrature error of 800 radii (rotations average over
        # angle, not radius) and of reading r at pixel centres (0.28 mm)
        assert np.all(np.abs(got - want) <= 0.01 * total), (x_mm[sel].mean(), got, want)
    # the profile falls across the edge in every channel, from ~R_d to ~0 far off
    assert np.all(edge_profile(-STRIP, params, total) > edge_profile(STRIP, params, total))


def test_uniform_light_on_a_plane_gives_total_diffuse_reflectance(renderers):
    renderer = renderers["glsl330"]
    params = profile_for(SKIN)
    total = profile_total(params)
    samples = screen_samples(SKIN)  # the defaults: N = 32, U = 8
    light = RenderLight(False, (0.0, 0.0, 1.0), 1.0)
    for fill, rtol in ((True, 1e-3), (False, 0.1)):
        item = plane_item(samples, ScreenRuntimeOptions(fill=fill))
        out = renderer.passes(item, light, top_camera(item))
        e = fresnel_transmittance(SKIN.eta, 1.0) / np.pi
        x, y = (out["position"][..., k] * item["mm_per_unit"] for k in (0, 1))
        centre = out["covered"] & (np.hypot(x, y) < 3.0)
        np.testing.assert_allclose(out["irradiance"][centre], e, rtol=1e-5)
        # with fill the ratio estimator is exact under uniform light; without, the 40 samples'
        # estimate of R_d is off by their quadrature error
        np.testing.assert_allclose(out["scattered"][centre].mean(axis=0), e * total, rtol=rtol)
    # the gather finds all of Rd's integral inside, and misses surface near the plane's border
    assert np.min(out["share"][centre]) > 0.7
    border = out["covered"] & (np.maximum(np.abs(x), np.abs(y)) > HALF - 0.5)
    assert np.max(out["share"][border]) < 0.75


def test_jacobian_is_one_on_a_plane_and_the_scale_is_in_mm(renderers):
    renderer = renderers["glsl330"]
    samples = screen_samples(SKIN, ScreenSamplesOptions(samples=24, uniform=4))
    light = RenderLight(False, (0.3, 0.2, 1.0), 1.0)
    # the same plane in other units and under a rotation with a uniform scale gives the same B
    model = np.eye(4)
    model[:3, :3] = 1.7 * np.array([[0.0, -1, 0], [1, 0, 0], [0, 0, 1]])
    results = []
    for mm, m, jacobian in ((2.0, np.eye(4), False), (2.0, np.eye(4), True), (0.5, model, False)):
        item = plane_item(samples, ScreenRuntimeOptions(jacobian=jacobian, fill=False), mm_per_unit=mm, model=m)
        out = renderer.passes(item, light, top_camera(item))
        world = out["position"] * mm / abs(np.linalg.det(m[:3, :3])) ** (1 / 3)
        centre = out["covered"] & (np.hypot(world[..., 0], world[..., 1]) < 5.0)
        results.append(out["scattered"][centre].mean(axis=0))
    np.testing.assert_allclose(results[1], results[0], rtol=1e-4)
    np.testing.assert_allclose(results[2], results[0], rtol=2e-3)


def test_final_draw_is_the_gather_times_the_exit_fresnel(renderers):
    renderer = renderers["glsl330"]
    samples = screen_samples(SKIN, ScreenSamplesOptions(samples=16, uniform=4))
    item = plane_item(samples)
    camera, light = top_camera(item), RenderLight(False, (0.2, -0.3, 1.0), 2.0)
    passes = renderer.passes(item, light, camera)
    image, mask = renderer.render([item], camera, light)
    assert np.array_equal(mask, passes["covered"])
    view = np.asarray(camera.eye) - passes["position"]
    cos_o = view[..., 2] / np.linalg.norm(view, axis=-1)
    expected = passes["scattered"] * fresnel_transmittance(SKIN.eta, cos_o)[..., None]
    np.testing.assert_allclose(image[mask], expected[mask], rtol=1e-4, atol=1e-7)


def test_interleaving_turns_the_pattern_per_pixel(renderers):
    renderer = renderers["glsl330"]
    samples = screen_samples(SKIN, ScreenSamplesOptions(samples=16, uniform=4))
    item = plane_item(samples)
    camera, light = top_camera(item), RenderLight(False, (0.0, 0.0, 1.0), 1.0)
    first = renderer.passes(item, light, camera)
    lit = np.where(first["covered"] & (first["position"][..., 0] < 0), 1.0, 0.0)
    # along the edge every pixel has the same exact B: one pattern gives it each time, the
    # interleaved rotations scatter the estimates around it
    column = np.argmin(np.abs(first["position"][192, :, 0] * item["mm_per_unit"] - 0.5))
    spread = {}
    for interleave in (1, 4):
        runtime = ScreenRuntimeOptions(interleave=interleave, resolve=False)
        out = renderer.passes(plane_item(samples, runtime), light, camera, given=lit)
        along = out["scattered"][180:204, column, 0]
        spread[interleave] = np.ptp(along) / along.mean()
    # (float32 rounding of the positions alone moves the first by ~3e-5; the rotations by ~60 %)
    assert spread[1] < 1e-4 and spread[4] > 0.1


def test_resolve_averages_the_tile_window_without_crossing_discontinuities(renderers):
    renderer = renderers["glsl330"]
    samples = screen_samples(SKIN, ScreenSamplesOptions(samples=8, uniform=2))
    # the plane, and a step 10 mm up over x > 0: pixels across its edge are far apart in 3-D
    item = plane_item(samples)
    step = item["positions"][[1, 2]].copy()
    top = np.vstack([step * [0, 1, 1], step]) + [0, 0, 5.0]
    item = {**item, "positions": np.vstack([item["positions"], top]), "normals": np.tile([0.0, 0, 1], (8, 1)),
            "faces": np.vstack([item["faces"], [[4, 6, 7], [4, 7, 5]]])}
    camera, light = top_camera(item), RenderLight(False, (0.3, 0.4, 1.0), 1.0)
    first = renderer.passes(item, light, camera)
    lit = np.where(first["covered"] & (np.hypot(*first["position"][..., :2].transpose(2, 0, 1)) < 8.0), 1.0, 0.0)
    raw = renderer.passes({**item, "screen_runtime": ScreenRuntimeOptions(resolve=False)}, light, camera,
                          given=lit)
    resolved = renderer.passes(item, light, camera, given=lit)
    # numpy: the mean of the 4 x 4 window (offsets -1..2) over covered neighbours within the
    # widest channel's median radius that face the same way
    h, w = lit.shape
    mm = item["mm_per_unit"]
    expected = np.zeros_like(raw["scattered"])
    rows, cols = np.nonzero(raw["covered"][::-1])  # GL rows: the window runs upwards in the image
    flip = lambda a: a[::-1]
    b, p, c = flip(raw["scattered"]), flip(raw["position"]), flip(raw["covered"])
    for y, x in zip(rows, cols):
        ys, xs = np.clip(np.arange(y - 1, y + 3), 0, h - 1), np.clip(np.arange(x - 1, x + 3), 0, w - 1)
        yy, xx = np.meshgrid(ys, xs, indexing="ij")
        near = c[yy, xx] & (np.linalg.norm(p[yy, xx] - p[y, x], axis=-1) * mm <= samples.uniform_radius_mm)
        expected[h - 1 - y, x] = b[yy, xx][near].mean(axis=0)
    np.testing.assert_allclose(resolved["scattered"], expected, rtol=1e-5, atol=1e-7)
    # and it differs from the raw gather: it did average
    assert np.abs(resolved["scattered"] - raw["scattered"]).max() > 1e-3 * raw["scattered"].max()


def test_table_total_is_the_closed_form_reflectance():
    for name in ("skin1", "marble", "ketchup", "skimmilk"):
        material = preset(name)
        params = profile_for(material)
        samples = screen_samples(material)
        # the table stops where 1 - 1e-4 of R_d is inside and interpolates within 1e-3
        np.testing.assert_allclose(table_total(samples), profile_total(params),
                                   rtol=1.5e-3)


def test_bad_screen_items_are_refused(renderers):
    renderer = renderers["glsl330"]
    samples = screen_samples(SKIN, ScreenSamplesOptions(samples=8, uniform=0))
    item = plane_item(samples)
    camera, light = top_camera(item), RenderLight()
    for change, needle in (({"mm_per_unit": 0.0}, "mm_per_unit > 0"), ({"screen": "tables"}, "ScreenSamples"),
                           ({"screen": dataclasses.replace(samples, weights=samples.weights[:3])}, "weights"),
                           ({"screen_runtime": ScreenRuntimeOptions(interleave=0)}, "interleave")):
        with pytest.raises(ValueError, match=needle):
            renderer.render([{**item, **change}], camera, light)
