"""Stable argsort of non-negative integer keys of known bound without a comparison sort.

The kernels precompute orders tens of millions of (row, column) keys of F; numpy's comparison
argsort costs ~100 ns a key there. Its stable sort of 16-bit integers is a radix sort, so a key
of b bits sorts in ceil(b / 16) stable passes, least significant digit first, faster than the
comparison sort (benchmarks/README.md#integer-key-sort).
"""

from __future__ import annotations

import numpy as np


def argsort_keys(key: np.ndarray, bound: int) -> np.ndarray:
    """Stable argsort of integer keys.

    Parameters
    ----------
    key : (m,) int
        Values in [0, bound).
    bound : int

    Returns
    -------
    (m,) int64
        The order that sorts `key`, ties in their input order.
    """
    key = np.asarray(key, dtype=np.int64)
    order = None
    shift = 0
    while shift == 0 or (bound - 1) >> shift:
        digit = ((key >> shift) & 0xFFFF).astype(np.uint16)  # gathered as 2 bytes, not 8
        order = np.argsort(digit, kind="stable") if order is None else order[np.argsort(digit[order], kind="stable")]
        shift += 16
    return order.astype(np.int64)


def unique_keys(key: np.ndarray, bound: int) -> tuple[np.ndarray, np.ndarray]:
    """``np.unique(key, return_index=True, return_inverse=True)[1:]`` by `argsort_keys`.

    Parameters
    ----------
    key : (m,) int
        Values in [0, bound).
    bound : int

    Returns
    -------
    first : (u,) int64
        Where each distinct key, in increasing order, first occurs.
    inverse : (m,) int64
        Each key's place among the distinct keys.
    """
    key = np.asarray(key, dtype=np.int64)
    order = argsort_keys(key, bound)
    ordered = key[order]
    new = np.empty(len(key), dtype=bool)
    new[:1] = True
    np.not_equal(ordered[1:], ordered[:-1], out=new[1:])
    inverse = np.empty(len(key), dtype=np.int64)
    inverse[order] = np.cumsum(new) - 1
    return order[new], inverse  # stable: the first of equal keys comes first
