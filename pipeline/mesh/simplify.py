"""Quadric edge-collapse simplification with a vertex collapse map (fast-simplification).

The collapse map is what the prt technique needs: every original vertex learns which vertex of
the simplified mesh it was merged into, and every simplified vertex is one original vertex
("reference points = a subset of vertices", Hao & Varshney 2004).
"""

from __future__ import annotations

from dataclasses import dataclass

import fast_simplification
import numpy as np

from sssbake.pipeline.core.errors import SssbakeError


class SimplifyError(SssbakeError, ValueError):
    """Input the simplification step cannot work with."""


@dataclass(frozen=True, eq=False)
class Simplified:
    """A simplified mesh and how the original vertices map onto it.

    Attributes
    ----------
    positions : (k, 3) float64
        Simplified vertex positions. With ``snap=True`` exactly ``original_positions[kept]``.
    faces : (f, 3) int64
        Triangles indexing ``positions``.
    collapse_map : (n,) int64
        For every original vertex, the simplified vertex it was collapsed into (itself for kept
        vertices); -1 for original vertices that no face references.
    kept : (k,) int64
        The original vertex each simplified vertex is; ``collapse_map[kept] == arange(k)``.
    """

    positions: np.ndarray
    faces: np.ndarray
    collapse_map: np.ndarray
    kept: np.ndarray


def simplify(
    positions: np.ndarray,
    faces: np.ndarray,
    target_fraction: float = 0.1,
    *,
    target_count: int | None = None,
    snap: bool = True,
) -> Simplified:
    """Simplify a triangle mesh by quadric edge collapses and record where each vertex went.

    Parameters
    ----------
    positions : (n, 3) float64
    faces : (m, 3) int64
    target_fraction : float
        Fraction of the faces to keep, in (0, 1]. Ignored when ``target_count`` is given.
    target_count : int, optional
        Number of faces to keep (at least 1; more than ``m`` keeps the mesh as is).
    snap : bool
        Put every simplified vertex at the original position of the vertex it keeps, so the
        simplified vertices are a subset of the input vertices. fast-simplification itself moves
        each surviving vertex to its quadric-optimal point, up to edges away
        (benchmarks/README.md#simplification-snap); ``False`` keeps those positions (a closer LOD
        surface, same faces).

    Returns
    -------
    Simplified

    Notes
    -----
    fast-simplification keeps its mesh in module-global state: do not call this from several
    threads of one process at once.
    """
    positions = np.asarray(positions, dtype=np.float64)
    faces = np.asarray(faces)
    if positions.ndim != 2 or positions.shape[1] != 3:
        raise SimplifyError(f"simplify: positions must be (n, 3), got {positions.shape}")
    if faces.ndim != 2 or faces.shape[1] != 3 or len(faces) == 0:
        raise SimplifyError(f"simplify: faces must be a non-empty (m, 3) array, got {faces.shape}")
    if not np.issubdtype(faces.dtype, np.integer):
        raise SimplifyError(f"simplify: faces must be integer indices, got {faces.dtype}")
    faces = faces.astype(np.int64)
    if faces.min() < 0 or faces.max() >= len(positions):
        raise SimplifyError(f"simplify: face indices outside 0..{len(positions) - 1}; clean the mesh first")
    if not np.isfinite(positions).all():
        raise SimplifyError("simplify: positions contain NaN or Inf; clean the mesh first")
    if target_count is None:
        if not 0.0 < target_fraction <= 1.0:
            raise SimplifyError(f"simplify: target_fraction must be in (0, 1], got {target_fraction}")
        target_count = max(1, int(round(target_fraction * len(faces))))
    elif target_count < 1:
        raise SimplifyError(f"simplify: target_count must be at least 1, got {target_count}")
    target_count = min(int(target_count), len(faces))

    _, _, collapses = fast_simplification.simplify(
        positions, faces, target_count=target_count, return_collapses=True
    )
    # Replaying the collapses yields the same mesh plus the per-vertex map the simplifier lacks.
    new_positions, new_faces, collapse_map = fast_simplification.replay_simplification(
        positions, faces, collapses
    )
    collapse_map = np.asarray(collapse_map, dtype=np.int64)
    k = len(new_positions)

    survivor = np.zeros(len(positions), dtype=bool)
    survivor[faces.ravel()] = True
    survivor[np.asarray(collapses, dtype=np.int64).reshape(-1, 2)[:, 1]] = False
    survivors = np.flatnonzero(survivor)
    kept = np.full(k, -1, dtype=np.int64)
    kept[collapse_map[survivors]] = survivors
    if (kept < 0).any():
        raise SimplifyError(
            "simplify: fast-simplification produced vertices no original vertex survives as; "
            "try a larger target_fraction"
        )

    return Simplified(
        positions=positions[kept].copy() if snap else np.asarray(new_positions, dtype=np.float64),
        faces=np.asarray(new_faces, dtype=np.int64).reshape(-1, 3),
        collapse_map=collapse_map,
        kept=kept,
    )
