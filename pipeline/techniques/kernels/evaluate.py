"""The kernels runtime in numpy (float64): steps 2-5 of `kernels_data` for a given illumination
map. The precompute's tests and the GPU runtime's tests compare against it."""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from sssbake.pipeline.techniques.kernels.data import KernelsData


def local_response(data: KernelsData, illumination: np.ndarray) -> np.ndarray:
    """B_l per covered texel.

    Parameters
    ----------
    data : KernelsData
    illumination : (height, width) float64
        E per texel (covered and border texels; 0 elsewhere).

    Returns
    -------
    (S, 3) float64
    """
    e = _checked(data, illumination)
    r = data.radius
    padded = np.pad(e, r)
    rows, cols = np.divmod(data.texels, data.width)
    dy, dx = data.offsets()
    taps = padded[rows[:, None] + r + dy[None, :], cols[:, None] + r + dx[None, :]]  # (S, k²)
    return np.einsum("so,soc->sc", taps, data.kernels.astype(np.float64))


def vertex_response(data: KernelsData, illumination: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The hat-basis irradiance and the direct and global radiosity at the welded vertices.

    Returns
    -------
    e_g : (n,) float64
        Σ texel_dual · E.
    b_d : (n, 3) float64
        Σ texel_direct · E.
    b_g : (n, 3) float64
        F · e_g.
    """
    e = _checked(data, illumination).reshape(-1)[data.texels]
    n = data.vertex_count
    corners = data.texel_vertices.reshape(-1)
    e_g = np.bincount(corners, weights=(data.texel_dual.astype(np.float64) * e[:, None]).reshape(-1), minlength=n)
    direct = data.texel_direct.astype(np.float64) * e[:, None, None]
    b_d = np.stack([np.bincount(corners, weights=direct[:, :, c].reshape(-1), minlength=n) for c in range(3)], axis=1)
    f = global_matrix(data)
    b_g = np.stack([f[c] @ e_g for c in range(3)], axis=1)
    return e_g, b_d, b_g


def global_matrix(data: KernelsData) -> list[sp.csr_matrix]:
    """F per channel as (n, n) CSR, row = receiver, column = source."""
    n = data.vertex_count
    return [sp.csr_matrix((data.f_values[:, c].astype(np.float64), data.f_indices, data.f_indptr), shape=(n, n))
            for c in range(3)]


def texel_q(data: KernelsData, illumination: np.ndarray, barycentric: np.ndarray) -> np.ndarray:
    """(S, 3) q at the covered texels' centres, whose barycentric weights in their triangles
    (``texel_vertices`` order) are `barycentric` (S, 3)."""
    _, b_d, b_g = vertex_response(data, illumination)
    vertex = b_d + b_g
    smooth = np.einsum("sa,sac->sc", barycentric, vertex[data.texel_vertices])
    return local_response(data, illumination) + smooth


def _checked(data: KernelsData, illumination: np.ndarray) -> np.ndarray:
    e = np.asarray(illumination, dtype=np.float64)
    if e.shape != (data.height, data.width) or not np.all(np.isfinite(e)):
        raise ValueError(f"kernels: illumination must be finite with shape {(data.height, data.width)}, got {e.shape}")
    return e
