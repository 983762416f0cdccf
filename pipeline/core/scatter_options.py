"""The hierarchical gather's knobs (`scatter_operator`), apart from it (numpy, scipy, numba): the
prt options' defaults and the CLI's help read them without the numerical stack."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class ScatterOptions:
    """Knobs of the hierarchical gather.

    Attributes
    ----------
    energy_dropped : float
        Fraction of the total diffuse reflectance R_d a source may lose to the truncation radius.
    separation : int
        Cells within this many cells (per axis) of each other are near. The cluster error falls
        roughly as 1/separation²; the entries per vertex and level grow as ~(2·separation + 1)².
    vertices_per_cell : float
        Sets the finest cell size h_0 = sqrt(vertices_per_cell · area / n).
    hierarchy : bool
        False sums every pair within the radius exactly (O(N·neighbours); for tests and checks).
    float32 : bool
        Store the matrices and run the products in float32 (half the memory, ~1.5× faster);
        the rounding is ~1e-6 of q, far below the clustering error (tests measure it).
    threads : int
        Worker threads for building and applying (the compiled loops release the GIL).
    block : int
        Signals per thread of one pass of `ScatterOperator.apply`: a pass reads the operator once
        for threads · block signals (the threads share its rows), and bounds the pass's temporaries.
    """

    energy_dropped: float = 1e-2
    separation: int = 2
    vertices_per_cell: float = 1.0
    hierarchy: bool = True
    float32: bool = True
    threads: int = 2
    block: int = 32


SCATTER_DEFAULTS = ScatterOptions()
