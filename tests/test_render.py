"""The reference runtime renders closed-form radiance, the same in both GLSL dialects."""

import numpy as np
import pytest
import trimesh

from sssbake.pipeline.fresnel import fresnel_transmittance
from sssbake.pipeline.render import Renderer, RenderLight, fit_camera

QUAD = (np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], float), np.array([[0, 1, 2], [0, 2, 3]]))


@pytest.mark.parametrize("dialect", ["glsl330", "essl300"])
def test_constant_radiance_leaves_through_the_exit_fresnel(dialect):
    v, f = QUAD
    item = dict(positions=v, normals=np.tile([0, 0, 1.0], (4, 1)), faces=f, model=np.eye(4), eta=1.3,
                q=np.tile([0.2, 0.4, 0.6], (4, 1)))
    camera = fit_camera(v, view_dir=(0, 0, -1))
    image, mask = Renderer((64, 64), dialect).render([item], camera, RenderLight())
    # the centre pixel looks straight down the normal
    np.testing.assert_allclose(image[32, 32], np.array([0.2, 0.4, 0.6]) * fresnel_transmittance(1.3, 1.0), rtol=1e-5)
    assert mask[32, 32] and not mask[0, 0]


def test_sphere_coverage_matches_its_silhouette():
    s = trimesh.creation.icosphere(subdivisions=4)
    v, f = np.asarray(s.vertices), np.asarray(s.faces)
    camera = fit_camera(v, view_dir=(0, 0, -1), fov_degrees=30)
    item = dict(positions=v, normals=v, faces=f, model=np.eye(4), eta=1.3, q=np.ones((len(v), 3)))
    _, mask = Renderer((128, 128)).render([item], camera, RenderLight())
    # the bounding sphere fills sin(15°)·1.05 of the frame's half-height... projected: a disc of
    # radius tan(asin(1/d))/tan(15°) of the half-width, d the eye distance
    d = np.linalg.norm(np.asarray(camera.eye))
    r = np.tan(np.arcsin(1.0 / d)) / np.tan(np.radians(15.0))
    assert mask.mean() == pytest.approx(np.pi * r * r / 4.0, rel=0.03)


def test_frame_time_is_measured():
    v, f = QUAD
    item = dict(positions=v, normals=np.tile([0, 0, 1.0], (4, 1)), faces=f, model=np.eye(4), eta=1.3, q=np.ones((4, 3)))
    ms = Renderer((32, 32)).frame_ms([item], fit_camera(v, view_dir=(0, 0, -1)), RenderLight(), frames=3)
    assert 0.0 < ms < 1000.0
