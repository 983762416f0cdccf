"""Compiled loops of the scatter gather's entries: each row's exact pairs (`near_field.NearField`)
and vertex-cluster terms (`scatter_operator._KernelTable`) computed and written straight into CSR.

The numpy formulation built per-pair temporaries (offsets, masks, per-case index arrays, sub-
triangle expansions) and then stacked them: ~330 ns per stored entry on the 50k dragon, 69 % of
prt's precompute. Here every entry is computed once in registers and written in place, in two
passes over blocks of rows: one counts each row's entries per channel (distances only) so that
the CSR arrays are allocated once at their final size, the other fills them. Both release the
GIL, so the callers' threads run blocks side by side.

Also compiled: the plan's descent to child cell pairs (`child_pairs`) and the operator's apply
(`csr_rows_product`, `shared_rows_product`, `cluster_moments`): scipy's products read the 2 GB
operator of the 150k dragon once per thread's block of columns, ~3.5× the CPU per column of one
pass over all columns.

The arithmetic follows the numpy definitions term by term (`profile.diffuse_reflectance_profile`,
`disc_average.DiscMean`, and the disc mean's numpy form in tests/disc_reference.py), with two
departures below float32 rounding (tests compare against the numpy forms):

- Rd and the disc expansion read a table in ln r (`radial_table`, ~1e-7 relative) instead of
  summing 18 poles × 3 channels of exponentials per evaluation (the sub-triangles of close
  pairs take millions of them);
- the triangle rules take their angles by atan2, not acos, which lost half the digits near 0
  and π (entries moved by ~1e-8 when the mesh was rotated).

Arrays are passed as a few typed arguments (numba cannot take the dataclasses): a *profile*
is its (P, 3) weight, depth and sigma; a *disc* is ``(log_a0, table, gauss_x, gauss_w,
polar_rho, polar_cos, polar_weight, z_min, sigma_tr, radial, a, t)`` (`radial_table`; the table
filled as it is read, `table_cell`, on the grid of radii a and of d/a t); a *field* the
arrays of `NearField` (`NearField.kernel_args` builds them all).
"""

from __future__ import annotations

import math

import numba
import numpy as np

from sssbake.pipeline.core.disc_average import (
    EDGE_BAND,
    EDGE_SHARP,
    LOG_A_STEP,
    OFF_PLANE,
    POINT_REACH,
    POINT_SIGMA,
    POLAR_HEIGHT,
    SMALL_TILTED,
    T_STEP,
    TABLE_REACH,
)

_FOUR_PI = 4.0 * math.pi
#: Step in ln r of `radial_table`, and its reach in decay lengths 1/σ_tr: there the far tail
#: e^(-σ_tr r) makes the 4-point rule's error ~(step σ_tr r)⁴/24 ~1e-7 relative.
RADIAL_STEP = 2e-3
RADIAL_DECAYS = 20.0

_jit = numba.njit(cache=True, nogil=True)
_inline = numba.njit(cache=True, nogil=True, inline="always")


@_jit
def _expansion(r, a, h, weight, depth, sigma, out):
    """Rd + ½ tr(H Σ) of a disc of radius a seen from h off its plane, clipped at 0, into out (3,)
    (`disc_reference.disc_expansion` in tests)."""
    r2 = r * r
    c2 = h * h / r2 if r > 0.0 else 0.0
    spread = 0.125 * a * a
    for c in range(3):
        total = 0.0
        for p in range(weight.shape[0]):
            w = weight[p, c]
            if w == 0.0:
                continue
            z = depth[p, c]
            d2 = r2 + z * z
            d = math.sqrt(d2)
            big_p = sigma[p, c] * d
            q2 = big_p * (big_p + 3.0) + 3.0
            q3 = big_p * (big_p * (big_p + 5.0) + 12.0) + 12.0
            bracket = ((1.0 - c2) * (q3 * r2 - q2 * (z * z)) / d2 - (1.0 + c2) * q2) * (spread / d2) + (1.0 + big_p)
            total += w * z * math.exp(-big_p) / (d2 * d) * bracket
        out[c] = max(total / _FOUR_PI, 0.0)


def radial_table(weight: np.ndarray, depth: np.ndarray, sigma: np.ndarray, r_lo: float, r_hi: float) -> tuple:
    """Rd and the disc expansion's two spread terms per channel on a grid of ln r, for `_radial`.

    `_expansion` is A(r) + (a²/8)(U(r) - c² V(r)) with A = Rd and U, V sums over the poles of
    e^(-P)/D⁵ polynomials: three functions of r alone. Tabulated at `RADIAL_STEP` in ln r and
    read by 4-point Lagrange interpolation (error ~ step⁴ f⁗/24 in ln r; tests compare against
    `_expansion`): one logarithm and a few dozen products instead of a square root and an
    exponential per pole and channel.

    Returns
    -------
    (u0, 1/step, values (3, 3, N)): ln r of the first node, its inverse step, and per channel
    (A, U, V) / 4π at the nodes; r outside [r_lo, r_hi] is left to `_expansion`.
    """
    u = np.arange(np.log(r_lo) - 2 * RADIAL_STEP, np.log(r_hi) + 3 * RADIAL_STEP, RADIAL_STEP)
    r2 = np.exp(2.0 * u)
    values = np.zeros((3, 3, len(u)))
    for c in range(3):
        for w, z, s in zip(weight[:, c], depth[:, c], sigma[:, c]):
            if w == 0.0:
                continue
            d2 = r2 + z * z
            d = np.sqrt(d2)
            big_p = s * d
            q2 = big_p * (big_p + 3.0) + 3.0
            q3 = big_p * (big_p * (big_p + 5.0) + 12.0) + 12.0
            base = w * z * np.exp(-big_p) / (d2 * d)
            f, g = base * (q3 * r2 - q2 * (z * z)) / (d2 * d2), base * q2 / d2
            values[c, 0] += base * (1.0 + big_p)
            values[c, 1] += f - g
            values[c, 2] += f + g
    return float(u[0]), 1.0 / RADIAL_STEP, values / _FOUR_PI


@_inline
def lagrange4(f):
    """Weights of 4-point Lagrange interpolation at i + f (0 <= f < 1) from the nodes i - 1 .. i + 2."""
    return (-f * (f - 1.0) * (f - 2.0) / 6.0, (f + 1.0) * (f - 1.0) * (f - 2.0) / 2.0,
            -(f + 1.0) * f * (f - 2.0) / 2.0, (f + 1.0) * f * (f - 1.0) / 6.0)


@_inline
def _radial(r, a, h, radial, weight, depth, sigma, out):
    """`_expansion` (a = 0: Rd) from `radial_table`, or exactly outside its range."""
    u0, inv_step, values = radial
    u = (math.log(r) - u0) * inv_step if r > 0.0 else -1.0
    i = int(u)
    if u < 1.0 or i + 2 >= values.shape[2]:
        _expansion(r, a, h, weight, depth, sigma, out)
        return
    w0, w1, w2, w3 = lagrange4(u - i)
    spread = 0.125 * a * a
    c2 = h * h / (r * r)
    for c in range(3):
        t = w0 * values[c, 0, i - 1] + w1 * values[c, 0, i] + w2 * values[c, 0, i + 1] + w3 * values[c, 0, i + 2]
        if spread > 0.0:
            uu = w0 * values[c, 1, i - 1] + w1 * values[c, 1, i] + w2 * values[c, 1, i + 1] + w3 * values[c, 1, i + 2]
            vv = w0 * values[c, 2, i - 1] + w1 * values[c, 2, i] + w2 * values[c, 2, i + 1] + w3 * values[c, 2, i + 2]
            t += spread * (uu - c2 * vv)
        out[c] = max(t, 0.0)


@_jit
def _cumulative_pole(r, h, w, z, s):
    """One pole's share of G(r) above height h (`disc_reference._cumulative` in tests), before the ½."""
    r2 = r * r
    lifted = math.sqrt(h * h + z * z)
    excess = r2 / (math.sqrt(r2 + lifted * lifted) + lifted)
    return w * z * math.exp(-s * lifted) / lifted * -math.expm1(-math.log1p(excess / lifted) - s * excess)


@_jit
def _tail_pole(r, h, w, z, s):
    """One pole's share of H(r) above height h (`disc_reference._tail` in tests), before the ½."""
    dist = math.sqrt(r * r + h * h + z * z)
    return w * z * math.exp(-s * dist) / dist


@_jit
def disc_mean_exact_one(d, a, h, weight, depth, sigma, gauss_x, gauss_w, out):
    """Exact mean of Rd over a disc (`disc_reference.disc_mean_exact` in tests) for one (d, a, h), into out (3,)."""
    t = d / a
    for c in range(3):
        out[c] = 0.0
    if t < 1.0:
        for k in range(len(gauss_x)):
            phi = 0.5 * math.pi * (gauss_x[k] + 1.0)
            rho = a * (t * math.cos(phi) + math.sqrt(max(1.0 - (t * math.sin(phi)) ** 2, 0.0)))
            for c in range(3):
                g = 0.0
                for p in range(weight.shape[0]):
                    if weight[p, c] != 0.0:
                        g += _cumulative_pole(rho, h, weight[p, c], depth[p, c], sigma[p, c])
                out[c] += gauss_w[k] * 0.5 * g
        for c in range(3):
            out[c] *= 0.5 / (math.pi * a * a)
        return
    for k in range(len(gauss_x)):
        psi = 0.25 * math.pi * (gauss_x[k] + 1.0)
        cos_phi = math.sqrt(max(1.0 - (math.sin(psi) / t) ** 2, 0.0))
        near = a * (t * cos_phi - math.cos(psi))
        far = a * (t * cos_phi + math.cos(psi))
        jac = math.cos(psi) / max(t * cos_phi, 1e-300)
        for c in range(3):
            band = 0.0
            for p in range(weight.shape[0]):
                if weight[p, c] == 0.0:
                    continue
                band += (_tail_pole(near, h, weight[p, c], depth[p, c], sigma[p, c])
                         - _tail_pole(far, h, weight[p, c], depth[p, c], sigma[p, c]))
            out[c] += gauss_w[k] * jac * 0.5 * band
    for c in range(3):
        out[c] *= (0.25 * math.pi) / (math.pi * math.pi * a * a)


@_inline
def table_cell(table, i, j, a, t, weight, depth, sigma, gauss_x, gauss_w, value):
    """Makes sure cell (i, j) of the disc table (3, A, T) holds ln of the exact disc mean at radius
    a[i] and d/a = t[j] (`disc_average.DiscMean`): computed on its first read; value (3,) is overwritten.

    The table starts as NaN and every cell is a function of (i, j) alone, so each channel's value
    is its own flag: a thread that sees NaN computes the cell (two threads at once write the same
    bits), one that sees a number reads it, whatever the order of the threads' stores."""
    if math.isnan(table[0, i, j]) or math.isnan(table[1, i, j]) or math.isnan(table[2, i, j]):
        disc_mean_exact_one(a[i] * t[j], a[i], 0.0, weight, depth, sigma, gauss_x, gauss_w, value)
        for c in range(3):
            table[c, i, j] = math.log(max(value[c], 1e-300))


@numba.njit(cache=True, nogil=True)
def disc_mean_rows(a, t, weight, depth, sigma, gauss_x, gauss_w, out, i0, i1):
    """Rows i0..i1-1 of the disc table (3, A, T) on the grid a (A,) × d/a (T,): every cell not
    filled yet (`table_cell`), for readers of the whole table (`DiscMean.log_table`)."""
    value = np.empty(3)
    for i in range(i0, i1):
        for j in range(len(t)):
            table_cell(out, i, j, a, t, weight, depth, sigma, gauss_x, gauss_w, value)


@_inline
def _disc(d, a, h, weight, depth, sigma, disc, out, scratch):
    """ḡ of a disc of radius a at distance d, the receiver h off its plane, into out (3,)
    (`disc_reference.disc_mean` in tests); scratch (3,) is overwritten."""
    log_a0, table, gauss_x, gauss_w, polar_rho, polar_cos, polar_weight, z_min, sigma_tr, radial, a_grid, t_grid = disc
    h = min(h, d)
    t = d / max(a, 1e-300)
    u = (math.log(max(a, 1e-300)) - log_a0) / LOG_A_STEP
    close = t <= TABLE_REACH and u >= 0.0
    tabled = close and h <= OFF_PLANE * d
    edge = tabled and abs(t - 1.0) < EDGE_BAND and a > EDGE_SHARP * z_min
    tabled = tabled and not edge
    tilted = close and not tabled and a > SMALL_TILTED * math.sqrt(d * d + z_min * z_min)
    if tilted:  # written last in the numpy form: it wins over `edge`
        along = math.sqrt(max(d * d - h * h, 0.0))
        if h < POLAR_HEIGHT * a:
            disc_mean_exact_one(along, a, h, weight, depth, sigma, gauss_x, gauss_w, out)
        else:
            for c in range(3):
                out[c] = 0.0
            for k in range(len(polar_rho)):
                ar = a * polar_rho[k]
                r2 = h * h + along * along + ar * ar - 2.0 * along * ar * polar_cos[k]
                _radial(math.sqrt(r2), 0.0, 0.0, radial, weight, depth, sigma, scratch)
                for c in range(3):
                    out[c] += polar_weight[k] * scratch[c]
    elif edge:
        disc_mean_exact_one(d, a, 0.0, weight, depth, sigma, gauss_x, gauss_w, out)
    elif tabled:
        ui = min(max(u, 0.0), table.shape[1] - 1.000001)
        ti = min(max(t / T_STEP, 0.0), table.shape[2] - 1.000001)
        i, j = int(ui), int(ti)
        fu, ft = ui - i, ti - j
        for di in range(2):
            for dj in range(2):
                table_cell(table, i + di, j + dj, a_grid, t_grid, weight, depth, sigma, gauss_x, gauss_w, out)
        for c in range(3):
            v = ((1 - fu) * ((1 - ft) * table[c, i, j] + ft * table[c, i, j + 1])
                 + fu * ((1 - ft) * table[c, i + 1, j] + ft * table[c, i + 1, j + 1]))
            out[c] = math.exp(v)
    elif d > POINT_REACH * a and a * sigma_tr < POINT_SIGMA:
        _radial(d, 0.0, 0.0, radial, weight, depth, sigma, out)
    else:
        _radial(d, a, h, radial, weight, depth, sigma, out)


@_inline
def _apex_triangle(ax, ay, az, px, py, pz, qx, qy, qz, log_r0, log_g, slope, g_table, steps, gauss_x, gauss_w, sign,
                   out):
    """Adds sign · ∫ Rd(|x - apex|) dx over the triangle (apex, p, q) to out (3,) (`cell_integral.apex_triangle`)."""
    e1x, e1y, e1z = px - ax, py - ay, pz - az
    e2x, e2y, e2z = qx - ax, qy - ay, qz - az
    cx, cy, cz = e1y * e2z - e1z * e2y, e1z * e2x - e1x * e2z, e1x * e2y - e1y * e2x
    double_area = math.sqrt(cx * cx + cy * cy + cz * cz)
    if not double_area > 1e-300:
        return
    fx, fy, fz = qx - px, qy - py, qz - pz
    length = math.sqrt(fx * fx + fy * fy + fz * fz)
    # The angles as atan2 of their sine and cosine: acos, as in the numpy form, loses half the
    # digits near 0 and π (right angles at p are common), where rotating the mesh then moved
    # entries by ~1e-8.
    angle = math.atan2(double_area, e1x * e2x + e1y * e2y + e1z * e2z)
    foot = double_area / length
    along = -(e1x * fx + e1y * fy + e1z * fz) / length  # from p towards the foot
    to_foot = math.atan2(abs(along), foot)
    if along < 0.0:
        to_foot = -to_foot
    last = log_g.shape[1] - 1
    scale = sign * (0.5 * angle / (2.0 * math.pi))
    for k in range(len(gauss_x)):
        phi = 0.5 * angle * (gauss_x[k] + 1.0)
        rho = foot / max(math.cos(phi - to_foot), 1e-12)
        u = (math.log(max(rho, 1e-300)) - log_r0) * steps
        at = min(max(u, 0.0), last)
        i = int(at)
        f = at - i
        if u < 0.0:  # below the table G ∝ r²
            below = u * (2.0 / steps)
            for c in range(3):
                out[c] += scale * gauss_w[k] * math.exp(log_g[c, i] + below)
            continue
        for c in range(3):
            # exp(log_g + f·slope) as G_i e^(f·slope): the step in ln G is at most 2/steps
            # (G ∝ r² at most), so Taylor to the 6th order is exact to double rounding (x⁷/7! < 1e-18).
            x = f * slope[c, i]
            e = 1.0 + x * (1.0 + x * (0.5 + x * (1.0 / 6.0 + x * (1.0 / 24.0 + x * (1.0 / 120.0 + x * (1.0 / 720.0))))))
            out[c] += scale * gauss_w[k] * (g_table[c, i] * e)


@_jit
def apex_triangles(apex, p, q, log_r0, log_g, slope, g_table, steps, gauss_x, gauss_w):
    """∫ Rd(|x - apex|) dx over triangles (apex[k], p[k], q[k]), (m, 3) each -> (m, 3)."""
    out = np.zeros((len(apex), 3))
    for k in range(len(apex)):
        _apex_triangle(apex[k, 0], apex[k, 1], apex[k, 2], p[k, 0], p[k, 1], p[k, 2], q[k, 0], q[k, 1], q[k, 2],
                       log_r0, log_g, slope, g_table, steps, gauss_x, gauss_w, 1.0, out[k])
    return out


@_jit
def triangles_in_plane(point, a, b, c, log_r0, log_g, slope, g_table, steps, gauss_x, gauss_w):
    """∫ Rd(|x - point[k]|) dx over triangles (a[k], b[k], c[k]) in the point's plane, (m, 3) each -> (m, 3)."""
    out = np.zeros((len(point), 3))
    tri = np.empty((3, 3))
    for k in range(len(point)):
        tri[0], tri[1], tri[2] = a[k], b[k], c[k]
        _triangle_in_plane(point[k], tri, log_r0, log_g, slope, g_table, steps, gauss_x, gauss_w, out[k])
    return out


@_inline
def _triangle_in_plane(point, tri, log_r0, log_g, slope, g_table, steps, gauss_x, gauss_w, out):
    """Adds ∫ Rd(|p - point|) dp over the triangle tri (3, 3) to out (3,): the signed sum of the
    triangles (point, edge) (`cell_integral.triangle_integral_in_plane`)."""
    ux, uy, uz = tri[1, 0] - tri[0, 0], tri[1, 1] - tri[0, 1], tri[1, 2] - tri[0, 2]
    vx, vy, vz = tri[2, 0] - tri[0, 0], tri[2, 1] - tri[0, 1], tri[2, 2] - tri[0, 2]
    nx, ny, nz = uy * vz - uz * vy, uz * vx - ux * vz, ux * vy - uy * vx
    for e in range(3):
        p, q = tri[e], tri[(e + 1) % 3]
        ax, ay, az = p[0] - point[0], p[1] - point[1], p[2] - point[2]
        bx, by, bz = q[0] - point[0], q[1] - point[1], q[2] - point[2]
        turn = (ay * bz - az * by) * nx + (az * bx - ax * bz) * ny + (ax * by - ay * bx) * nz
        if turn != 0.0:
            _apex_triangle(point[0], point[1], point[2], p[0], p[1], p[2], q[0], q[1], q[2],
                           log_r0, log_g, slope, g_table, steps, gauss_x, gauss_w, 1.0 if turn > 0.0 else -1.0, out)


@_inline
def _is_point(o, i, d, a, sigma_tr):
    """Whether source i (disc radius a) is a point to receiver o at distance d (`DiscMean.is_point`)."""
    return o != i and d > POINT_REACH * a and a * sigma_tr < POINT_SIGMA


@_jit
def pair_weight(o, i, field, weight, depth, sigma, disc, cumulative, out, scratch):
    """∫_{cell_i} Rd(|p - x_o|) dp into out (3,) (`near_field.NearField.weights`).

    field = (positions, area, radius, normals, own, sub_ptr, sub_corners, sub_normal, sub_area,
    sub_face, zone); cumulative = (log_r0, log_g, slope, g_table, steps, gauss_x, gauss_w) of
    `cell_integral.Cumulative` (`Cumulative.kernel_args`) with the `cell_integral.NODES_BESIDE`
    rule; scratch (6,) is overwritten."""
    x, area, radius, normals, own, sub_ptr, sub_corners, sub_normal, sub_area, sub_face, zone = field
    log_r0, log_g, slope, g_table, steps, beside_x, beside_w = cumulative
    sigma_tr, radial = disc[8], disc[9]
    dx, dy, dz = x[o, 0] - x[i, 0], x[o, 1] - x[i, 1], x[o, 2] - x[i, 2]
    d = math.sqrt(dx * dx + dy * dy + dz * dz)
    a = radius[i]
    if _is_point(o, i, d, a, sigma_tr):
        # Most pairs far from small sources: the point value (`DiscMean.is_point`).
        _radial(d, 0.0, 0.0, radial, weight, depth, sigma, out)
        for c in range(3):
            out[c] *= area[i]
    elif o == i:
        for c in range(3):
            out[c] = own[o, c]
    elif d < zone * (radius[o] + a):
        # Close: the source's sub-triangles, exactly where they share a triangle with the receiver.
        for c in range(3):
            out[c] = 0.0
        one, inner = scratch[:3], scratch[3:]
        for s in range(sub_ptr[i], sub_ptr[i + 1]):
            if sub_face[s, 0] == o or sub_face[s, 1] == o or sub_face[s, 2] == o:
                _triangle_in_plane(x[o], sub_corners[s], log_r0, log_g, slope, g_table, steps, beside_x, beside_w, out)
            else:
                cen = (sub_corners[s, 0] + sub_corners[s, 1] + sub_corners[s, 2]) / 3.0
                sx, sy, sz = x[o, 0] - cen[0], x[o, 1] - cen[1], x[o, 2] - cen[2]
                dist = math.sqrt(sx * sx + sy * sy + sz * sz)
                h = abs(sx * sub_normal[s, 0] + sy * sub_normal[s, 1] + sz * sub_normal[s, 2])
                _disc(dist, math.sqrt(sub_area[s] / math.pi), h, weight, depth, sigma, disc, one, inner)
                for c in range(3):
                    out[c] += one[c] * sub_area[s]
    else:
        h = abs(dx * normals[i, 0] + dy * normals[i, 1] + dz * normals[i, 2])
        _disc(d, a, h, weight, depth, sigma, disc, out, scratch)
        for c in range(3):
            out[c] *= area[i]


@_jit
def pair_weights(o, i, field, weight, depth, sigma, disc, cumulative):
    """`pair_weight` of pairs (o[k], i[k]): (m, 3)."""
    out = np.empty((len(o), 3))
    scratch = np.empty(6)
    for k in range(len(o)):
        pair_weight(o[k], i[k], field, weight, depth, sigma, disc, cumulative, out[k], scratch)
    return out


@_jit
def pair_counts(j0, j1, rows, keys, ptr, lists, range_ptr, targets, sources, radius, counts):
    """Entries of rows j0..j1 - 1 into counts (4, T): per channel c < 3 the sources within the
    channel's radius of target rows[j], and in counts[3] those within the largest radius (the
    channels' patterns' union, which a shared layout stores).

    Row j's sources are sources[range_ptr[g]] .. sources[range_ptr[g + 1] - 1] (3,) each, for
    each g in lists[ptr[keys[j]]:ptr[keys[j] + 1]] (vertices of cells, or clusters one by one)."""
    r_max = max(radius[0], radius[1], radius[2])
    for j in range(j0, j1):
        o = rows[j]
        n0 = n1 = n2 = n3 = 0
        for g in lists[ptr[keys[j]]:ptr[keys[j] + 1]]:
            for i in range(range_ptr[g], range_ptr[g + 1]):
                dx, dy, dz = targets[o, 0] - sources[i, 0], targets[o, 1] - sources[i, 1], targets[o, 2] - sources[i, 2]
                d = math.sqrt(dx * dx + dy * dy + dz * dz)
                n0 += d <= radius[0]
                n1 += d <= radius[1]
                n2 += d <= radius[2]
                n3 += d <= r_max
        counts[0, j], counts[1, j], counts[2, j], counts[3, j] = n0, n1, n2, n3


@_inline
def _put(shared, t, j, d, radius, column, value, indptr, at, indices, data):
    """Writes one source's entries (value (3,) per channel, at `column`) of row j, at the next
    place `at` (3,) of each channel's row: in a shared layout (`pair_counts` union; data (U·3,)
    as (U, 3)) one entry for the three channels, 0.0 where d is beyond the channel's radius; else
    channel c's row j is CSR row c·T + j."""
    if shared:
        k = indptr[j] + at[0]
        indices[k] = column
        for c in range(3):
            data[3 * k + c] = value[c] if d <= radius[c] else 0.0
        at[0] += 1
        return
    for c in range(3):
        if d <= radius[c]:
            k = indptr[c * t + j] + at[c]
            indices[k], data[k] = column, value[c]
            at[c] += 1


@_jit
def near_fill(j0, j1, rows, keys, ptr, lists, range_ptr, radius, field, weight, depth, sigma, disc, cumulative,
              shared, indptr, indices, data):
    """Writes the entries of rows j0..j1 - 1 (`pair_counts`, the vertices of cells) into CSR arrays,
    in the layout `_put` describes, the sources in list order."""
    x = field[0]
    t = len(rows)
    r_max = max(radius[0], radius[1], radius[2])
    value, scratch = np.empty(3), np.empty(6)
    at = np.empty(3, dtype=np.int64)
    for j in range(j0, j1):
        o = rows[j]
        at[:] = 0
        for g in lists[ptr[keys[j]]:ptr[keys[j] + 1]]:
            for i in range(range_ptr[g], range_ptr[g + 1]):
                dx, dy, dz = x[o, 0] - x[i, 0], x[o, 1] - x[i, 1], x[o, 2] - x[i, 2]
                d = math.sqrt(dx * dx + dy * dy + dz * dz)
                if d > r_max:
                    continue
                pair_weight(o, i, field, weight, depth, sigma, disc, cumulative, value, scratch)
                _put(shared, t, j, d, radius, i, value, indptr, at, indices, data)


@_jit
def far_fill(j0, j1, rows, keys, ptr, lists, xt, centroid, spread, trace, radius, log_lo, step, value, slope,
             shared, indptr, indices, data):
    """Writes the cluster kernels Rd_c(D) + ½ tr(H Σ) of rows j0..j1 - 1 (`pair_counts`, clusters one by one) into CSR
    arrays, in the layout `_put` describes, the columns the clusters (`_KernelTable` value, slope (3, 3, N))."""
    t = len(rows)
    nodes = value.shape[2]
    r_max = max(radius[0], radius[1], radius[2])
    at = np.empty(3, dtype=np.int64)
    kernel = np.empty(3)
    for j in range(j0, j1):
        o = rows[j]
        at[:] = 0
        for s in lists[ptr[keys[j]]:ptr[keys[j] + 1]]:
            dx, dy, dz = xt[0, o] - centroid[0, s], xt[1, o] - centroid[1, s], xt[2, o] - centroid[2, s]
            d2 = dx * dx + dy * dy + dz * dz
            d = math.sqrt(d2)  # >= separation · h_l > 0
            if d > r_max:
                continue
            radial = (spread[0, s] * dx * dx + spread[1, s] * dy * dy + spread[2, s] * dz * dz
                      + 2.0 * (spread[3, s] * dx * dy + spread[4, s] * dx * dz + spread[5, s] * dy * dz)) / d2
            u = (math.log(d) - log_lo) / step
            node = min(max(int(u), 0), nodes - 2)
            w = u - node
            for c in range(3):
                kernel[c] = value[c, 0, node] + w * slope[c, 0, node]
                kernel[c] += (value[c, 1, node] + w * slope[c, 1, node]) * radial
                kernel[c] += (value[c, 2, node] + w * slope[c, 2, node]) * trace[s]
            _put(shared, t, j, d, radius, s, kernel, indptr, at, indices, data)


@_inline
def _put_row(s, y, r, add):
    """y[r] = s, or y[r] += s where `add`."""
    if add:
        for c in range(len(s)):
            y[r, c] += s[c]
    else:
        for c in range(len(s)):
            y[r, c] = s[c]


@_jit
def csr_rows_product(r0, r1, indptr, indices, data, x, y, add):
    """Rows r0..r1 - 1 of the sparse product A x, A in CSR (indptr, indices, data) and x (width, K)
    dense: into y (rows, K) in place, or added to it where `add` (`scatter_operator.ChannelRows.product`).

    Each row is summed in `y`'s dtype entry by entry in CSR order, as scipy's `A @ x` does (its
    result is equal bit for bit), but over all K columns at once: the matrix is read once per
    call, not once per block of columns, and the loop over the columns vectorises."""
    k = x.shape[1]
    s = np.zeros(k, dtype=y.dtype)
    for r in range(r0, r1):
        for c in range(k):
            s[c] = 0
        for jj in range(indptr[r], indptr[r + 1]):
            a = data[jj]
            row = x[indices[jj]]
            for c in range(k):
                s[c] += a * row[c]
        _put_row(s, y, r, add)


@_jit
def shared_rows_product(o0, o1, indptr, indices, data, stride, x, y, add):
    """Rows o0..o1 - 1 of the three products A_c x_c of matrices sharing one CSR pattern (indptr,
    indices) with values data (nnz, 3), x_c's row j x[c·stride + j] (stride 0: one x for the
    three): channel c's row o into y[c·T + o] (T = len(indptr) - 1) in place, or added to it
    where `add`.

    Each (row, channel) is summed entry by entry in CSR order as `csr_rows_product` sums a row:
    its result over the channel's own entries bit for bit, the pattern's others holding 0.0 (a
    sum plus 0·x, x finite, is the sum). With one x the three sums share each index and row of x
    (the 150k dragon's exact pairs: 40 % less CPU than the split layout's three rows); else a
    row's channels go one after another, its indices then in cache, at the split layout's cost
    per stored value (three sums over three channels' rows at once took up to 50 % more)."""
    t = len(indptr) - 1
    k = x.shape[1]
    s0, s1, s2 = np.zeros(k, dtype=y.dtype), np.zeros(k, dtype=y.dtype), np.zeros(k, dtype=y.dtype)
    for o in range(o0, o1):
        lo, hi = indptr[o], indptr[o + 1]
        if stride:
            for ch in range(3):
                for c in range(k):
                    s0[c] = 0
                for jj in range(lo, hi):
                    a = data[jj, ch]
                    row = x[ch * stride + indices[jj]]
                    for c in range(k):
                        s0[c] += a * row[c]
                _put_row(s0, y, ch * t + o, add)
            continue
        for c in range(k):
            s0[c] = s1[c] = s2[c] = 0
        for jj in range(lo, hi):
            a0, a1, a2 = data[jj, 0], data[jj, 1], data[jj, 2]
            row = x[indices[jj]]
            for c in range(k):
                v = row[c]
                s0[c] += a0 * v
                s1[c] += a1 * v
                s2[c] += a2 * v
        _put_row(s0, y, o, add)
        _put_row(s1, y, t + o, add)
        _put_row(s2, y, 2 * t + o, add)


@_jit
def cluster_moments(e, weights, starts, out):
    """Per channel c and cluster s (the vertices starts[s] .. starts[s + 1] - 1, the last to the end)
    Σ_i weights[c, i] e[i, :] summed in float64 in vertex order into out[c·m + s, :] (3m, K),
    m = len(starts): numpy's `add.reduceat` of the weighted signal, but in one pass for the
    three channels and without the (n, K) product (reduceat sums pairwise: the sums differ by
    ~1e-16 relative, which float32 moments round away)."""
    n, k = e.shape
    m = len(starts)
    acc = np.zeros((3, k))
    for s in range(m):
        end = starts[s + 1] if s + 1 < m else n
        acc[:] = 0.0
        for i in range(starts[s], end):
            for c in range(3):
                w = weights[c, i]
                for j in range(k):
                    acc[c, j] += e[i, j] * w
        for c in range(3):
            for j in range(k):
                out[c * m + s, j] = acc[c, j]


@_jit
def child_pairs(pairs, first, count, coords, a):
    """The children of (target cell, source cell) pairs, split by their gap (`scatter_operator.scatter_plan`).

    Each pair (t, s) (p, 2) stands for the cells first[t] + i, i < count[t], against first[s] + j,
    j < count[s], in that order (i major); coords (m, 3) are the children's integer coordinates.
    Returns (near, far): the child pairs within `a` cells of each other in every axis and the
    others, each (q, 2) int64 in the order above. Counted first, then written: numpy's expansion
    held every child pair and its gap at once (~2 s of the 150k dragon's plan)."""
    empty = np.empty((0, 2), dtype=np.int64)
    near_count, far_count = _child_pass(pairs, first, count, coords, a, empty, empty, False)
    near = np.empty((near_count, 2), dtype=np.int64)
    far = np.empty((far_count, 2), dtype=np.int64)
    _child_pass(pairs, first, count, coords, a, near, far, True)
    return near, far


@_jit
def _child_pass(pairs, first, count, coords, a, near, far, write):
    """`child_pairs`' walk over the child pairs: their near and far counts, each written into
    `near` or `far` where `write`."""
    near_at = far_at = 0
    for p in range(pairs.shape[0]):
        t, s = pairs[p, 0], pairs[p, 1]
        for i in range(first[t], first[t] + count[t]):
            for j in range(first[s], first[s] + count[s]):
                gap = max(abs(coords[i, 0] - coords[j, 0]), abs(coords[i, 1] - coords[j, 1]),
                          abs(coords[i, 2] - coords[j, 2]))
                if gap > a:
                    if write:
                        far[far_at, 0], far[far_at, 1] = i, j
                    far_at += 1
                else:
                    if write:
                        near[near_at, 0], near[near_at, 1] = i, j
                    near_at += 1
    return near_at, far_at


@_jit
def gather_rows(j0, j1, points, normals, radius, h_grid, field, weight, depth, sigma, disc, cumulative, total, behind):
    """Rows j0..j1 - 1 of `total` and `behind` (k, 3) of `back_share.gathered`: receiver points[j] gathers every vertex
    within its channel's `radius` (3,), in index order, with `scatter_kernels.pair_weight`'s
    weight (the field, profile, disc and cumulative of `NearField.kernel_args`), and times
    h(n_o·n_i) (linear in `h_grid` over μ in [-1, 1], uniform) into `behind`.

    Every vertex is tested against every receiver (1024 × n distances cost less than a k-d tree's
    lists of the pairs within the radius), and each pair's weight goes straight into its sums: no
    per-pair arrays (benchmarks/README.md#escape-gain-cost). Pairs far from small sources take
    pair_weight's point value here, inline: called, it cost ~200 ns a pair against ~30."""
    x, area, a_radius = field[0], field[1], field[2]
    sigma_tr, radial = disc[8], disc[9]
    r_max = max(radius[0], radius[1], radius[2])
    step = 2.0 / (len(h_grid) - 1)
    value, scratch = np.empty(3), np.empty(6)
    for j in range(j0, j1):
        o = points[j]
        for i in range(len(x)):
            d = math.sqrt((x[o, 0] - x[i, 0]) ** 2 + (x[o, 1] - x[i, 1]) ** 2 + (x[o, 2] - x[i, 2]) ** 2)
            if d > r_max:
                continue
            a = a_radius[i]
            if _is_point(o, i, d, a, sigma_tr):
                _radial(d, 0.0, 0.0, radial, weight, depth, sigma, value)
                for c in range(3):
                    value[c] *= area[i]
            else:
                pair_weight(o, i, field, weight, depth, sigma, disc, cumulative, value, scratch)
            mu = normals[o, 0] * normals[i, 0] + normals[o, 1] * normals[i, 1] + normals[o, 2] * normals[i, 2]
            u = min(max((mu + 1.0) / step, 0.0), len(h_grid) - 1.0)
            m = min(int(u), len(h_grid) - 2)
            h = h_grid[m] + (u - m) * (h_grid[m + 1] - h_grid[m])
            for c in range(3):
                if d <= radius[c]:
                    total[j, c] += value[c]
                    behind[j, c] += value[c] * h
