"""Morton (Z-order) codes of integer grid coordinates: sorting by them keeps points that lie close
together in space close together in the order, cell by cell at every level of an octree."""

from __future__ import annotations

import numpy as np


def _spread_bits(v: np.ndarray) -> np.ndarray:
    """The low 21 bits of `v` spread out so that two zero bits follow each one."""
    v = v.astype(np.uint64) & np.uint64(0x1FFFFF)
    for shift, mask in ((32, 0x1F00000000FFFF), (16, 0x1F0000FF0000FF), (8, 0x100F00F00F00F00F),
                        (4, 0x10C30C30C30C30C3), (2, 0x1249249249249249)):
        v = (v | (v << np.uint64(shift))) & np.uint64(mask)
    return v


def morton_codes(coords: np.ndarray) -> np.ndarray:
    """(n,) int64 Morton codes of non-negative integer coordinates (n, 3) below 2^21.

    Shifting a code right by 3l gives the code of the level-l cell (coordinates >> l).
    """
    code = (_spread_bits(coords[:, 0]) << np.uint64(2)) | (_spread_bits(coords[:, 1]) << np.uint64(1))
    return (code | _spread_bits(coords[:, 2])).astype(np.int64)
