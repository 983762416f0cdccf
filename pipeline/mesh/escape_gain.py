"""How much more of the light entering an object leaves it than a flat semi-infinite medium lets
leave: the object's escape gain, per channel, by a random walk inside its own surface.

Every technique integrates the half-space profile R(r) over the surface, so it returns at most
the half-space total R_tot of the light that entered. A finite object returns more: light that
would wander deep into a half-space and be absorbed meets the far side of a small object instead,
and a convex surface curving away lets shallow light out more easily. Against Mitsuba 3 volpath
this is most of what the techniques lack (docs/fidelity.md: on the 20 mm sample sphere truth = 1.11
x prt for marble, 1.25, 1.20, 1.16 x for skin1, where this gain is 1.11 and 1.30, 1.18, 1.11).

The walk (units of mm, isotropic phase with the reduced coefficients, the similarity relation the
profile stands for): photons enter at area-uniform points of the surface from a diffuse
(cosine-weighted) exterior, refracted by Snell's law; each flight of length drawn with σ'_t is
cast against the surface with embree; a photon that reaches the boundary is reflected back with
the exact Fresnel reflectance from inside (total internal reflection included) or leaves; one that
does not scatters isotropically or is absorbed (analog, with probability 1 - α'). The gain is the
share that leaves over the share that leaves a plane under the same entry law, walked with the
same random numbers (the ratio's noise then partly cancels).

Where light leaves matters as much as how much: through a thin part much of it leaves on the
far side, where the half-space profile carries too little. So each photon that leaves is counted
by the side of its exit point that its light came from: in front when the exit's outward normal
faces the light the photon entered from (n_exit·ω > 0, the directions a technique's receiver
calls front-lit), behind otherwise. `core.back_share` turns the two shares into the profile's
factor (`Material.escape_gain`) and one on the light from behind (`Material.back_gain`). On a
compact object little leaves behind (a 10 mm skin1 sphere: 0.11 of 1.30 in red); on the 2 mm
sample slab more leaves behind than in front (skin1: 0.99, 1.00, 0.63 against 0.82, 1.03, 1.05).

A closed, consistently wound surface only (`winding.edge_defects`): through a hole a photon would
walk on outside. Deterministic for a given seed.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np
from embreex import rtcore_scene
from embreex.mesh_construction import TriangleMesh

from sssbake.pipeline.core.materials import Material
from sssbake.pipeline.mesh.winding import edge_defects

#: Photons per channel at least, and at most (the count grows where few leave, `TARGET_ERROR`).
PHOTONS = (16_384, 262_144)
#: Relative standard error of the plane's escape share the photon count aims at.
TARGET_ERROR = 0.005
#: Flights after which a photon still inside counts as absorbed (marble's deepest walks in a 200 mm
#: hand take ~5000).
MAX_STEPS = 200_000
#: Free paths deep the photons may start (1e-6 of the diagonal, what float32 embree resolves): a
#: channel whose start lies deeper is a half-space to its light, gain 1, not walked. Past it the walk
#: starts under the light and loses it (the 20 mm sample sphere, marble: 0.99 at 0.1 free path, 0.9
#: at 1, 0 at 40), while an object 1e5 free paths across is a half-space within 1 %.
MAX_START_DEPTH = 0.1
#: Uniforms the walk draws ahead at least (a block ends where a flight would read past it).
_BLOCK = 1 << 20


@dataclass(frozen=True)
class EscapeGain:
    """Attributes
    ----------
    gain : (3,) float
        Escape share in the object over that of the plane, per channel (1 for an open surface).
    front, back : (3,) float
        The parts of `gain` that leave in front of and behind the light they entered from
        (front + back = gain; the plane's all leave in front).
    escape, plane : (3,) float
        The two shares.
    photons : (3,) int
    behind : (3,) int
        Photons that left behind (the back share's count: its relative error is ~1/sqrt(behind)).
    closed : bool
        Whether the surface was closed (otherwise nothing was walked).
    """

    gain: tuple[float, float, float]
    front: tuple[float, float, float]
    back: tuple[float, float, float]
    escape: tuple[float, float, float]
    plane: tuple[float, float, float]
    photons: tuple[int, int, int]
    behind: tuple[int, int, int]
    closed: bool


def escape_gain(positions: np.ndarray, faces: np.ndarray, mm_per_unit: float, material: Material,
                seed: int = 1, closed: bool | None = None) -> EscapeGain:
    """The escape gain of `material` inside the surface `faces` (m, 3) over `positions` (n, 3)
    (file units, `mm_per_unit` mm each): see the module docstring. `closed`: the surface's
    ``winding.edge_defects(faces).closed`` where the caller has it already."""
    faces = np.asarray(faces, dtype=np.int64)
    if closed is None:
        closed = edge_defects(faces).closed
    if not closed:  # an opening lets photons out; a fold turns an entry normal inward
        one, zero = (1.0, 1.0, 1.0), (0.0, 0.0, 0.0)
        return EscapeGain(one, one, zero, zero, zero, (0, 0, 0), (0, 0, 0), False)
    x = np.asarray(positions, dtype=np.float64) * float(mm_per_unit)
    x = x - 0.5 * (x.min(axis=0) + x.max(axis=0))  # embree is float32: centred keeps its precision
    triangles = x[faces]
    normal = np.cross(triangles[:, 1] - triangles[:, 0], triangles[:, 2] - triangles[:, 0])
    area = 0.5 * np.linalg.norm(normal, axis=1)
    keep = area > 0
    triangles, normal, area = triangles[keep], normal[keep] / (2.0 * area[keep, None]), area[keep]
    # outward: a closed surface wound inward has a negative signed volume
    if np.einsum("ij,ij->", triangles[:, 0], np.cross(triangles[:, 1], triangles[:, 2])) < 0:
        normal = -normal
    scene = rtcore_scene.EmbreeScene()
    TriangleMesh(scene, triangles.reshape(-1, 3).astype(np.float32),
                 np.arange(3 * len(triangles), dtype=np.int32).reshape(-1, 3))
    offset = 1e-6 * float(np.linalg.norm(np.ptp(x, axis=0)))
    gains, fronts, backs, escapes, planes, counts, behinds = [], [], [], [], [], [], []
    for c in range(3):
        s, a = material.sigma_s_prime[c], material.sigma_a[c]
        if (s + a) * offset > MAX_START_DEPTH:  # a half-space to this channel's light
            for shares, value in zip((gains, fronts, backs, escapes, planes, counts, behinds), (1.0, 1.0, 0.0, 0.0,
                                                                                               0.0, 0, 0)):
                shares.append(value)
            continue
        plane, _ = _walk(None, s, a, material.eta, PHOTONS[0], seed)
        photons = int(np.clip((1.0 - plane) / max(plane, 1e-12) / TARGET_ERROR ** 2, *PHOTONS))
        if photons > PHOTONS[0]:
            plane, _ = _walk(None, s, a, material.eta, photons, seed)
        inside, behind = _walk((scene, triangles, normal, area, offset), s, a, material.eta, photons, seed)
        if plane > 0:
            gains.append(inside / plane)
            fronts.append((inside - behind) / plane)
            backs.append(behind / plane)
        else:  # nothing leaves either (no scattering to speak of): the half-space stands
            gains.append(1.0), fronts.append(1.0), backs.append(0.0)
        escapes.append(inside)
        planes.append(plane)
        counts.append(photons)
        behinds.append(int(round(behind * photons)))
    return EscapeGain(tuple(gains), tuple(fronts), tuple(backs), tuple(escapes), tuple(planes), tuple(counts),
                      tuple(behinds), True)


def _walk(body, sigma_s: float, sigma_a: float, eta: float, photons: int, seed: int) -> tuple[float, float]:
    """The shares of `photons` entering `body` (embree scene, triangles, outward unit normals,
    areas, start offset; None: the plane z = 0 over the medium z < 0) that leave it, in all and
    behind the light they entered from."""
    rng = np.random.default_rng(seed)
    sigma_t = sigma_s + sigma_a
    albedo = sigma_s / sigma_t
    if body is None:
        p, n, offset = np.zeros((photons, 3)), np.tile([0.0, 0.0, 1.0], (photons, 1)), 0.0
    else:
        scene, triangles, normal, area, offset = body
        f = rng.choice(len(triangles), photons, p=area / area.sum())
        u, v = rng.random(photons), rng.random(photons)
        flip = u + v > 1.0
        u[flip], v[flip] = 1.0 - u[flip], 1.0 - v[flip]
        t = triangles[f]
        p = t[:, 0] + u[:, None] * (t[:, 1] - t[:, 0]) + v[:, None] * (t[:, 2] - t[:, 0])
        n = normal[f]
    # diffuse exterior light, refracted: sin θ_t = sin θ_e / η with cos² θ_e uniform
    sin_t = np.sqrt(1.0 - rng.random(photons)) / eta
    phi = 2.0 * np.pi * rng.random(photons)
    helper = np.where(np.abs(n[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    t1 = np.cross(n, helper)
    t1 /= np.linalg.norm(t1, axis=1)[:, None]
    t2 = np.cross(n, t1)
    d = (-np.sqrt(1.0 - sin_t ** 2)[:, None] * n + (sin_t * np.cos(phi))[:, None] * t1
         + (sin_t * np.sin(phi))[:, None] * t2)
    # towards the light each photon came from (the exterior direction, before refraction)
    sin_e = eta * sin_t
    light = (np.sqrt(1.0 - sin_e ** 2)[:, None] * n - (sin_e * np.cos(phi))[:, None] * t1
             - (sin_e * np.sin(phi))[:, None] * t2)
    # Only the photons still inside are kept, compacted in place after each flight (the first m
    # rows of `state`). Every random number after the entry is read in order from blocks the
    # generator draws ahead (numpy draws a block as it draws its parts one after another), in the
    # order and sizes the photons' fates ask for them, and each flight's length from the block's
    # log1p taken in numpy (the compiled log1p differs in the last bit). The plane's flights all
    # run compiled; inside, each calls embree between two compiled passes. A few calls per flight,
    # not the two dozen numpy ones that took most of the walk once few photons were left.
    state = np.ascontiguousarray(np.hstack((p - offset * n, d, light)))
    walls = np.array([[0.0, 0.0, 1.0]]) if body is None else normal
    flight, distance, wall = np.empty(photons), np.empty(photons), np.empty(photons, dtype=np.int32)
    origin, direction = np.empty((photons, 3), dtype=np.float32), np.empty((photons, 3), dtype=np.float32)
    reach = np.empty(photons, dtype=np.float32)
    uniform, counts = np.empty(0), np.zeros(3, dtype=np.int64)  # left, behind, flights
    m, at = photons, 0
    while m and counts[2] < MAX_STEPS:
        if len(uniform) - at < 4 * m:  # a flight reads at most 4 per photon
            uniform = np.concatenate((uniform[at:], rng.random(max(4 * photons, _BLOCK))))
            logs, at = np.log1p(-uniform), 0
        if body is None:
            m, at = _plane_flights(state, m, uniform, logs, at, sigma_t, albedo, eta, flight, wall, distance, walls,
                                   counts)
            continue
        at = _rays(state, m, logs, at, sigma_t, flight, origin, direction, reach)
        found = scene.run(origin[:m], direction[:m], dists=reach[:m], output=1)
        wall[:m], distance[:m] = found["primID"], found["tfar"]
        m, at = _fly(state, m, flight, wall, distance, walls, uniform, at, albedo, eta, offset, counts)
        counts[2] += 1
    return int(counts[0]) / photons, int(counts[1]) / photons


@numba.njit(cache=True, nogil=True)
def _plane_flights(state, m, uniform, logs, at, sigma_t, albedo, eta, flight, wall, distance, walls, counts):
    """Flights of the first m photons of `state` under the plane z = 0 (`_fly`'s, meeting it where
    they fly up past it) while `uniform` from `at` holds a flight's worth and `counts[2]` (flights
    so far) is under `MAX_STEPS`; their flight lengths -logs / sigma_t. Returns m and `at` after."""
    while m and len(uniform) - at >= 4 * m and counts[2] < MAX_STEPS:
        for k in range(m):
            flight[k] = -logs[at + k] / sigma_t
            up = state[k, 5] > 0.0
            distance[k] = -state[k, 2] / state[k, 5] if up else np.inf
            wall[k] = 0 if up and distance[k] < flight[k] else -1
        m, at = _fly(state, m, flight, wall, distance, walls, uniform, at + m, albedo, eta, 0.0, counts)
        counts[2] += 1
    return m, at


@numba.njit(cache=True, nogil=True)
def _rays(state, m, logs, at, sigma_t, flight, origin, direction, reach):
    """The flight lengths -logs[at:at + m] / sigma_t of the first m photons of `state` into
    `flight`, and their rays for embree (float32 origins, directions and lengths). Returns `at` after."""
    for k in range(m):
        flight[k] = -logs[at + k] / sigma_t
        for a in range(3):
            origin[k, a] = state[k, a]
            direction[k, a] = state[k, 3 + a]
        reach[k] = flight[k]
    return at + m


@numba.njit(cache=True, nogil=True)
def _fly(state, m, flight, wall, distance, walls, uniform, at, albedo, eta, offset, counts):
    """One flight of the first m photons of `state` (m, 9): position, direction, towards its light,
    in place, the photons still inside compacted to its first rows in order. A photon whose `wall`
    (m,) is >= 0 meets the surface of normal ``walls[wall]`` after `distance` (m,) and leaves with
    Fresnel's transmittance at its outside angle or is reflected (`offset` back inside); the others
    fly `flight` (m,) and are absorbed or scatter isotropically. The uniforms are read from
    `uniform` at `at` in blocks: one per free photon (absorbed?), then one per scattered one (cos θ),
    one per scattered one (azimuth), one per photon at the wall (leaves?), each in photon order.
    Adds the photons that left, and of them those that left behind their light (n_exit·ω < 0), to
    counts[0] and counts[1].

    Returns
    -------
    m, at : int
        Photons still inside; the next uniform's index.
    """
    met = 0
    for k in range(m):
        met += wall[k] >= 0
    absorbed, scattered = at, 0
    for j in range(m - met):
        scattered += uniform[absorbed + j] < albedo
    z = absorbed + m - met
    angle = z + scattered
    leave = angle + scattered
    kept = 0
    for k in range(m):
        hit = wall[k] >= 0
        step = distance[k] if hit else flight[k]
        stays = True
        for a in range(3):
            state[k, a] += step * state[k, 3 + a]
        if not hit:
            if uniform[absorbed] >= albedo:
                stays = False
            else:
                cos_z = 2.0 * uniform[z] - 1.0
                r, phi = np.sqrt(1.0 - cos_z * cos_z), 2.0 * np.pi * uniform[angle]
                state[k, 3], state[k, 4], state[k, 5] = r * np.cos(phi), r * np.sin(phi), cos_z
                z, angle = z + 1, angle + 1
            absorbed += 1
        else:
            w = walls[wall[k]]
            cos_i = state[k, 3] * w[0] + state[k, 4] * w[1] + state[k, 5] * w[2]
            sign = 1.0 if cos_i > 0.0 else (-1.0 if cos_i < 0.0 else 0.0)  # towards the outward normal
            cos_i = abs(cos_i)
            # leaving: the transmittance at the outside angle (reciprocity), 0 past the critical angle
            cos_out = np.sqrt(min(max(1.0 - eta * eta * (1.0 - cos_i * cos_i), 0.0), 1.0))
            if uniform[leave] < _transmittance(eta, cos_out):
                counts[0] += 1
                if sign * (w[0] * state[k, 6] + w[1] * state[k, 7] + w[2] * state[k, 8]) < 0.0:
                    counts[1] += 1
                stays = False
            else:
                for a in range(3):
                    outward = w[a] * sign
                    state[k, 3 + a] -= 2.0 * cos_i * outward
                    state[k, a] -= offset * outward
            leave += 1
        if stays:
            if kept != k:
                state[kept] = state[k]
            kept += 1
    return kept, leave


@numba.njit(cache=True, nogil=True)
def _transmittance(eta, cos_i):
    """`fresnel.fresnel_transmittance` of one cosine, compiled."""
    ci = min(max(cos_i, 0.0), 1.0)
    ct = np.sqrt(min(max(1.0 - (1.0 - ci * ci) / (eta * eta), 0.0), 1.0))
    if ci <= 0.0:  # grazing: total reflection
        return 0.0
    rs = (ci - eta * ct) / (ci + eta * ct)
    rp = (eta * ci - ct) / (eta * ci + ct)
    return min(max(1.0 - 0.5 * (rs * rs + rp * rp), 0.0), 1.0)
