"""The lowest eigenpairs of W φ = λ M φ (cotangent stiffness, lumped mass; `laplacian`): the
manifold harmonics basis of the spectral technique (Vallet & Lévy 2008; Patro 2007 §3.2).

M is diagonal, so the problem is the standard symmetric one A ψ = λ ψ with A = M^-½ W M^-½ and
φ = M^-½ ψ (then Φᵀ M Φ = I). Small meshes are solved densely. Otherwise shift-invert Lanczos
(`scipy.sparse.linalg.eigsh`) finds the pairs nearest a shift σ; one solve for hundreds of pairs
spends most of its time re-orthogonalising a Lanczos basis of 2m vectors of n, not in the
factor's solves (benchmarks/README.md#spectral-eigensolve). As in Vallet & Lévy, the spectrum is
instead cut into bands of at most `BAND` pairs, each a shift-invert solve about its own shift: the
first band about a shift just below 0, the next bands' shifts placed from the density of
eigenvalues the previous band measured (Weyl's law: λ grows linearly with the index on a surface),
the bands overlapping so that none misses a pair. Consecutive bands are joined at
the widest gap between eigenvalues in their overlap, so that a multiplet (λ repeated on
symmetric shapes) comes whole from one band. Exactly repeated eigenvalues can still lose a
member in any Lanczos solve (benchmarks/README.md#spectral-eigensolve): meshes up to `DENSE`
vertices, where such shapes are typical, are solved densely.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
import scipy.linalg
import scipy.sparse as sp
import scipy.sparse.linalg as sla

from sssbake.pipeline.techniques.spectral.laplacian import Laplacian
from sssbake.pipeline.techniques.spectral.shifted_factor import ShiftedFactor

#: Meshes up to this many vertices are solved densely.
DENSE = 1500
#: Most new eigenpairs per shift-invert solve (bands beat one solve for hundreds of pairs, and
#: with CHOLMOD's cheaper solves narrow bands beat wide ones: benchmarks/README.md#spectral-eigensolve).
BAND = 30
#: Share of a band spent overlapping the previous one.
OVERLAP = 0.08
#: Eigenvalues closer than this (relative) count as one multiplet.
MULTIPLET = 1e-6
#: Relative accuracy of the eigenvalues (ARPACK's default, machine precision, costs more time
#: for no visible change: benchmarks/README.md#spectral-eigensolve).
TOLERANCE = 1e-8
#: Seed of the bands' Lanczos start vectors: ARPACK's own are drawn unseeded, so two bakes of one
#: mesh differed (eigenvalues by ~3e-12, eigenvectors by sign and rotation within multiplets, and
#: now and then a band retried): a bake is a function of its inputs, which its caches assume.
START_SEED = 0


@dataclass(frozen=True, eq=False)
class Harmonics:
    """Attributes
    ----------
    values : (m,) float64
        Eigenvalues λ, increasing, >= 0 (1 / length², in the positions' units).
    vectors : (n, m) float64
        Φ, M-orthonormal: Φᵀ M Φ = I.
    bands : int
        Shift-invert solves used (0: dense).
    seconds : dict
    """

    values: np.ndarray
    vectors: np.ndarray
    bands: int = 0
    seconds: dict = field(default_factory=dict)


def manifold_harmonics(laplacian: Laplacian, count: int) -> Harmonics:
    """The `count` lowest eigenpairs (all of them on a mesh with fewer vertices).

    Parameters
    ----------
    laplacian : Laplacian
    count : int
        m >= 1.
    """
    if count < 1:
        raise ValueError(f"spectral: need at least one eigenpair, got {count}")
    n = len(laplacian.mass)
    scale = 1.0 / np.sqrt(laplacian.mass)
    a = (sp.diags(scale) @ laplacian.stiffness @ sp.diags(scale)).tocsc()
    a = 0.5 * (a + a.T)
    t = time.perf_counter()
    if n <= max(DENSE, count + 1):
        values, vectors = scipy.linalg.eigh(a.toarray())
        values, vectors, bands = values[:count], vectors[:, :count], 0
    else:
        values, vectors, bands = _banded(a, count, float(laplacian.mass.sum()))
    seconds = {"eigensolve": time.perf_counter() - t}
    values = np.maximum(values, 0.0)  # round-off below the constant's 0
    return Harmonics(values, vectors * scale[:, None], bands, seconds)


def _banded(a: sp.csc_matrix, count: int, area: float) -> tuple[np.ndarray, np.ndarray, int]:
    """The `count` lowest eigenpairs of symmetric positive semi-definite `a`, band by band."""
    n = a.shape[0]
    factor = ShiftedFactor(a)
    shift = -1e-3 / area  # just below 0: A - σI is positive definite
    # as few bands as BAND allows, each a share of `count` plus its overlap and a margin
    band = min(n - 2, int(np.ceil(count / np.ceil(count / BAND) * (1.0 + OVERLAP))) + 8)
    # the pairs kept so far are the first `kept` of these (a band adds at most `band` past `count`)
    values, vectors, kept = np.zeros(count + band), np.zeros((n, count + band)), 0
    solves = 0
    start = np.random.default_rng(START_SEED)
    while kept < count:
        op = sla.LinearOperator(a.shape, matvec=factor.solver(shift), dtype=np.float64)
        lam, psi = sla.eigsh(a, k=band, sigma=shift, which="LM", OPinv=op, tol=TOLERANCE,
                             v0=start.standard_normal(n))
        solves += 1
        order = np.argsort(lam)
        lam, psi = lam[order], psi[:, order]
        if kept:
            overlap = values[:kept][values[:kept] >= lam[0]]
            gaps = np.diff(overlap)
            if not np.any(gaps > MULTIPLET * max(float(values[kept - 1]), 1e-300)):
                # the band does not reach back over two distinct eigenvalues of the last one
                # (either band's edge may hold part of a multiplet only): shift down, retry
                shift = 0.5 * (shift + values[kept - 1])
                continue
            # join at the widest gap of the overlap: both sides of it are whole multiplets
            gap = int(np.argmax(gaps))
            cut = 0.5 * (overlap[gap] + overlap[gap + 1])
            kept = int(np.searchsorted(values[:kept], cut, side="right"))
            new = lam > cut
            lam, psi = lam[new], psi[:, new]
        values[kept:kept + len(lam)], vectors[:, kept:kept + len(lam)] = lam, psi
        kept += len(lam)
        # the next shift from the density of eigenvalues this band measured (Weyl: about even
        # spacing), so that the next band reaches OVERLAP of a band back into this one
        spacing = (values[kept - 1] - values[max(0, kept - band)]) / max(min(band, kept) - 1, 1)
        shift = values[kept - 1] + (0.5 - OVERLAP) * band * spacing
    return values[:count], vectors[:, :count], solves
