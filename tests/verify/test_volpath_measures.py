"""The three readings of volpath's comparison (pixel, block, vertex) and their noise floors."""

import numpy as np
import trimesh

from sssbake.pipeline.render.renderer import Renderer, RenderLight, fit_camera
from sssbake.pipeline.verify.volpath_measures import block_reading, measure, pixel_reading, vertex_reading


def noisy_halves(truth: np.ndarray, sigma: float, seed: int = 3) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return truth[None] + rng.normal(0.0, sigma, (2, *truth.shape))


def test_block_reading_averages_the_covered_pixels_of_each_tile():
    mask = np.zeros((16, 16), dtype=bool)
    mask[0:8, 0:8] = True           # a whole tile
    mask[8:16, 0:4] = True          # exactly half a tile: kept
    mask[0:3, 8:16] = True          # 24 of 64: dropped
    image = np.random.default_rng(0).random((16, 16, 3))
    reading = block_reading(mask, 8)
    got = reading(image)
    assert got.shape == (2, 3)
    assert np.allclose(got[0], image[0:8, 0:8].reshape(-1, 3).mean(axis=0))
    assert np.allclose(got[1], image[8:16, 0:4].reshape(-1, 3).mean(axis=0))
    assert pixel_reading(mask)(image).shape == (int(mask.sum()), 3)


def test_floor_is_what_a_perfect_image_scores_and_blocks_average_noise_away():
    """The noise floor ||A - B|| / (2 ||T||) estimates the truth's own error: a perfect image's
    error against T is the floor (within sampling), and 8 × 8 blocks cut white noise 8-fold."""
    size = 128
    mask = np.zeros((size, size), dtype=bool)
    mask[16:112, 16:112] = True
    clean = np.ones((size, size, 3))
    halves = noisy_halves(clean, 0.2)
    for reading, shrink in ((pixel_reading(mask), 1.0), (block_reading(mask, 8), 8.0)):
        m = measure(reading, {"perfect": clean, "dark": 0.8 * clean}, halves)
        expected = 0.2 / np.sqrt(2.0) / shrink  # the mean of two halves of σ 0.2, averaged over shrink² pixels
        assert abs(m["noise_floor"] / expected - 1.0) < 0.1, reading.name
        assert abs(m["rmse_relative"]["perfect"] / m["noise_floor"] - 1.0) < 0.1
        assert m["rmse_relative_denoised"]["perfect"] < 0.5 * m["noise_floor"]
        assert abs(m["rmse_relative_denoised"]["dark"] - 0.2) < 0.02  # a 20 % level error survives the noise


def test_vertex_reading_picks_the_pixels_of_the_vertices_the_camera_sees():
    """A sphere drawn with each vertex's own position as its colour: every sample the reading
    takes holds the position of its vertex (rows in vertex order, a flipped or shifted pixel would
    hold another's), the hidden half is never read and most of the near half is."""
    sphere = trimesh.creation.icosphere(subdivisions=3, radius=10.0)
    positions, faces = np.asarray(sphere.vertices), np.asarray(sphere.faces)
    normals = np.asarray(sphere.vertex_normals)
    camera = fit_camera(positions)
    item = {"positions": positions, "normals": normals, "faces": faces, "model": np.eye(4), "eta": 1.0,
            "q": positions + 20.0}  # positive: the renderer's float target keeps it as it is
    image, covered = Renderer((256, 256)).render([item], camera, RenderLight(False, (0.0, 0.0, 1.0), 1.0))
    seen = vertex_reading([(positions, faces, normals)], camera, covered)(image.astype(np.float64)) - 20.0
    facing = np.flatnonzero(np.einsum("ij,ij->i", normals, np.asarray(camera.eye) - positions) > 0)
    assert 0.8 * len(facing) < len(seen) <= len(facing)
    # Each sample holds a vertex's position: within a pixel (0.12 mm) of one where the surface faces
    # the camera (a pixel read elsewhere holds a point between vertices, which lie 1.9 mm apart);
    # at the grazing rim one pixel spans more of the surface.
    nearest = np.linalg.norm(seen[:, None, :] - positions[None, facing, :], axis=2)
    vertex = facing[nearest.argmin(axis=1)]
    towards = np.asarray(camera.eye) - positions[vertex]
    facing_well = np.einsum("ij,ij->i", normals[vertex], towards / np.linalg.norm(towards, axis=1, keepdims=True)) > 0.5
    assert facing_well.sum() > 0.4 * len(seen)
    assert nearest.min(axis=1)[facing_well].max() < 0.2
    assert len(np.unique(vertex[facing_well])) == facing_well.sum()  # one sample per vertex
