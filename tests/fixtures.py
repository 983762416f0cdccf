"""Tiny fixtures several test modules share."""

import numpy as np

from sssbake.pipeline.baked import Fallback

# A plausible marble-like fallback with distinct values in every field, so a field swapped on export shows.
FALLBACK = Fallback(
    base_color=(0.83, 0.79, 0.75),
    thickness_texture=None,
    thickness_factor=2.0,
    attenuation_color=(0.9, 0.8, 0.7),
    attenuation_distance=4.0,
    diffuse_transmission_factor=0.4,
    diffuse_transmission_color=(1.0, 0.95, 0.9),
    ior=1.5,
)


def plane(spacing: float, half: int) -> tuple[np.ndarray, np.ndarray, int]:
    """A regular triangulated square of (2·half + 1)² vertices in z = 0: positions, faces, centre index."""
    n = 2 * half + 1
    g = (np.arange(n) - half) * spacing
    xx, yy = np.meshgrid(g, g, indexing="ij")
    verts = np.column_stack([xx.ravel(), yy.ravel(), np.zeros(n * n)])
    idx = np.arange(n * n).reshape(n, n)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    faces = np.concatenate([np.column_stack([a, b, c]), np.column_stack([a, c, d])])
    return verts, faces, half * n + half
