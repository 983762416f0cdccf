"""Per-vertex tangent frames for normal mapping, in glTF's TANGENT convention."""

from __future__ import annotations

import numpy as np

# A face whose two UV edges make an angle with a sine below this (collinear or collapsed UVs) has
# no usable UV derivative.
DEGENERATE_UV = 1e-12


def vertex_tangents(positions: np.ndarray, faces: np.ndarray, normals: np.ndarray, uvs: np.ndarray) -> np.ndarray:
    """Unit tangents and handedness of every vertex, from the UV derivatives of its faces.

    Lengyel's method with MikkTSpace's weighting: each face's direction of increasing u
    (dP/du) is projected onto the tangent plane of each of its corners' normals and summed with
    the corner's angle as weight; the sum is orthonormalised against the normal
    (Gram-Schmidt). The handedness w compares ``cross(normal, tangent)`` with the summed
    direction of the image's "up" (decreasing glTF v).

    MikkTSpace is the reference that normal maps are baked against; this is an approximation
    that matches it on smooth, non-mirrored UV layouts. Unlike MikkTSpace it never splits a
    vertex, so vertices shared by mirrored and non-mirrored faces get one compromise frame.

    Parameters
    ----------
    positions : (n, 3) float
    faces : (m, 3) int
        Counter-clockwise triangles.
    normals : (n, 3) float
        Unit vertex normals.
    uvs : (n, 2) float
        The normal texture's UV set, glTF convention (v down from the image's top).

    Returns
    -------
    (n, 4) float64
        Unit xyz orthogonal to the normal, w = ±1, such that the bitangent
        ``cross(normal, xyz) * w`` points up the image. Vertices with no usable UV derivative
        (only degenerate UV faces, or none) get a unit vector perpendicular to the normal and
        w = 1.
    """
    positions = np.asarray(positions, dtype=np.float64)
    normals = np.asarray(normals, dtype=np.float64)
    uvs = np.asarray(uvs, dtype=np.float64)
    faces = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    n = len(positions)

    p = positions[faces]
    t = uvs[faces]
    e1, e2 = p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]
    du1, dv1 = t[:, 1, 0] - t[:, 0, 0], t[:, 1, 1] - t[:, 0, 1]
    du2, dv2 = t[:, 2, 0] - t[:, 0, 0], t[:, 2, 1] - t[:, 0, 1]
    det = du1 * dv2 - du2 * dv1
    usable = np.abs(det) > DEGENERATE_UV * np.hypot(du1, dv1) * np.hypot(du2, dv2)
    # dP/du = (e1 dv2 - e2 dv1) / det and dP/dv = (e2 du1 - e1 du2) / det; only directions are
    # needed, so multiply by sign(det) instead of dividing by a possibly tiny det.
    sign = np.where(usable, np.sign(det), 0.0)[:, None]
    face_t = (e1 * dv2[:, None] - e2 * dv1[:, None]) * sign
    # glTF's v runs down the image, but a normal map's +Y (green) points up it, so the bitangent
    # the map is baked against is -dP/dv. Flat quad check: positions (x, y, 0), normal +z,
    # uv = (x, 1 - y) shows the image upright seen from +z; dP/du = +x, -dP/dv = +y, and
    # cross(normal, tangent) = cross(+z, +x) = +y, so w = +1, as glTF expects of an unmirrored
    # layout (three.js negates MikkTSpace's w on glTF UVs for the same reason).
    face_b = -(e2 * du1[:, None] - e1 * du2[:, None]) * sign

    tangent = np.zeros((n, 3))
    bitangent = np.zeros((n, 3))
    weight = np.zeros(n)
    for k in range(3):
        a, b = p[:, (k + 1) % 3] - p[:, k], p[:, (k + 2) % 3] - p[:, k]
        angle = np.arctan2(np.linalg.norm(np.cross(a, b), axis=1), np.einsum("ij,ij->i", a, b))
        nk = normals[faces[:, k]]
        np.add.at(tangent, faces[:, k], angle[:, None] * _unit(_reject(face_t, nk)))
        np.add.at(bitangent, faces[:, k], angle[:, None] * _unit(_reject(face_b, nk)))
        weight += np.bincount(faces[:, k], weights=angle * usable, minlength=n)

    tangent = _reject(tangent, normals)
    length = np.linalg.norm(tangent, axis=1)
    # A sum that (nearly) cancelled, e.g. across a mirror seam, has no direction worth keeping.
    ok = length > 1e-6 * weight
    xyz = _perpendicular(normals)
    xyz[ok] = tangent[ok] / length[ok, None]
    w = np.where(np.einsum("ij,ij->i", np.cross(normals, xyz), bitangent) < 0.0, -1.0, 1.0)
    w[~ok] = 1.0
    return np.column_stack([xyz, w])


def _reject(v: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """(k, 3) `v` minus its component along the unit `normals` (k, 3)."""
    return v - normals * np.einsum("ij,ij->i", v, normals)[:, None]


def _unit(v: np.ndarray) -> np.ndarray:
    """(k, 3) `v` scaled to unit length; zero rows stay zero."""
    length = np.linalg.norm(v, axis=1, keepdims=True)
    return np.divide(v, length, out=np.zeros_like(v), where=length > 0)


def _perpendicular(normals: np.ndarray) -> np.ndarray:
    """(k, 3) unit vectors perpendicular to the unit `normals` (k, 3)."""
    # The coordinate axis least aligned with the normal keeps the rejection well conditioned.
    axis = np.eye(3)[np.argmin(np.abs(normals), axis=1)]
    return _unit(_reject(axis, normals))
