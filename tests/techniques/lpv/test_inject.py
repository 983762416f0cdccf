"""lpv injection: the shadow map's texels carry the flux a light sends through them (closed forms for
a directional light on a square and a point light on a ball), enter refracted by Snell's law, and
land in the cells they hit."""

import numpy as np
import pytest
import trimesh

from sssbake.pipeline.core.fresnel import fresnel_transmittance
from sssbake.pipeline.core.reference import Light
from sssbake.pipeline.mesh.clean import weld_surface
from sssbake.pipeline.mesh.scene import Primitive
from sssbake.pipeline.techniques.lpv.data import LpvGrid
from sssbake.pipeline.techniques.lpv.inject import inject, light_samples, refracted


def surface_of(mesh):
    return weld_surface([Primitive(positions=np.asarray(mesh.vertices, float), faces=np.asarray(mesh.faces))], 1e-9)


def test_a_directional_light_sends_irradiance_times_the_projected_area():
    box = trimesh.creation.box(extents=(4.0, 4.0, 1.0))  # units of 2 mm
    surface = surface_of(box)
    towards = np.array([0.3, 0.0, 1.0]) / np.linalg.norm([0.3, 0.0, 1.0])
    samples = light_samples(surface, 2.0, Light("directional", tuple(towards), intensity=1.5), size=512)
    # the box's projected area: top 16 cos θ plus the side facing the light 4 sin θ (mm²: x 4)
    projected = (16.0 * towards[2] + 4.0 * towards[0]) * 4.0
    np.testing.assert_allclose(samples.flux.sum(), 1.5 * projected, rtol=5e-3)
    np.testing.assert_allclose(samples.towards, np.broadcast_to(towards, samples.towards.shape), atol=1e-12)
    # the texels split between the top and the lit side as their projected areas do
    top = np.isclose(samples.positions[:, 2], 0.5)
    np.testing.assert_allclose(samples.flux[top].sum() / samples.flux.sum(), 64 * towards[2] / projected, rtol=5e-3)


def test_a_point_light_sends_intensity_times_the_solid_angle():
    ball = trimesh.creation.icosphere(subdivisions=5, radius=1.0)
    surface = surface_of(ball)
    distance = 3.0
    samples = light_samples(surface, 1.0, Light("point", position=(0.0, 0.0, distance), intensity=2.0), size=512)
    # the ball subtends 2π (1 - √(1 - (R/D)²)) from the light (the icosphere is slightly smaller)
    solid = 2 * np.pi * (1 - np.sqrt(1 - (1.0 / distance) ** 2))
    np.testing.assert_allclose(samples.flux.sum(), 2.0 * solid, rtol=0.01)
    expected = np.array([0, 0, distance]) - samples.positions
    np.testing.assert_allclose(samples.towards, expected / np.linalg.norm(expected, axis=1)[:, None], atol=1e-9)


def test_refraction_follows_snell():
    normal = np.array([[0.0, 0.0, 1.0]])
    for angle in (0.0, 0.4, 1.2, np.pi / 2):
        towards = np.array([[np.sin(angle), 0.0, np.cos(angle)]])
        t = refracted(towards, normal, 1.4)[0]
        np.testing.assert_allclose(np.linalg.norm(t), 1.0, rtol=1e-12)
        assert t[2] < 0 and t[0] <= 0  # into the medium, on the far side of the normal
        np.testing.assert_allclose(np.hypot(t[0], t[1]), np.sin(angle) / 1.4, atol=1e-12)


def test_injection_puts_the_transmitted_lobe_in_the_sample_s_cell():
    grid = LpvGrid(origin=np.zeros(3), cell=1.0, mm_per_unit=1.0, occupancy=np.ones((3, 3, 3), np.float32),
                   sigma_t=np.ones((3, 3, 3, 3), np.float32), albedo=np.full((3, 3, 3, 3), 0.9, np.float32),
                   g=np.zeros((3, 3, 3, 3), np.float32), eta=1.5)
    from sssbake.pipeline.techniques.lpv.inject import LightSamples

    towards = np.array([[0.6, 0.0, 0.8], [0.0, 0.0, 1.0]])
    samples = LightSamples(positions=np.array([[1.5, 0.5, 2.9], [1.2, 0.7, 2.95]]), normals=np.array([[0, 0, 1.0]] * 2),
                           towards=towards, flux=np.array([2.0, 1.0]))
    out = inject(grid, samples)
    assert np.count_nonzero(out.any(axis=(3, 4))) == 1  # both in cell (1, 0, 2)
    c = out[2, 0, 1, 0]
    transmitted = fresnel_transmittance(1.5, np.array([0.8, 1.0])) * samples.flux
    np.testing.assert_allclose(c[0] * np.sqrt(4 * np.pi), transmitted.sum(), rtol=1e-12)  # flux of the lobes
    # band 1: (2/3) √(3/4π) Σ T Φ ω_t, basis order (y, z, x)
    omega = refracted(towards, samples.normals, 1.5)
    band = 2 / 3 * np.sqrt(3 / (4 * np.pi)) * (transmitted[:, None] * omega).sum(axis=0)
    np.testing.assert_allclose(c[1:], band[[1, 2, 0]], rtol=1e-12)
    np.testing.assert_array_equal(out[..., 0, :], out[..., 2, :])  # white light
    with pytest.raises(ValueError, match="shadow map size"):
        light_samples(surface_of(trimesh.creation.box()), 1.0, Light(), size=0)
