"""SSLPV propagation matrices (Børlum et al. 2011, after Kaplanyan & Dachsbacher 2010), derived by
numerical integration.

Basis: two SH bands, real, WITHOUT the Condon-Shortley phase, order c = (c00, c1-1, c10, c11):
y00 = 1/√(4π), (y1-1, y10, y11) = √(3/(4π)) (ω_y, ω_z, ω_x). (`sh.sh_basis` carries the
Condon-Shortley sign and so differs in the sign of y1-1 and y11; it is not used here.)

Cells are unit cubes; the destination d is centred at the origin and the source s at -D, D being the
propagation direction (offset from source to destination). For each face f of d except the one it
shares with s:

* the flux from s onto f is Φ_f = v_f · c_s with [v_f]_lm = ∫_{Δω_f} y_lm dω, Δω_f the solid angle
  of f seen from the centre of s, integrated over the face area with dω = |n_f·(x - p)| / r³ dA by
  Gauss-Legendre quadrature;
* Φ_f is re-emitted from d's centre as the lobe Φ_f/π · max(0, n_f·ω) (total flux Φ_f), whose
  projection is (1/π) u_f Φ_f with [u_f]_lm = ∫_{n_f·ω>0} (n_f·ω) y_lm dω, in closed form
  u_00 = π y00 = √π/2 and u_1 = (2π/3) √(3/(4π)) (n_y, n_z, n_x).

Hence M_{d←s} = (1/π) Σ_f u_f v_f^T and c_d += M_{d←s} c_s.

Every ray from the centre of s that reaches one of the five faces enters d through the shared face,
so the five Δω_f tile the solid angle of the shared face seen from s, which is a cube face seen
from its cube's centre: 4π/6. The six neighbours' tiles therefore cover the sphere once and, since
both the y00 projection of the input and the cosine lobe's normalisation are exact, the matrices
conserve total flux; M[k][0, 0] = 1/6 exactly.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

DIRECTIONS = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]],
                      dtype=np.int64)
DIRECTIONS.setflags(write=False)

DEFAULT_QUADRATURE = 32
_BAND1 = np.sqrt(3.0 / (4.0 * np.pi))
# Basis order (y, z, x) for band 1: the column of ω feeding each of c1-1, c10, c11.
_BAND1_AXES = (1, 2, 0)


def lpv_basis(omega: np.ndarray) -> np.ndarray:
    """The paper's two-band real SH basis (no Condon-Shortley phase) at unit directions.

    Parameters
    ----------
    omega : (m, 3) float64
        Unit directions (x, y, z).

    Returns
    -------
    (m, 4) float64
        (y00, y1-1, y10, y11) = (1/√(4π), √(3/(4π)) (ω_y, ω_z, ω_x)).
    """
    omega = np.asarray(omega, dtype=np.float64)
    if omega.ndim != 2 or omega.shape[1] != 3:
        raise ValueError(f"lpv_basis: directions must be an (m, 3) array, got shape {omega.shape}")
    if not np.all(np.isfinite(omega)):
        raise ValueError("lpv_basis: directions must be finite")
    out = np.empty((len(omega), 4))
    out[:, 0] = 0.5 / np.sqrt(np.pi)
    out[:, 1:] = _BAND1 * omega[:, _BAND1_AXES]
    return out


def cube_faces() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The six faces of the unit cube centred at the origin, in the order of `DIRECTIONS`.

    Returns
    -------
    centres : (6, 3) float64
        Face centres, ±0.5 along the face's axis.
    normals : (6, 3) float64
        Outward unit normals (= DIRECTIONS).
    edges : (6, 2, 3) float64
        Half-edge vectors spanning each face (length 0.5, along the two other axes).
    """
    normals = DIRECTIONS.astype(np.float64)
    axes = np.abs(DIRECTIONS).argmax(axis=1)
    eye = np.eye(3)
    edges = np.stack([eye[[(a + 1) % 3, (a + 2) % 3]] * 0.5 for a in axes])
    return 0.5 * normals, normals, edges


def face_projection(point: np.ndarray, centre: np.ndarray, edges: np.ndarray,
                    quadrature: int = DEFAULT_QUADRATURE) -> np.ndarray:
    """∫ over the solid angle of a parallelogram, seen from `point`, of the basis: [v]_lm.

    Tensor Gauss-Legendre quadrature over the face area with dω = |n·(x - p)| / r³ dA; the
    integrand is smooth while `point` stays off the face's plane.

    Parameters
    ----------
    point : (3,) float64
        Viewpoint, not on the face's plane.
    centre : (3,) float64
        Face centre.
    edges : (2, 3) float64
        Half-edge vectors; the face is centre + s e0 + t e1, s, t in [-1, 1].
    quadrature : int
        Gauss-Legendre points per edge.

    Returns
    -------
    (4,) float64
        ∫_{Δω} (y00, y1-1, y10, y11) dω; the solid angle Δω itself is [0] · √(4π).
    """
    if quadrature < 1:
        raise ValueError(f"face_projection: quadrature must be >= 1, got {quadrature}")
    nodes, weights = np.polynomial.legendre.leggauss(quadrature)
    edges = np.asarray(edges, dtype=np.float64)
    normal = np.cross(edges[0], edges[1])
    area_jacobian = np.linalg.norm(normal)  # dA per ds dt
    normal /= area_jacobian
    x = (np.asarray(centre, dtype=np.float64) + nodes[:, None, None] * edges[0]
         + nodes[None, :, None] * edges[1]).reshape(-1, 3) - np.asarray(point, dtype=np.float64)
    r = np.linalg.norm(x, axis=1)
    if np.any(np.abs(x @ normal) < 1e-12 * r):
        raise ValueError("face_projection: the point lies on the face's plane")
    d_omega = np.abs(x @ normal) / r**3 * np.outer(weights, weights).ravel() * area_jacobian
    return lpv_basis(x / r[:, None]).T @ d_omega


def cosine_lobe_projection(normal: np.ndarray) -> np.ndarray:
    """Closed-form [u]_lm = ∫_{n·ω>0} (n·ω) y_lm(ω) dω for a unit normal n.

    ∫ (n·ω) dω = π over the hemisphere and ∫ (n·ω) ω dω = (2π/3) n.

    Parameters
    ----------
    normal : (3,) float64
        Unit normal.

    Returns
    -------
    (4,) float64
    """
    normal = np.asarray(normal, dtype=np.float64)
    return np.concatenate([[np.sqrt(np.pi) / 2.0], _BAND1 * (2.0 * np.pi / 3.0) * normal[list(_BAND1_AXES)]])


def propagation_matrices(quadrature: int = DEFAULT_QUADRATURE) -> np.ndarray:
    """Propagation matrices for the six directions: c_d += M[k] @ c_s for s = d - DIRECTIONS[k].

    Parameters
    ----------
    quadrature : int
        Gauss-Legendre points per face edge; 32 converges to ~1e-15.

    Returns
    -------
    (6, 4, 4) float64, read-only
    """
    return _propagation_matrices(int(quadrature))


@lru_cache(maxsize=4)
def _propagation_matrices(quadrature: int) -> np.ndarray:
    centres, normals, edges = cube_faces()
    out = np.zeros((6, 4, 4))
    for k, direction in enumerate(DIRECTIONS):
        source = -direction.astype(np.float64)
        for f in range(6):
            if np.array_equal(DIRECTIONS[f], -direction):  # the face shared with s lets light in
                continue
            v = face_projection(source, centres[f], edges[f], quadrature)
            out[k] += np.outer(cosine_lobe_projection(normals[f]), v) / np.pi
    out.setflags(write=False)  # cached: shared between callers
    return out
