"""Solves with A − σI for the shift-invert bands of `manifold_harmonics`, one factor per shift.

A − σI is symmetric and, past the first band, indefinite. CHOLMOD's simplicial LDLᵀ (through
`cvxopt.cholmod`) factors it without pivoting, on one fill-reducing ordering for every shift since
the pattern does not change, and its solves take 0.4× SuperLU's on a column ordering (150k-vertex
dragon: 10.3 against 25.4 ms; benchmarks/README.md#spectral-eigensolve). The ordering is
CHOLMOD's AMD, or METIS's nested dissection (`pymetis`; cvxopt's CHOLMOD is built without it)
where that fills L less. AMD fills L with 19-21 entries a vertex on scanned and simplified meshes
(50k-400k) but 32-46 on subdivided ones, whose vertices mostly have six neighbours; there METIS's
fills 27-34 (800k dragon: 27.0M entries instead of 36.5M, so the solves and factors that the
eigensolve repeats take 0.77× and 0.47× the time), elsewhere slightly more. METIS costs ~6 µs a
vertex, so it is asked only where more than `REGULAR` of the vertices have six neighbours. Without
pivoting a pivot can vanish or grow: a factor that CHOLMOD refuses, or whose solve of a test
vector has a backward error above `BACKWARD_ERROR`, is replaced by SuperLU's with partial
pivoting, so every shift gets a factor as stable as before.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as sla

#: Largest normwise backward error ‖r‖ / (‖A − σI‖ ‖x‖ + ‖b‖) (∞-norms, r = (A − σI)x − b) of the
#: test solve an LDLᵀ factor may leave. Stable solves leave 1e-18 to 1e-17 on the 150k and 800k
#: dragons whatever the conditioning (the first shift, just below λ = 0, makes A − σI nearly
#: singular: there even SuperLU's plain relative residual ‖r‖ / ‖b‖ is ~1e-5).
BACKWARD_ERROR = 1e-12
#: Share of vertices with six neighbours above which METIS's ordering is tried besides AMD (the
#: module docstring; measured shares: 0.23-0.38 scanned and simplified, 0.83-0.96 subdivided).
REGULAR = 0.5


class ShiftedFactor:
    """Factors of `a` − σI for the shifts asked, sharing one symbolic analysis.

    Parameters
    ----------
    a : (n, n) scipy.sparse matrix, symmetric
    """

    def __init__(self, a: sp.spmatrix):
        import cvxopt

        self._a = sp.csc_matrix(a)
        n = self._a.shape[0]
        lower = sp.tril(self._a).tocoo()
        # the diagonal once more, as entries of its own (CHOLMOD adds duplicates), so that σ has a
        # place on every row whatever `a`'s own diagonal holds
        self._rows = cvxopt.matrix(np.r_[lower.row, np.arange(n)].astype(np.int64))
        self._cols = cvxopt.matrix(np.r_[lower.col, np.arange(n)].astype(np.int64))
        self._values = lower.data.astype(np.float64)
        # the graph of the pattern CHOLMOD gets; given METIS's ordering of it, CHOLMOD analyses that
        # and its own AMD and keeps whichever fills L less
        off = lower.row != lower.col
        rows, cols = np.r_[lower.row[off], lower.col[off]], np.r_[lower.col[off], lower.row[off]]
        self._order = None
        if np.mean(np.bincount(rows, minlength=n) == 6) > REGULAR:
            import pymetis

            graph = sp.csr_matrix((np.ones(len(rows)), (rows, cols)), shape=(n, n))
            order, _ = pymetis.nested_dissection(pymetis.CSRAdjacency(graph.indptr, graph.indices))
            self._order = cvxopt.matrix(np.array(order, dtype=np.int64))
        self._symbolic = None
        self._probe = np.random.default_rng(0).standard_normal(n)

    def solver(self, shift: float) -> Callable[[np.ndarray], np.ndarray]:
        """x ↦ (a − shift·I)⁻¹ x, for (n,) float64 x; the previous solver of this object is spent."""
        import cvxopt
        import cvxopt.cholmod as cholmod

        n = self._a.shape[0]
        m = cvxopt.spmatrix(cvxopt.matrix(np.r_[self._values, np.full(n, -shift)]), self._rows, self._cols, (n, n))
        saved = cholmod.options.get("supernodal")
        cholmod.options["supernodal"] = 0  # simplicial: LDLᵀ (the supernodal factor is LLᵀ only)
        try:
            if self._symbolic is None:
                ordering = {} if self._order is None else {"p": self._order}
                self._symbolic = cholmod.symbolic(m, uplo="L", **ordering)
            cholmod.numeric(m, self._symbolic)
        except ArithmeticError:  # a zero pivot: this shift's factor needs pivoting
            return self._pivoted(shift)
        finally:
            if saved is None:
                del cholmod.options["supernodal"]
            else:
                cholmod.options["supernodal"] = saved
        factor = self._symbolic

        def solve(b: np.ndarray) -> np.ndarray:
            x = cvxopt.matrix(np.ascontiguousarray(b, dtype=np.float64))
            cholmod.solve(factor, x)
            return np.asarray(x).ravel()

        probe = self._probe
        x = solve(probe)
        residual = np.abs(self._a @ x - shift * x - probe).max()
        scale = self._norm(shift) * np.abs(x).max() + np.abs(probe).max()
        if not residual <= BACKWARD_ERROR * scale:  # NaN fails too
            return self._pivoted(shift)
        return solve

    def _norm(self, shift: float) -> float:
        """‖a − shift·I‖∞ (largest absolute row sum)."""
        magnitude = abs(self._a) - sp.diags(np.abs(self._a.diagonal())) + sp.diags(np.abs(self._a.diagonal() - shift))
        return float(np.asarray(magnitude.sum(axis=1)).max())

    def _pivoted(self, shift: float) -> Callable[[np.ndarray], np.ndarray]:
        n = self._a.shape[0]
        lu = sla.splu((self._a - shift * sp.identity(n, format="csc")).tocsc(), permc_spec="COLAMD")
        return lu.solve
