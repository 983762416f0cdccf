"""Fixtures shared by several test modules (pytest finds them here)."""

import numpy as np
import pytest
import trimesh

from sssbake.pipeline.core.directions import direction_set
from sssbake.pipeline.core.surface import area_weighted_normals


@pytest.fixture(scope="module")
def blob():
    """A bumpy sphere and a smooth q field with a soft self-shadow-like falloff in direction."""
    s = trimesh.creation.icosphere(subdivisions=4)
    v = np.asarray(s.vertices)
    v = v * (1.0 + 0.08 * np.sin(3 * v[:, :1]) * np.cos(2 * v[:, 1:2]))
    f = np.asarray(s.faces)
    n = area_weighted_normals(v, f)
    ds = direction_set(64, lookup_size=32)
    cos = n @ ds.directions.T
    lobe = np.clip(0.3 + cos, 0.0, None) ** 2
    q = np.stack([lobe * (0.5 + 0.1 * c + 0.05 * v[:, :1]) for c in range(3)])
    return v, f, ds, q
