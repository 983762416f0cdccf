"""The cotangent stiffness matrix and the lumped mass matrix of a triangle mesh: the discrete
Laplace-Beltrami operator of the spectral technique (Patro 2007, Eq. 4; Vallet & Lévy 2008).

A triangle with edge vectors e_0, e_1, e_2 (e_i opposite corner i) adds the element matrix
``K_T = G / (4 A)``, G the Gram matrix e_i · e_j, to W (off the diagonal that is the familiar
-½ cot of the opposite angle). G is positive semi-definite for any triangle, so W is too. Slivers
make cotangents unbounded: the area in the denominator is floored at `SLIVER` times the sum of
the squared edge lengths (an equilateral triangle has 0.144), which bounds every cotangent by
1 / (4 SLIVER) = 2500 and keeps each element positive semi-definite (a clamp on the cotangents
themselves would not). Boundary edges of open meshes simply have one triangle (the natural,
Neumann condition); a triangle of zero edges adds nothing.

Mass: the lumped (barycentric) M_ii = a third of the areas of i's triangles. Vertices in no
triangle of positive area get a tiny mass (`FLOOR` of the mean) so that M stays invertible; their
rows of W are zero, so they only add eigenvalue-0 pairs of their own.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

#: Smallest area, relative to the sum of the squared edge lengths, that a triangle's element uses.
SLIVER = 1e-4
#: Mass of a vertex that no triangle of positive area reaches, relative to the mean mass.
FLOOR = 1e-9


@dataclass(frozen=True, eq=False)
class Laplacian:
    """Attributes
    ----------
    stiffness : (n, n) scipy.sparse.csr_matrix, float64
        W: symmetric positive semi-definite, rows summing to zero.
    mass : (n,) float64
        The lumped mass diagonal, > 0 (area units).
    slivers : int
        Triangles whose area was floored.
    """

    stiffness: sp.csr_matrix
    mass: np.ndarray
    slivers: int


def cotangent_laplacian(positions: np.ndarray, faces: np.ndarray) -> Laplacian:
    """Parameters
    ----------
    positions : (n, 3) float64
    faces : (m, 3) int

    Returns
    -------
    Laplacian
    """
    x = np.asarray(positions, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    n = len(x)
    # e_i is the edge opposite corner i, running around the triangle
    edges = np.stack([x[f[:, 2]] - x[f[:, 1]], x[f[:, 0]] - x[f[:, 2]], x[f[:, 1]] - x[f[:, 0]]], axis=1)
    area = 0.5 * np.linalg.norm(np.cross(edges[:, 0], edges[:, 1]), axis=1)
    floor = SLIVER * np.einsum("tij,tij->t", edges, edges)
    slivers = int(np.count_nonzero((area < floor) & (floor > 0)))
    denominator = 4.0 * np.maximum(area, floor)
    gram = np.einsum("tid,tjd->tij", edges, edges) / np.where(denominator > 0, denominator, 1.0)[:, None, None]
    rows = np.repeat(f, 3, axis=1).reshape(-1)
    cols = np.tile(f, (1, 3)).reshape(-1)
    stiffness = sp.csr_matrix((gram.reshape(-1), (rows, cols)), shape=(n, n))
    stiffness.sum_duplicates()
    mass = np.bincount(f.reshape(-1), weights=np.repeat(area / 3.0, 3), minlength=n)
    mean = float(mass[mass > 0].mean()) if np.any(mass > 0) else 1.0
    mass = np.where(mass > 0, mass, FLOOR * mean)
    return Laplacian(stiffness, mass, slivers)
