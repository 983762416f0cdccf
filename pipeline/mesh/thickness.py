"""Object thickness behind surface samples, by casting rays inwards with Embree (trimesh + embreex).

Thickness is the distance from a surface sample along the inward direction (−normal) to the
first surface the ray meets. Rays that meet nothing (open meshes, backwards normals) get ``cap``
and ``hit = False``; every thickness is capped at ``cap``.

Choice of estimator (measured, see tests/mesh/test_thickness.py): one ray along −n is exact on the two
closed forms, a sphere of radius R (2R at every vertex) and a slab of thickness t (t on the big
faces). A cone of jittered rays biases both — a ray at angle α from −n sees 2R cos α in the sphere
and t / cos α in the slab, so five rays in a 15° cone read the sphere 1.4 % thin and the slab
1.4 % thick — and costs ``rays`` × the time. So ``rays=1`` is the default; more rays only pay off
on noisy or cracked meshes, where the mean over a cone smooths single-ray outliers.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import trimesh
from trimesh.ray.ray_pyembree import RayMeshIntersector

from sssbake.pipeline.core.errors import SssbakeError


class ThicknessError(SssbakeError, ValueError):
    """Input the thickness bake cannot work with."""


@dataclass(frozen=True, eq=False)
class ThicknessResult:
    """Thickness per sample, in mesh units (multiply by mm per unit for mm).

    Attributes
    ----------
    thickness : (k,) float64
        Mean over the sample's rays of the distance to the first surface hit, each ray capped
        at ``cap``; an escaping ray counts as ``cap``.
    hit : (k,) bool
        More than half of the sample's rays hit the mesh.
    hit_fraction : (k,) float64
        Fraction of the sample's rays that hit the mesh.
    """

    thickness: np.ndarray
    hit: np.ndarray
    hit_fraction: np.ndarray


def bake_thickness(
    positions: np.ndarray,
    faces: np.ndarray,
    normals: np.ndarray | None = None,
    *,
    origins: np.ndarray | None = None,
    directions: np.ndarray | None = None,
    cap: float,
    rays: int = 1,
    cone_degrees: float = 15.0,
    epsilon: float = 1e-5,
    seed: int = 0,
) -> ThicknessResult:
    """Cast rays inwards from surface samples and measure how far they travel inside the object.

    Parameters
    ----------
    positions : (n, 3) float64
        Mesh vertices.
    faces : (m, 3) int64
    normals : (n, 3) float64, optional
        Outward unit vertex normals; used when ``origins`` is None (the samples are then the
        vertices, cast along −normals).
    origins : (k, 3) float64, optional
        Sample points on the surface, e.g. texel positions. Needs ``directions``.
    directions : (k, 3) float64, optional
        Inward direction per sample, e.g. −texel normals; need not be unit length.
    cap : float
        Largest thickness reported, mesh units, and the value of samples whose rays escape.
    rays : int
        Rays per sample: the first along the direction, the others uniform in a cone.
    cone_degrees : float
        Half-angle of the cone for ``rays > 1``.
    epsilon : float
        Rays start this fraction of the bounding-box diagonal inside the surface, so they do not
        hit the triangles around their own origin; the distance is still measured from the
        sample point.
    seed : int
        Seed of the cone directions.

    Returns
    -------
    ThicknessResult
    """
    positions = np.asarray(positions, dtype=np.float64)
    faces = np.asarray(faces)
    if positions.ndim != 2 or positions.shape[1] != 3 or not np.isfinite(positions).all():
        raise ThicknessError(f"thickness: positions must be finite (n, 3), got {positions.shape}")
    if faces.ndim != 2 or faces.shape[1] != 3 or len(faces) == 0:
        raise ThicknessError(f"thickness: faces must be a non-empty (m, 3) array, got {faces.shape}")
    if faces.min() < 0 or faces.max() >= len(positions):
        raise ThicknessError(f"thickness: face indices outside 0..{len(positions) - 1}; clean the mesh first")
    if not (np.isfinite(cap) and cap > 0):
        raise ThicknessError(f"thickness: cap must be a positive finite length, got {cap}")
    if rays < 1:
        raise ThicknessError(f"thickness: rays must be at least 1, got {rays}")
    if origins is None:
        if normals is None:
            raise ThicknessError("thickness: pass vertex normals, or origins and directions")
        origins = positions
        directions = -np.asarray(normals, dtype=np.float64)
    elif directions is None:
        raise ThicknessError("thickness: origins need directions (the inward normal of each sample)")
    origins = np.asarray(origins, dtype=np.float64)
    directions = np.asarray(directions, dtype=np.float64)
    if origins.ndim != 2 or origins.shape[1] != 3 or directions.shape != origins.shape:
        raise ThicknessError(
            f"thickness: origins and directions must both be (k, 3), got {origins.shape}, {directions.shape}"
        )
    length = np.linalg.norm(directions, axis=1, keepdims=True)
    if not (np.isfinite(origins).all() and np.isfinite(directions).all() and (length > 0).all()):
        raise ThicknessError("thickness: origins or directions contain NaN, Inf or zero-length vectors")
    directions = directions / length

    # Embree works in float32: centring the mesh keeps its precision relative to the mesh size.
    centre = 0.5 * (positions.min(axis=0) + positions.max(axis=0))
    diagonal = float(np.linalg.norm(np.ptp(positions, axis=0)))
    mesh = trimesh.Trimesh(positions - centre, faces, process=False, validate=False)
    intersector = RayMeshIntersector(mesh)

    k = len(origins)
    ray_dirs = _cone(directions, rays, np.radians(cone_degrees), seed).reshape(-1, 3)
    ray_origins = np.repeat(origins - centre, rays, axis=0)
    tri = intersector.intersects_first(ray_origins + (epsilon * diagonal) * ray_dirs, ray_dirs)

    hit = tri >= 0
    distance = np.full(len(tri), cap, dtype=np.float64)
    corners = mesh.vertices[mesh.faces[tri[hit]]]
    plane_normal = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    along = np.einsum("ij,ij->i", ray_dirs[hit], plane_normal)
    reach = np.einsum("ij,ij->i", corners[:, 0] - ray_origins[hit], plane_normal)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = reach / along
    distance[hit] = np.clip(np.nan_to_num(t, nan=cap, posinf=cap, neginf=0.0), 0.0, cap)

    hit_fraction = hit.reshape(k, rays).mean(axis=1)
    return ThicknessResult(
        thickness=distance.reshape(k, rays).mean(axis=1),
        hit=hit_fraction > 0.5,
        hit_fraction=hit_fraction,
    )


def _cone(axis: np.ndarray, rays: int, half_angle: float, seed: int) -> np.ndarray:
    """(k, rays, 3) unit directions: the axis itself, then ``rays - 1`` uniform in the cone."""
    k = len(axis)
    out = np.empty((k, rays, 3))
    out[:, 0] = axis
    if rays == 1:
        return out
    rng = np.random.default_rng(seed)
    cos_theta = rng.uniform(np.cos(half_angle), 1.0, (k, rays - 1))
    sin_theta = np.sqrt(1.0 - cos_theta**2)
    phi = rng.uniform(0.0, 2.0 * np.pi, (k, rays - 1))
    helper = np.where(np.abs(axis[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    u = np.cross(axis, helper)
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    v = np.cross(axis, u)
    out[:, 1:] = (
        cos_theta[..., None] * axis[:, None]
        + (sin_theta * np.cos(phi))[..., None] * u[:, None]
        + (sin_theta * np.sin(phi))[..., None] * v[:, None]
    )
    return out
