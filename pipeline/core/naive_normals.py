"""Patro 2007's naive subsurface normals (Eq. 3): ``n'_i = α n_i + Σ_{j ∈ N(i), j ≠ i} n_j e^(-σ_tr d_ij)``,
normalised, N(i) the vertices within a radius of v_i (straight-line distance, k-d tree).

The sum counts vertices, not area, so it weights densely sampled regions more: the paper's
"discretisation" artefacts on unevenly sampled meshes, kept here as the paper has them (the
spectral normals are the fix). A vertex whose sum cancels (opposite sides of a thin sheet) keeps
its own normal.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

#: Pairs per chunk of the neighbour sum.
CHUNK = 4096


def naive_normals(positions_mm: np.ndarray, normals: np.ndarray, sigma_tr: float, alpha: float,
                  radius_mm: float) -> np.ndarray:
    """Parameters
    ----------
    positions_mm : (n, 3) float64
    normals : (n, 3) float64
        Unit vertex normals.
    sigma_tr : float
        Effective transport coefficient, 1/mm (>= 0).
    alpha : float
        Weight of a vertex's own normal.
    radius_mm : float
        Neighbourhood radius d.

    Returns
    -------
    (n, 3) float64, unit.
    """
    x = np.asarray(positions_mm, dtype=np.float64)
    nrm = np.asarray(normals, dtype=np.float64)
    tree = cKDTree(x)
    out = alpha * nrm
    for start in range(0, len(x), CHUNK):
        stop = min(len(x), start + CHUNK)
        pairs = cKDTree(x[start:stop]).sparse_distance_matrix(tree, radius_mm, output_type="ndarray")
        i, j, d = pairs["i"].astype(np.int64), pairs["j"].astype(np.int64), pairs["v"]
        other = j != i + start
        i, j, d = i[other], j[other], d[other]
        weight = np.exp(-sigma_tr * d)
        for c in range(3):
            out[start:stop, c] += np.bincount(i, weights=weight * nrm[j, c], minlength=stop - start)
    return unit_or_original(out, nrm)


def unit_or_original(vectors: np.ndarray, fallback: np.ndarray) -> np.ndarray:
    """`vectors` normalised; rows too short to have a direction (below 1e-6 of the longest or
    not finite) take `fallback`'s."""
    length = np.linalg.norm(vectors, axis=1)
    ok = np.isfinite(length) & (length > 1e-6 * max(float(np.nanmax(length, initial=0.0)), 1e-300))
    return np.where(ok[:, None], vectors / np.where(ok, length, 1.0)[:, None], fallback)
