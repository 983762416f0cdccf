"""The welded surface of a mesh and the area-weighted quantities every technique reads."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True, eq=False)
class Surface:
    """The welded surface of one Mesh (all its primitives), in the mesh's local frame, file units.

    Attributes
    ----------
    positions : (w, 3) float64
    faces : (f, 3) int64
    normals : (w, 3) float64
        Area-weighted unit vertex normals.
    vertex_areas : (w,) float64
        A third of the incident triangle areas, file units².
    weld : tuple of (n_p,) int64
        For each primitive, the welded vertex of each of its (cleaned) render vertices.
    """

    positions: np.ndarray
    faces: np.ndarray
    normals: np.ndarray
    vertex_areas: np.ndarray
    weld: tuple[np.ndarray, ...]

    @property
    def area(self) -> float:
        return float(self.vertex_areas.sum())


def triangle_areas(positions: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(m,) areas of the triangles `faces` (m, 3) over `positions` (n, 3)."""
    p = positions[faces]
    return 0.5 * np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1)


def vertex_areas(positions: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(n,) per-vertex areas: a third of the incident triangle areas (they sum to the mesh area)."""
    third = np.repeat(triangle_areas(positions, faces) / 3.0, 3)
    return np.bincount(faces.ravel(), weights=third, minlength=len(positions))


def area_weighted_normals(positions: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(n, 3) unit vertex normals, the sum of incident face normals weighted by face area.

    Vertices with no incident area get +Z rather than NaN.
    """
    p = positions[faces]
    fn = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])  # length = 2 × area: area weighting for free
    acc = np.zeros_like(positions)
    for k in range(3):
        np.add.at(acc, faces[:, k], fn)
    return unit_rows(acc)


def unit_rows(v: np.ndarray) -> np.ndarray:
    """Unit rows of `v` (n, 3); zero or non-finite rows become +z.

    Each row is divided by its largest component first: the length of an authored normal of
    1e300 would overflow, and one of 1e-310 underflow, where the direction is still good.
    """
    largest = np.abs(v).max(axis=1, keepdims=True) if len(v) else np.zeros((0, 1))
    ok = np.isfinite(largest[:, 0]) & (largest[:, 0] > 0)
    out = np.tile([0.0, 0.0, 1.0], (len(v), 1))
    w = v[ok] / largest[ok]
    out[ok] = w / np.linalg.norm(w, axis=1, keepdims=True)
    return out
