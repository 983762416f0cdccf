"""Relative errors against volpath's truth read three ways: per pixel, per block of pixels and per
visible vertex, each with the truth's own noise floor.

A reading (`Reading`) is a sparse (k, H·W) matrix S: a sample is a weighted sum of pixels. Per
pixel, S picks the object's pixels; per block, each row averages the object's pixels of one
`BLOCK` × `BLOCK` tile that the object covers at least half of (Monte Carlo noise falls with the
pixels averaged, the low frequencies a technique gets wrong stay); per vertex, each row picks the
pixel a vertex the camera sees projects into (a vertex-density weighting, what a per-vertex
export is judged by). For any reading, with the truth's halves A, B and mean T,

    error(image) = ||S image - S T|| / ||S T||,    floor = ||S A - S B|| / (2 ||S T||),

the floor being the error a perfect image would score (Var T = Var A / 2 and E||A - B||² = 2
E||A - E A||²); sqrt(error² - floor²) is the error without the truth's noise.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import sparse

from sssbake.pipeline.core.visibility import point_visibility
from sssbake.pipeline.render.renderer import Camera

#: Side of a block, pixels.
BLOCK = 8


@dataclass(frozen=True, eq=False)
class Reading:
    """Attributes
    ----------
    name : str
        ``pixel``, ``block`` or ``vertex``.
    matrix : (k, H·W) scipy.sparse.csr_matrix
        Each row one sample's weights over the row-major pixels.
    """

    name: str
    matrix: sparse.csr_matrix

    def __call__(self, image: np.ndarray) -> np.ndarray:
        """(k, 3) the samples of an (H, W, 3) image."""
        return np.asarray(self.matrix @ image.reshape(-1, image.shape[-1]), dtype=np.float64)


def pixel_reading(mask: np.ndarray) -> Reading:
    """Every pixel of the (H, W) bool `mask`."""
    index = np.flatnonzero(mask)
    return Reading("pixel", _picks(index, mask.size))


def block_reading(mask: np.ndarray, block: int = BLOCK) -> Reading:
    """The mean over `mask`'s pixels of each `block`² tile that holds at least half a tile of them
    (a tile cut by the image's edge counts the pixels it has)."""
    h, w = mask.shape
    rows, cols = np.nonzero(mask)
    tile = (rows // block) * (-(-w // block)) + cols // block
    counts = np.bincount(tile, minlength=(-(-h // block)) * (-(-w // block)))
    kept = np.flatnonzero(counts * 2 >= block * block)
    order = np.full(len(counts), -1)
    order[kept] = np.arange(len(kept))
    inside = order[tile] >= 0
    weights = 1.0 / counts[tile[inside]]
    matrix = sparse.csr_matrix((weights, (order[tile[inside]], (rows * w + cols)[inside])), shape=(len(kept), h * w))
    return Reading("block", matrix)


def vertex_reading(points: list[tuple[np.ndarray, np.ndarray, np.ndarray]], camera: Camera, mask: np.ndarray
                   ) -> Reading:
    """The pixel of each vertex the camera sees, among `mask`'s pixels.

    Parameters
    ----------
    points : list of (positions (n, 3), faces (m, 3), normals (n, 3))
        Each closed body's welded surface in world units; a vertex counts when a ray from it
        (offset along its normal) reaches the eye past its own body and it projects into `mask`.
        One body does not hide another's vertices here.
    camera : Camera
        verify's (the images' pixels are its clip space, row 0 at the top).
    """
    h, w = mask.shape
    picked = []
    for positions, faces, normals in points:
        seen = point_visibility(positions, faces, normals, np.asarray(camera.eye, dtype=np.float64))
        clip = np.c_[positions[seen], np.ones(int(seen.sum()))] @ np.asarray(camera.view_projection).T
        front = clip[:, 3] > 0
        ndc = clip[front, :2] / clip[front, 3:4]
        col = np.floor((ndc[:, 0] + 1.0) * 0.5 * w).astype(np.int64)
        row = np.floor((1.0 - ndc[:, 1]) * 0.5 * h).astype(np.int64)
        inside = (col >= 0) & (col < w) & (row >= 0) & (row < h)
        flat = row[inside] * w + col[inside]
        picked.append(flat[mask.reshape(-1)[flat]])
    return Reading("vertex", _picks(np.concatenate(picked) if picked else np.zeros(0, np.int64), mask.size))


def measure(reading: Reading, images: dict[str, np.ndarray], halves: np.ndarray) -> dict:
    """Relative errors of `images` against the mean of `halves` under `reading`.

    Parameters
    ----------
    images : dict of str to (H, W, 3) float
    halves : (2, H, W, 3) float
        The truth's independent halves.

    Returns
    -------
    dict
        ``samples`` (k), ``noise_floor``, ``rmse_relative`` and ``rmse_relative_denoised``
        (sqrt(max(r² - floor², 0))), each a dict by the images' names; every figure is 0 when the
        reading has no samples or the truth is black there.
    """
    a, b = reading(halves[0]), reading(halves[1])
    truth = 0.5 * (a + b)
    norm = float(np.linalg.norm(truth))
    scale = 1.0 / norm if norm > 0 else 0.0
    floor = float(np.linalg.norm(a - b)) * 0.5 * scale
    errors = {name: float(np.linalg.norm(reading(image) - truth)) * scale for name, image in images.items()}
    return {"samples": int(truth.shape[0]), "noise_floor": floor, "rmse_relative": errors,
            "rmse_relative_denoised": {k: float(np.sqrt(max(v * v - floor * floor, 0.0))) for k, v in errors.items()}}


def _picks(index: np.ndarray, size: int) -> sparse.csr_matrix:
    return sparse.csr_matrix((np.ones(len(index)), (np.arange(len(index)), index)), shape=(len(index), size))
