"""Object thickness behind surface samples, by casting rays inwards with Embree (trimesh + embreex).

Thickness is the distance from a surface sample along an inward direction to the first surface the
ray meets, capped at ``cap``.

Choice of estimator (measured, see tests/mesh/test_thickness.py): one ray along −n is exact on the two
closed forms, a sphere of radius R (2R at every vertex) and a slab of thickness t (t on the big
faces). A cone of jittered rays biases both — a ray at angle α from −n sees 2R cos α in the sphere
and t / cos α in the slab, so five rays in a 15° cone read the sphere 1.4 % thin and the slab
1.4 % thick — and costs ``rays`` × the time. So ``rays=1`` is the default; more rays only pay off
on noisy or cracked meshes, where the mean over a cone smooths single-ray outliers.

Hard edges. A vertex where faces meet at a hard edge or corner has no normal: the averaged one
points along no face and reads the slab's t / cos α (a 100 mm textured cube's corners read
122-150 mm). Where the author split the normals at a position (render copies of a welded vertex
whose normals are more than `SPLIT_DEGREES` apart: a hard edge as exporters mark it) the vertex
casts one ray along each distinct inward copy normal instead and keeps the shortest chord: every
vertex of a box reads its shortest side, a capped cylinder's rim the shorter of its height and its
diameter. The rays start a hair inside along the averaged normal, not along themselves, so that a
ray along one face does not graze the face beside it; a copy normal turned away from the averaged
one (an inverted normal, the back of a two-sided sheet) would meet the surface at once and is left
out. Split normals rather than the geometry decide: with incident face normals more than 25° off
the averaged normal as the test, 31 % of the dragon's vertices (a decimated scan) came out hard, 10 %
of Nefertiti's, and the dragon's median thickness fell 22 % to the shortest of noisy chords. 5° keeps
together copies at UV seams whose normals differ by rounding or quantisation (8-bit components:
steps under 1°); a split that small changes a chord by at most 1 - cos 5° = 0.4 %. Texels (`thickness_map`) cast along their interpolated shading normal,
as KHR_materials_volume bakes its thickness ("opposite the surface normal"): normals split at a hard
edge give the faces' normals there (a textured cube's texels read its edge). Without split normals
(smooth shading across an edge, or no normals in the file) a vertex keeps its averaged normal.

Rays that meet no surface. On a closed, consistently wound mesh every inward ray meets the surface;
one that does not either left through an opening of an open mesh (a scan's base) or started on a
fold (triangles wound against their neighbours, whose normals point into the object). The generalized
winding number w (`winding.py`, inside where ``|w| > 1/2``) says where the inside is, read at a probe
depth ``PROBE_EDGES`` × the longest edge of the sample's triangles (a vertex: of its incident ones):
close to the surface w follows the sample's own triangles, a fold included, and only a few triangle
sizes away does it follow the object (a fold one ring wide flips w within 0.6 ring radii of it).
- Inside ahead: the ray left through an opening; it ends where w first falls to 1/2 along it
  (`MARCH_STEPS` samples from the probe to where the ray leaves the bounding box, past which
  ``|w| <= 1/2``, then `REFINEMENTS` false-position steps, w being smooth off the surface): over a
  planar opening that is its plane, the closed object's chord.
- Inside behind (probed at most half way to the surface behind): the direction points out of the
  object (a fold, or inward-facing triangles); the ray is cast the other way and ends on the surface
  it meets, or as above.
- Inside on neither side: the sample lies on a sheet with no volume behind it; thickness 0.
Rays that meet a surface keep it: a surface is where the object ends, and checking w along every hit
ray would cost `MARCH_STEPS` evaluations per texel. So a sample whose direction points out of the
object and still meets some other part of it (an inverted normal facing another limb) is not turned.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import trimesh
from trimesh.ray.ray_pyembree import RayMeshIntersector

from sssbake.pipeline.core.errors import SssbakeError
from sssbake.pipeline.core.surface import unit_rows
from sssbake.pipeline.mesh.winding import INSIDE, edge_defects, winding_numbers

#: A welded vertex whose render copies' normals are more than this apart is on a hard edge or corner.
SPLIT_DEGREES = 5.0
#: Depth of the winding-number probes, in longest edges of the sample's triangles.
PROBE_EDGES = 2.0
#: Winding-number samples along a ray that left through an opening, before refining.
MARCH_STEPS = 32
#: False-position steps in the step where the winding number falls to 1/2, each a libigl call (~0.15 s
#: of tree building on the 70k-triangle bunny). On the tilted open hemisphere of the tests 0, 1 and 2
#: all read within 0.42 % (median 0.07 %), the fast winding number's own error; two for where w bends.
REFINEMENTS = 2


class ThicknessError(SssbakeError, ValueError):
    """Input the thickness bake cannot work with."""


@dataclass(frozen=True, eq=False)
class ThicknessResult:
    """Thickness per sample, in mesh units (multiply by mm per unit for mm).

    Attributes
    ----------
    thickness : (k,) float64
        Mean over the sample's rays of each ray's length inside the object, capped at ``cap``
        (module docstring); for a vertex on a hard edge the shortest such mean over its directions.
    hit : (k,) bool
        More than half of the sample's rays met the surface.
    hit_fraction : (k,) float64
        Fraction of the sample's rays that met the surface (for a hard vertex: in its shortest direction).
    rays : int
        Rays cast (over every sample and direction).
    opening : int
        Rays that met no surface and ended where the winding number fell to 1/2.
    flipped : int
        Rays cast against their sample's direction: the inside lay behind it.
    no_inside : int
        Rays with no inside on either side (thickness 0).
    """

    thickness: np.ndarray
    hit: np.ndarray
    hit_fraction: np.ndarray
    rays: int
    opening: int
    flipped: int
    no_inside: int


def bake_thickness(
    positions: np.ndarray,
    faces: np.ndarray,
    normals: np.ndarray | None = None,
    *,
    split_normals: tuple[np.ndarray, np.ndarray] | None = None,
    origins: np.ndarray | None = None,
    directions: np.ndarray | None = None,
    probe: np.ndarray | None = None,
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
        vertices, cast along −normals, or along their split normals on hard edges).
    split_normals : ((r,) int64, (r, 3) float64), optional
        With ``normals``: the vertex (index into ``positions``) of each render vertex and its outward
        normal as authored; where a vertex's copies differ by more than `SPLIT_DEGREES` it casts
        along each of their distinct normals (module docstring, Hard edges).
    origins : (k, 3) float64, optional
        Sample points on the surface, e.g. texel positions. Needs ``directions``.
    directions : (k, 3) float64, optional
        Inward direction per sample, e.g. −texel normals; need not be unit length.
    probe : (k,) float64, optional
        With ``origins``: the longest edge of each sample's triangle, mesh units (the depth of the
        winding-number probes is `PROBE_EDGES` times it); default the mesh's median edge.
    cap : float
        Largest thickness reported, mesh units.
    rays : int
        Rays per sample and direction: the first along the direction, the others uniform in a cone.
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
        One entry per vertex, or per sample of ``origins``.
    """
    positions = np.asarray(positions, dtype=np.float64)
    faces = np.asarray(faces)
    if positions.ndim != 2 or positions.shape[1] != 3 or not np.isfinite(positions).all():
        raise ThicknessError(f"thickness: positions must be finite (n, 3), got {positions.shape}")
    if faces.ndim != 2 or faces.shape[1] != 3 or len(faces) == 0:
        raise ThicknessError(f"thickness: faces must be a non-empty (m, 3) array, got {faces.shape}")
    if faces.min() < 0 or faces.max() >= len(positions):
        raise ThicknessError(f"thickness: face indices outside 0..{len(positions) - 1}; clean the mesh first")
    faces = faces.astype(np.int64)
    if not (np.isfinite(cap) and cap > 0):
        raise ThicknessError(f"thickness: cap must be a positive finite length, got {cap}")
    if rays < 1:
        raise ThicknessError(f"thickness: rays must be at least 1, got {rays}")
    if origins is None:
        if normals is None:
            raise ThicknessError("thickness: pass vertex normals, or origins and directions")
        normals = np.asarray(normals, dtype=np.float64)
        if normals.shape != positions.shape or not np.isfinite(normals).all() or \
                not (np.abs(normals).max(axis=1) > 0).all():
            raise ThicknessError("thickness: normals must be (n, 3) like positions, without NaN, Inf or "
                                 "zero-length vectors")
        if split_normals is not None:
            weld, copies = (np.asarray(a) for a in split_normals)
            if weld.ndim != 1 or copies.shape != (len(weld), 3) or (weld.size and (
                    weld.min() < 0 or weld.max() >= len(positions))) or not np.isfinite(copies).all():
                raise ThicknessError("thickness: split_normals must be (r,) vertex indices and (r, 3) finite normals")
            split_normals = weld.astype(np.int64), unit_rows(copies.astype(np.float64))
        owner, directions, offsets, probe = _vertex_samples(positions, faces, unit_rows(normals), split_normals)
        origins = positions[owner]
    else:
        if directions is None:
            raise ThicknessError("thickness: origins need directions (the inward normal of each sample)")
        owner = None
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
        offsets = directions
        if probe is None:
            probe = np.full(len(origins), float(np.median(_edge_lengths(positions, faces))))
        probe = np.asarray(probe, dtype=np.float64)
        if probe.shape != (len(origins),) or not (np.isfinite(probe).all() and (probe >= 0).all()):
            raise ThicknessError(f"thickness: probe must be (k,) finite lengths >= 0, got shape {probe.shape}")

    caster = _Caster(positions, faces, epsilon)
    k = len(origins)
    ray_dirs = _cone(directions, rays, np.radians(cone_degrees), seed).reshape(-1, 3)
    ray_origins = np.repeat(origins, rays, axis=0)
    ray_offsets = np.repeat(offsets, rays, axis=0)
    # a probe shorter than the start offset would read w at the surface itself
    ray_probe = np.maximum(PROBE_EDGES * np.repeat(probe, rays), 2.0 * caster.offset)
    hit, t = caster.cast(ray_origins, ray_dirs, ray_offsets)
    counts = _settle_misses(caster, ray_origins, ray_dirs, ray_offsets, ray_probe, hit, t)
    distance = np.clip(np.nan_to_num(t, nan=cap, posinf=cap, neginf=0.0), 0.0, cap)

    thickness = distance.reshape(k, rays).mean(axis=1)
    hit_fraction = hit.reshape(k, rays).mean(axis=1)
    if owner is not None:
        # a hard vertex keeps its shortest direction: sort by (vertex, thickness), first of each vertex
        order = np.lexsort((thickness, owner))
        first = order[np.r_[True, owner[order][1:] != owner[order][:-1]]]
        thickness, hit_fraction = thickness[first], hit_fraction[first]
    return ThicknessResult(
        thickness=thickness,
        hit=hit_fraction > 0.5,
        hit_fraction=hit_fraction,
        rays=len(ray_dirs),
        **counts,
    )


def miss_warnings(result: ThicknessResult, faces: np.ndarray) -> list[str]:
    """One line per way `result`'s rays ended without meeting the surface, each opening with the
    surface's defects in parentheses (`winding.EdgeDefects.describe`, of the triangles `faces`
    (m, 3) int64); none when every ray met it."""
    if not (result.opening or result.flipped or result.no_inside):
        return []
    defects = edge_defects(faces)
    # a ray turned back on a closed surface with folds is a fold's, not an opening's
    turned = ("folded triangles" if defects.folded else "by an opening's rim" if defects.boundary
              else "normals facing inward")
    lines = ((result.opening, "met no surface; they end where the generalized winding number falls to 1/2 "
                              "(over an opening: its plane)"),
             (result.flipped, f"started with the inside behind them ({turned}); they were cast the other way"),
             (result.no_inside, "found no inside on either side (a sheet, or an opening's rim); thickness 0 there"))
    return [f"({defects.describe()}): {count} of {result.rays} thickness rays {what}" for count, what in lines if count]


def _edge_lengths(positions: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(m, 3) lengths of each triangle's edges (v0v1, v1v2, v2v0)."""
    return np.linalg.norm(positions[faces[:, [1, 2, 0]]] - positions[faces], axis=2)


def _vertex_samples(positions: np.ndarray, faces: np.ndarray, normals: np.ndarray,
                    split: tuple[np.ndarray, np.ndarray] | None) -> tuple[np.ndarray, np.ndarray, np.ndarray,
                                                                          np.ndarray]:
    """The rays of the vertices (module docstring, Hard edges).

    Parameters
    ----------
    normals : (n, 3) float64
        Unit averaged normals.
    split : ((r,) int64, (r, 3) float64) or None
        Each render vertex's vertex and unit authored normal.

    Returns
    -------
    owner : (s,) int64
        The vertex of each sample; every vertex has at least one.
    directions : (s, 3) float64
        Unit inward directions: −normal at a smooth vertex, the distinct inward split normals at a hard one.
    offsets : (s, 3) float64
        −normal of the sample's vertex: where the ray starts from.
    probe : (s,) float64
        Longest edge of the vertex's incident triangles.
    """
    n = len(positions)
    hard = np.zeros(n, dtype=bool)
    owner, directions = np.zeros(0, dtype=np.int64), np.zeros((0, 3))
    if split is not None:
        weld, copies = split
        facing = np.einsum("ij,ij->i", copies, normals[weld]) > 0
        weld, copies = weld[facing], copies[facing]
        # each copy against its vertex's first copy
        first = np.zeros((n, 3))
        _, lead = np.unique(weld, return_index=True)
        first[weld[lead]] = copies[lead]
        hard[weld[np.einsum("ij,ij->i", copies, first[weld]) < np.cos(np.radians(SPLIT_DEGREES))]] = True
        pick = hard[weld]
        # copies split only at UV seams share their normal: one ray for them
        key = np.column_stack([weld[pick], np.round(copies[pick] * 1e6).astype(np.int64)])
        _, distinct = np.unique(key, axis=0, return_index=True)
        owner, directions = weld[pick][distinct], -copies[pick][distinct]
    smooth = np.flatnonzero(~hard)
    owner = np.concatenate([smooth, owner])
    directions = np.concatenate([-normals[smooth], directions])
    longest = np.zeros(n)
    np.maximum.at(longest, faces.reshape(-1), np.repeat(_edge_lengths(positions, faces).max(axis=1), 3))
    return owner, directions, -normals[owner], longest[owner]


class _Caster:
    """Embree rays against one mesh, and its generalized winding number."""

    def __init__(self, positions: np.ndarray, faces: np.ndarray, epsilon: float):
        self.positions, self.faces = positions, faces
        self.lo, self.hi = positions.min(axis=0), positions.max(axis=0)
        # Embree works in float32: centring the mesh keeps its precision relative to the mesh size.
        self.centre = 0.5 * (self.lo + self.hi)
        self.offset = epsilon * float(np.linalg.norm(self.hi - self.lo))
        self.mesh = trimesh.Trimesh(positions - self.centre, faces, process=False, validate=False)
        self.intersector = RayMeshIntersector(self.mesh)

    def cast(self, origins: np.ndarray, directions: np.ndarray,
             offsets: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Whether each ray (r,) meets the mesh, and where: (r,) distance from its origin along its
        direction to the plane of the triangle it meets (NaN or ±Inf for a ray in that plane; NaN
        where it meets none). Rays start `offset` along `offsets` (r, 3) from `origins` (r, 3)."""
        start = origins - self.centre
        tri = self.intersector.intersects_first(start + self.offset * offsets, directions)
        hit = tri >= 0
        t = np.full(len(tri), np.nan)
        corners = self.mesh.vertices[self.mesh.faces[tri[hit]]]
        plane_normal = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
        along = np.einsum("ij,ij->i", directions[hit], plane_normal)
        reach = np.einsum("ij,ij->i", corners[:, 0] - start[hit], plane_normal)
        with np.errstate(divide="ignore", invalid="ignore"):
            t[hit] = reach / along
        return hit, t

    def margin(self, points: np.ndarray) -> np.ndarray:
        """(p,) float64 ``|w| - INSIDE`` at `points` (p, 3): positive inside the mesh."""
        return np.abs(winding_numbers(self.positions, self.faces, points)) - INSIDE

    def box_exit(self, origins: np.ndarray, directions: np.ndarray) -> np.ndarray:
        """(r,) distance along each ray to where it leaves the mesh's bounding box (>= 0)."""
        with np.errstate(divide="ignore", invalid="ignore"):
            wall = np.where(directions > 0, self.hi, self.lo)
            t = np.where(directions != 0, (wall - origins) / directions, np.inf)
        return np.maximum(t.min(axis=1), 0.0)


def _settle_misses(caster: _Caster, origins: np.ndarray, directions: np.ndarray, offsets: np.ndarray,
                   probe: np.ndarray, hit: np.ndarray, t: np.ndarray) -> dict[str, int]:
    """End the rays that met no surface by the winding number (module docstring), in place.

    Parameters
    ----------
    origins, directions, offsets : (r, 3) float64
        The rays, as `_Caster.cast` takes them; a flipped ray's direction is reversed here.
    probe : (r,) float64
        Depth of the winding-number probes.
    hit : (r,) bool
        Whether the ray met the surface (updated for flipped rays).
    t : (r,) float64
        Length of each ray (set for the rays that met nothing).

    Returns
    -------
    dict
        ``opening``, ``flipped``, ``no_inside``: how many rays ended each way.
    """
    miss = np.flatnonzero(~hit)
    if not len(miss):
        return {"opening": 0, "flipped": 0, "no_inside": 0}
    p, d, q = origins[miss], directions[miss], probe[miss]
    back_hit, back_t = caster.cast(p, -d, -offsets[miss])
    # the probe behind stays short of the surface behind, or it would read the outside beyond it
    q_back = np.where(back_hit, np.minimum(q, 0.5 * np.nan_to_num(back_t, nan=np.inf, posinf=np.inf, neginf=0.0)), q)
    probes = caster.margin(np.concatenate([p + q[:, None] * d, p - q_back[:, None] * d])) > 0
    ahead, behind = probes[: len(miss)], probes[len(miss):]
    flip = ~ahead & behind
    none = ~ahead & ~behind
    directions[miss[flip]] *= -1.0
    hit[miss[flip]] = back_hit[flip]
    t[miss[flip]] = back_t[flip]
    t[miss[none]] = 0.0
    march = ahead | (flip & ~back_hit)
    start = np.where(flip, q_back, q)[march]
    t[miss[march]] = _march(caster, p[march], directions[miss[march]], start)
    return {"opening": int(march.sum()), "flipped": int(flip.sum()), "no_inside": int(none.sum())}


def _march(caster: _Caster, origins: np.ndarray, directions: np.ndarray, start: np.ndarray) -> np.ndarray:
    """(r,) distance along each ray (r, 3) to where it first leaves the inside by the winding number,
    searched from `start` (r,) (the inside probe) to where it leaves the bounding box."""
    end = np.maximum(caster.box_exit(origins, directions), start)
    steps = start[:, None] + (end - start)[:, None] * (np.arange(MARCH_STEPS + 1) / MARCH_STEPS)
    points = origins[:, None, :] + steps[..., None] * directions[:, None, :]
    margin = caster.margin(points.reshape(-1, 3)).reshape(steps.shape)
    out = margin <= 0
    # past the bounding box |w| <= 1/2: a ray still inside at its last step ends there
    length = end.copy()
    found = np.flatnonzero(out.any(axis=1))
    first = np.argmax(out[found], axis=1)
    length[found[first == 0]] = start[found[first == 0]]
    found, first = found[first > 0], first[first > 0]
    # w is smooth along a ray that meets no surface: false position (Illinois) in the step it leaves in
    a, fa = steps[found, first - 1], margin[found, first - 1]
    b, fb = steps[found, first], margin[found, first]
    p, d = origins[found], directions[found]
    kept = np.zeros(len(found), dtype=np.int64)
    for _ in range(REFINEMENTS):
        c = (a * fb - b * fa) / (fb - fa)
        fc = caster.margin(p + c[:, None] * d)
        inward = fc > 0
        # an end kept twice in a row has its margin halved, so that the next point passes it
        fb = np.where(inward & (kept == 1), 0.5 * fb, fb)
        fa = np.where(~inward & (kept == -1), 0.5 * fa, fa)
        a, fa = np.where(inward, c, a), np.where(inward, fc, fa)
        b, fb = np.where(inward, b, c), np.where(inward, fb, fc)
        kept = np.where(inward, 1, -1)
    length[found] = (a * fb - b * fa) / (fb - fa)
    return length


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
