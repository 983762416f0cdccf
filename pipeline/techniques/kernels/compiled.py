"""Compiled loops of the kernels precompute's blending (`precompute._blend`), each over the pairs
of a chunk, released from the GIL so that its threads run chunks side by side.

- `local_transport`: T(r, t) = ``ProfileTable(|x_r - x_t|²) · A(t)`` (`precompute._Context.
  transport`). The local table reaches (k + 2)·√max(A)·2, so its step in d² is coarse for texel
  pairs and nearly all of them (99.7 % on the 150k dragon) fall below its ``exact_below`` onto the
  closed form: 18 poles × 3 channels of exponentials per pair in marble, most of the stage's time.
  Those pairs read a table in ln r instead (`near_table`: `scatter_kernels.radial_table`, 4-point
  Lagrange; 2e-11 relative to the closed form on the dragon's pairs, ~1e-7 bound); the others
  interpolate the ProfileTable as numpy did (to float64 rounding).
- `shared_hats` (`_Context.shared`) and `grouped_products` (the fit's `np.bincount` sums): the same
  products summed in the same order as the numpy forms, without their (m, 3) temporaries
  (bit-identical).
- `mix_global`: the two contractions of `_Context.global_part` over three terms each, in
  einsum's order, without its gathered (pairs, 3, 3) copies (equal to float64 rounding).

tests/techniques/kernels/test_compiled.py compares each with its numpy definition.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from sssbake.pipeline.core.profile import Profile
from sssbake.pipeline.core.profile_table import ProfileTable
from sssbake.pipeline.core.scatter_kernels import lagrange4, radial_table

_FOUR_PI = 4.0 * math.pi
_jit = numba.njit(cache=True, nogil=True)


@_jit
def _closed_form(d2, a, weight, depth, sigma, out, p):
    """out[p] = ``diffuse_reflectance_profile(sqrt(d2)) · a`` (which squares the distance again)."""
    r = math.sqrt(d2)
    r2 = r * r
    for c in range(3):
        total = 0.0
        for k in range(weight.shape[0]):
            w = weight[k, c]
            if w == 0.0:  # numpy adds an exact 0 there
                continue
            z = depth[k, c]
            d = math.sqrt(r2 + z * z)
            sd = sigma[k, c] * d
            total += w * z * (1.0 + sd) * math.exp(-sd) / (d * d * d)
        out[p, c] = total / _FOUR_PI * a


@_jit
def _transport(x, area, receiver, source, near, values, slopes, inv_step, exact_below, weight, depth, sigma, out):
    u0, inv_u, table = near
    last = table.shape[0] - 1
    for p in range(len(receiver)):
        i, j = receiver[p], source[p]
        d0 = x[i, 0] - x[j, 0]
        d1 = x[i, 1] - x[j, 1]
        d2_ = x[i, 2] - x[j, 2]
        d2 = d0 * d0 + d1 * d1 + d2_ * d2_
        if d2 >= exact_below:  # ProfileTable.__call__
            at = d2 * inv_step
            if at > values.shape[1] - 1:
                _closed_form(d2, area[j], weight, depth, sigma, out, p)
            else:
                index = int(at)
                frac = at - index
                for c in range(3):
                    out[p, c] = (values[c, index] + frac * slopes[c, index]) * area[j]
            continue
        u = (0.5 * math.log(d2) - u0) * inv_u if d2 > 0.0 else -1.0
        k = int(u)
        if u < 1.0 or k + 2 > last:  # outside the ln r table
            _closed_form(d2, area[j], weight, depth, sigma, out, p)
            continue
        # 4-point Lagrange in ln r between nodes k - 1 .. k + 2 (`scatter_kernels._radial`)
        w0, w1, w2, w3 = lagrange4(u - k)
        a = area[j]
        for c in range(3):
            out[p, c] = (w0 * table[k - 1, c] + w1 * table[k, c] + w2 * table[k + 1, c] + w3 * table[k + 2, c]) * a


@_jit
def _shared(corners, bary, receiver, source, out):
    for p in range(len(receiver)):
        i, j = receiver[p], source[p]
        for b in range(3):  # numpy's order: the receiver's corners in turn
            v = corners[i, b]
            for a in range(3):
                if corners[j, a] == v:
                    out[p, a] += bary[i, b]


@_jit
def _products(group, left, right, scale, out):
    for p in range(len(group)):
        g = group[p]
        for a in range(left.shape[1]):
            for b in range(right.shape[1]):
                out[g, a, b] += left[p, a] * right[p, b] * scale[p]


@_jit
def _mix(dual, src, block, per_source, bary, receiver, per_pair, out):
    mixed = np.empty((len(src), 3, 3))
    for v in range(len(src)):
        s, q = src[v], per_source[v]
        for b in range(3):
            for c in range(3):
                mixed[v, b, c] = (dual[s, 0] * block[q, 0, b, c] + dual[s, 1] * block[q, 1, b, c]
                                  + dual[s, 2] * block[q, 2, b, c])
    for p in range(len(receiver)):
        r, v = receiver[p], per_pair[p]
        for c in range(3):
            out[p, c] = bary[r, 0] * mixed[v, 0, c] + bary[r, 1] * mixed[v, 1, c] + bary[r, 2] * mixed[v, 2, c]


def _table_args(table: ProfileTable) -> tuple:
    p: Profile = table.params
    return table.values, table.slopes, 1.0 / table.step, table.exact_below, p.weight, p.depth, p.sigma


def near_table(table: ProfileTable) -> tuple:
    """Rd on a grid of ln r below the table's ``exact_below`` (`scatter_kernels.radial_table`, read
    by 4-point Lagrange interpolation, ~1e-7 relative): (ln r of the first node, inverse step,
    (N, 3) Rd per node), for `local_transport`."""
    p: Profile = table.params
    r_lo = 1e-4 * float(p.z_min.min())
    r_hi = max(float(np.sqrt(table.exact_below)), 4.0 * r_lo)
    u0, inv_step, values = radial_table(p.weight, p.depth, p.sigma, r_lo, r_hi)
    return u0, inv_step, np.ascontiguousarray(values[:, 0].T)  # a node's channels side by side


def local_transport(table: ProfileTable, near: tuple, x: np.ndarray, area: np.ndarray, receiver: np.ndarray,
                    source: np.ndarray) -> np.ndarray:
    """(m, 3) ``table(|x_r - x_s|²) · area[s]`` for the pairs (receiver, source): points (T, 3) mm,
    areas (T,) mm², `near` the `near_table` of `table` standing in for its closed form."""
    out = np.empty((len(receiver), 3))
    _transport(x, area, receiver, source, near, *_table_args(table), out)
    return out


def shared_hats(corners: np.ndarray, bary: np.ndarray, receiver: np.ndarray, source: np.ndarray) -> np.ndarray:
    """(m, 3 α) Σ_β bary[receiver, β] [corners[receiver, β] = corners[source, α]]
    (`precompute._Context.shared`): corners (T, 3) int, bary (T, 3)."""
    out = np.zeros((len(receiver), 3))
    _shared(corners, bary, receiver, source, out)
    return out


def grouped_products(group: np.ndarray, left: np.ndarray, right: np.ndarray, count: int,
                     scale: np.ndarray | None = None) -> np.ndarray:
    """(count, a, b) Σ_{p in group g} left[p, a] · right[p, b] (· scale[p]): `np.bincount` of each
    product with the same weights, summed in the same (pair) order."""
    out = np.zeros((count, left.shape[1], right.shape[1]))
    _products(group, np.ascontiguousarray(left), np.ascontiguousarray(right),
              np.ones(len(group)) if scale is None else scale, out)
    return out


def mix_global(dual: np.ndarray, src: np.ndarray, block: np.ndarray, per_source: np.ndarray, bary: np.ndarray,
               receiver: np.ndarray, per_pair: np.ndarray) -> np.ndarray:
    """(m, 3) ``einsum("pb,pbc->pc", bary[receiver], mixed[per_pair])`` with ``mixed =
    einsum("va,vabc->vbc", dual[src], block[per_source])`` (`precompute._Context.global_part`),
    without gathering `block` per (source, receiver face) nor `mixed` per pair."""
    out = np.empty((len(receiver), 3))
    _mix(dual, src, np.ascontiguousarray(block), per_source, bary, receiver, per_pair, out)
    return out
