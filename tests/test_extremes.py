"""Stability at the extremes, by property tests (hypothesis) across the techniques' precomputes:
materials over the whole valid range (α' from 0 to 1, σ_tr towards 0, η from 1 to 2), scales from
1e-3 to 1e4 mm per unit: outputs finite, non-negative and within the R_d energy bound."""

import re
from dataclasses import replace

import numpy as np
import pytest
import trimesh
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from sssbake.pipeline.core.profile import diffuse_reflectance_profile, disc_integral, profile_for, profile_total, total_reflectance
from sssbake.pipeline.core.materials import Material
from sssbake.pipeline.core.naive_normals import naive_normals
from sssbake.pipeline.core.scatter_operator import SCATTER_DEFAULTS, scatter_operator
from sssbake.pipeline.mesh.clean import weld_surface
from sssbake.pipeline.mesh.scene import Primitive
from sssbake.pipeline.techniques.lpv.calibrate import render_scales
from sssbake.pipeline.techniques.lpv.grid import LpvGridOptions, homogeneous, voxelise
from sssbake.pipeline.techniques.lpv.propagate import transport_factors
from sssbake.pipeline.techniques.screen.data import table_total
from sssbake.pipeline.techniques.screen.samples import ScreenSamplesOptions, screen_samples
from sssbake.pipeline.techniques.spectral.precompute import naive_parameters

#: Coefficients in 1/mm, log-uniform over eight decades of the valid range.
coefficient = st.floats(-4.0, 3.0).map(lambda e: float(10.0**e))
absorption = st.one_of(st.just(0.0), st.floats(-6.0, 2.0).map(lambda e: float(10.0**e)))
channel = st.tuples(coefficient, absorption)
materials = st.builds(lambda r, g, b, eta: Material("extreme", (r[0], g[0], b[0]), (r[1], g[1], b[1]), eta),
                      channel, channel, channel, st.floats(1.0, 2.0))
scales = st.floats(-3.0, 4.0).map(lambda e: float(10.0**e))
FAST = settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])


def small_ball():
    mesh = trimesh.creation.icosphere(subdivisions=1, radius=1.0)
    return weld_surface([Primitive(positions=np.asarray(mesh.vertices, float), faces=np.asarray(mesh.faces))], 1e-9)


@pytest.mark.parametrize("model", ["montecarlo", "dipole"])
@FAST
@given(material=materials)
def test_the_profile_stays_finite_and_within_its_energy(material, model):
    p = profile_for(replace(material, profile=model))
    light = total_reflectance(p)  # what leaves: at most what came in
    assert np.all(np.isfinite(light)) and np.all(light >= 0) and np.all(light <= 1.0 + 1e-12)
    total = profile_total(p)
    r = np.concatenate([[0.0], np.geomspace(1e-6, 1e6, 40)])
    profile = diffuse_reflectance_profile(r, p)
    assert np.all(np.isfinite(profile)) and np.all(profile >= 0)
    inside = np.stack([disc_integral(np.full(3, a), p).diagonal() for a in r])
    assert np.all(np.isfinite(inside)) and np.all(inside >= -1e-12)
    assert np.all(inside <= total * (1 + 1e-9) + 1e-300)
    assert np.all(np.diff(inside, axis=0) >= -1e-12 * np.maximum(total, 1e-300))  # grows with the disc


@FAST
@given(materials)
def test_screen_tables_are_finite_and_hold_the_reflectance(material):
    try:
        samples = screen_samples(material, ScreenSamplesOptions(samples=9, uniform=3, table_error=0.05))
    except ValueError as error:
        # one table on r = R t² cannot span channels many decades apart (a channel without
        # absorption reaches metres, one that absorbs strongly lives within microns)
        message = str(error)
        assert message.startswith("screen: the channels' profiles span") and "\n" not in message
        reach, narrowest = (float(v) for v in re.findall(r"([0-9.e+-]+) mm", message)[:2])
        assert reach / narrowest > 1e4, message
        return
    samples.check()
    p = profile_for(material)
    total = profile_total(p)
    integrated = table_total(samples)
    assert np.all(np.isfinite(integrated)) and np.all(integrated <= total * 1.06 + 1e-12)
    # where there is reflectance to speak of, the table holds it
    big = total > 1e-6
    np.testing.assert_allclose(integrated[big], total[big], rtol=0.06)


@FAST
@given(materials, scales)
def test_prt_scattering_is_finite_and_within_the_energy_bound(material, mm):
    surface = small_ball()
    p = profile_for(material)
    operator = scatter_operator(surface.positions * mm, surface.faces, surface.normals, p, SCATTER_DEFAULTS)
    out = operator.apply(np.ones((len(surface.positions), 1)))[:, :, 0]  # unit entering irradiance
    total = profile_total(p)
    assert np.all(np.isfinite(out)) and np.all(out >= 0)
    # no vertex gathers more than R_d from uniform light (sources are capped at R_d, and the ball
    # has no more surface around a vertex than a plane would give it... to the quadrature's error)
    assert np.all(out <= total[:, None] * 1.05 + 1e-12)


@FAST
@given(materials, scales)
def test_lpv_grids_transport_and_scales_are_finite(material, mm):
    surface = small_ball()
    grid = voxelise(surface, mm, homogeneous(material), material.eta, LpvGridOptions(resolution=6, supersample=2))
    grid.check()
    scatter, attenuation = transport_factors(grid)
    assert np.all((scatter >= 0) & (scatter <= 1)) and np.all((attenuation >= 0) & (attenuation <= 1))
    scales_ = render_scales(grid, 4, "montecarlo")
    assert np.all(np.isfinite(scales_)) and np.all(scales_ > 0)


@FAST
@given(materials, scales)
def test_naive_normals_stay_unit(material, mm):
    surface = small_ball()
    sigma_tr, radius = naive_parameters(material)
    out = naive_normals(surface.positions * mm, surface.normals, sigma_tr, 0.5, radius)
    assert np.all(np.isfinite(out))
    np.testing.assert_allclose(np.linalg.norm(out, axis=1), 1.0, rtol=1e-9)
