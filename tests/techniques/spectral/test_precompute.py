import numpy as np
import pytest
import trimesh

from sssbake.pipeline.core.profile import disc_integral, profile_for, profile_total, radius_holding
from sssbake.pipeline.core.materials import Material, preset
from sssbake.pipeline.mesh.clean import weld_surface
from sssbake.pipeline.mesh.scene import Primitive
from sssbake.pipeline.techniques.spectral.precompute import (
    SpectralPrecomputeOptions,
    channel_weights,
    precompute_spectral,
)


def _surface(mesh):
    x, f = np.asarray(mesh.vertices, float), np.asarray(mesh.faces, np.int64)
    prim = Primitive(positions=x, faces=f, normals=np.asarray(mesh.vertex_normals, float), uvs=(), material=None)
    return weld_surface([prim], 1e-9)


@pytest.mark.parametrize("name", ["skin1", "marble"])
def test_radius_holding_holds_the_asked_share_of_r_d(name):
    p = profile_for(preset(name))
    total = profile_total(p)
    for energy in (0.5, 0.95):
        r = radius_holding(p, energy)
        assert np.allclose(np.diagonal(disc_integral(r, p)), energy * total, rtol=1e-9)
    assert np.isclose(channel_weights(p).sum(), 1.0)


def test_no_absorption_still_gives_finite_lengths():
    clear = Material("clear", (1.0, 1.0, 1.0), (0.0, 0.0, 0.0), 1.3)
    r = radius_holding(profile_for(clear), 0.95)
    assert np.all(np.isfinite(r)) and np.all(r > 0)


def test_defaults_follow_the_material_and_scale():
    s = _surface(trimesh.creation.icosphere(subdivisions=3, radius=1.0))
    skin = precompute_spectral(s, 20.0, preset("skin1"), SpectralPrecomputeOptions(eigenpairs=40))
    p = profile_for(preset("skin1"))
    assert skin.width_mm == pytest.approx(channel_weights(p) @ radius_holding(p, 0.5) / np.sqrt(2 * np.log(2)))
    assert np.allclose(np.linalg.norm(skin.normals, axis=1), 1.0)
    # a sphere's normals are an l = 1 harmonic: the filter keeps their direction
    assert np.einsum("ij,ij->i", skin.normals, s.normals).min() > 0.999
    assert skin.stats["eigenpairs"] == 40 and 0 < skin.gamma < 1


def test_filter_smooths_a_cube_and_the_width_matters():
    s = _surface(trimesh.creation.box(extents=(1.0, 1.0, 1.0)).subdivide().subdivide().subdivide())
    tilt = []
    for width in (0.5, 2.0, 8.0):
        pre = precompute_spectral(s, 10.0, preset("marble"), SpectralPrecomputeOptions(eigenpairs=60, width_mm=width))
        tilt.append(np.degrees(np.arccos(np.clip(np.einsum("ij,ij->i", pre.normals, s.normals), -1, 1))).mean())
        assert np.all(np.isfinite(pre.normals))
    assert tilt[0] < tilt[1] < tilt[2]  # a wider filter bends the normals further from the faces'


@pytest.mark.parametrize("field, value", [("eigenpairs", 0), ("width_mm", -1.0), ("width_mm", float("inf"))])
def test_bad_options_raise_one_line_errors(field, value):
    with pytest.raises(ValueError, match=f"spectral: {field}"):
        SpectralPrecomputeOptions(**{field: value}).check()


def test_open_meshes_and_several_components():
    # a flat open sheet (boundary vertices, Neumann) beside a closed sphere: the sheet's constant
    # normal is untouched, the sphere's stay radial, and the two do not mix
    from fixtures import plane

    x, f, _ = plane(0.1, 12)
    sphere = trimesh.creation.icosphere(subdivisions=3, radius=0.5)
    sv = np.asarray(sphere.vertices) + [0.0, 0.0, 5.0]
    prim = Primitive(positions=np.r_[x, sv], faces=np.r_[f, np.asarray(sphere.faces) + len(x)],
                     normals=np.r_[np.tile([0.0, 0.0, 1.0], (len(x), 1)), np.asarray(sphere.vertex_normals)],
                     uvs=(), material=None)
    s = weld_surface([prim], 1e-9)
    pre = precompute_spectral(s, 10.0, preset("marble"), SpectralPrecomputeOptions(eigenpairs=50))
    sheet, ball = s.weld[0][: len(x)], s.weld[0][len(x):]
    assert np.abs(pre.normals[sheet] - [0.0, 0.0, 1.0]).max() < 1e-9
    assert np.einsum("ij,ij->i", pre.normals[ball], s.normals[ball]).min() > 0.999


def test_nyquist_frequency_of_a_regular_grid():
    from fixtures import plane

    from sssbake.pipeline.techniques.spectral.precompute import nyquist_frequency

    x, f, _ = plane(0.5, 3)
    assert nyquist_frequency(x, f) == pytest.approx(np.pi / (0.5 * (2 + np.sqrt(2)) / 3))
