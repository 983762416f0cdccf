"""Solves with A − σI for the shift-invert bands of `manifold_harmonics`, one factor per shift.

A − σI is symmetric and, past the first band, indefinite. CHOLMOD's simplicial LDLᵀ (through
`cvxopt.cholmod`) factors it without pivoting, on one fill-reducing ordering (AMD) for every
shift since the pattern does not change, and its solves take 0.4× SuperLU's on a column ordering
(150k-vertex dragon: 10.3 against 25.4 ms; benchmarks/README.md#spectral-eigensolve). Without
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
                self._symbolic = cholmod.symbolic(m, uplo="L")
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
