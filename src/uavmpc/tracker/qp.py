"""QP solvers for one axis of the tracker, behind one small contract.

The problem is always ``min ½ Uᵀ H U + fᵀ U  s.t.  lower ≤ [U; C U] ≤ upper`` with H and C fixed
by the :class:`~uavmpc.tracker.model.CondensedModel`; only ``f`` and the bounds change per tick.
The first ``m`` entries of ``lower``/``upper`` bound the inputs U, the others bound ``C U``.

Each backend checks its solver's status; the tracker then checks every returned solution
(finite, within bounds ± FEASIBILITY_TOL) for all axes at once before using it.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np

from uavmpc.tracker.model import CondensedModel

#: Largest bound violation accepted from a solver before its solution is declared failed.
FEASIBILITY_TOL = 1e-6


@dataclass(frozen=True)
class QpResult:
    """Outcome of one axis QP.

    Attributes:
        inputs: (m,) optimal commanded accelerations, or None when the solve failed.
        status: the solver's own status word ("optimal", or why it failed).
        iterations: solver iterations (0 when the unconstrained shortcut was used).
    """

    inputs: np.ndarray | None
    status: str
    iterations: int

    @property
    def ok(self) -> bool:
        return self.inputs is not None


class AxisQpSolver(Protocol):
    """Solves the tracker's QP for one axis, keeping any warm start between calls."""

    name: str

    def solve(self, f: np.ndarray, lower: np.ndarray, upper: np.ndarray) -> QpResult:
        """Solve with linear term f (m,) and bounds (m + rows of C,)."""
        ...


def check_solution(
    model: CondensedModel, u: np.ndarray, lower: np.ndarray, upper: np.ndarray
) -> str | None:
    """None if ``u`` is finite and within the bounds (± FEASIBILITY_TOL), else the reason."""
    rows = np.concatenate([u, model.constraint_matrix @ u])
    excess = float(np.maximum(lower - rows, rows - upper).max())
    if not excess <= FEASIBILITY_TOL:  # also catches NaN
        return "non-finite solution" if np.isnan(excess) else (
            f"solution violates its bounds by {excess:.3g}")
    return None


class DaqpSolver:
    """DAQP (dual active set, exact), warm-started from the previous tick's working set."""

    name = "daqp"

    def __init__(self, model: CondensedModel, iter_limit: int = 1000) -> None:
        import daqp

        self._daqp = daqp
        self._model = model
        self._iter_limit = iter_limit
        self._qp: object | None = None

    def solve(self, f: np.ndarray, lower: np.ndarray, upper: np.ndarray) -> QpResult:
        if self._qp is None:
            qp = self._daqp.Model()
            flag, _ = qp.setup(self._model.hessian, f, self._model.constraint_matrix, upper, lower)
            if flag < 0:
                return QpResult(None, f"daqp setup failed (exitflag {flag})", 0)
            qp.settings = {"iter_limit": self._iter_limit}
            self._qp = qp
        else:
            # Updating only f and bounds keeps the previous working set: the warm start.
            self._qp.update(f=f, bupper=upper, blower=lower)  # type: ignore[attr-defined]
        u, _, flag, info = self._qp.solve()  # type: ignore[attr-defined]
        iterations = int(info.get("iterations", 0))
        if flag != 1:
            self._qp = None  # a failed workspace is not a good warm start
            return QpResult(None, f"daqp exitflag {flag}", iterations)
        return QpResult(np.asarray(u, dtype=float), "optimal", iterations)


class ClarabelSolver:
    """Clarabel (interior point): an independent reference, tight tolerances, no warm start.

    An interior-point solution is accurate only to its tolerance, and this Hessian has flat
    directions (late inputs barely matter), so with ``polish`` the active set Clarabel found is
    solved exactly as an equality-constrained QP (its KKT system); the polished solution is kept
    when it is feasible and its multipliers have the right signs, i.e. when it is the exact
    optimum. Degenerate active sets (dependent rows) are left unpolished.
    """

    name = "clarabel"

    def __init__(self, model: CondensedModel, tol: float = 1e-10, polish: bool = True) -> None:
        import clarabel
        from scipy import sparse

        self._clarabel = clarabel
        self._model = model
        m = model.config.steps
        self._p = sparse.csc_matrix(np.triu(model.hessian))
        ident = np.eye(m)
        # lower ≤ G U ≤ upper as  [G; −G] U + s = [upper; −lower],  s ≥ 0
        g = np.vstack([ident, model.constraint_matrix])
        self._a = sparse.csc_matrix(np.vstack([g, -g]))
        self._n_rows = g.shape[0]
        settings = clarabel.DefaultSettings()
        settings.verbose = False
        settings.tol_gap_abs = tol
        settings.tol_gap_rel = tol
        settings.tol_feas = tol
        settings.max_iter = 200
        self._settings = settings
        self._g = g
        self._polish = polish
        self.polished = 0

    def solve(self, f: np.ndarray, lower: np.ndarray, upper: np.ndarray) -> QpResult:
        cl = self._clarabel
        b = np.concatenate([upper, -lower])
        cones = [cl.NonnegativeConeT(2 * self._n_rows)]
        solver = cl.DefaultSolver(self._p, f, self._a, b, cones, self._settings)
        sol = solver.solve()
        status = str(sol.status)
        if "Solved" not in status or "Almost" in status:
            return QpResult(None, f"clarabel {status}", int(sol.iterations))
        u = np.asarray(sol.x, dtype=float)
        if self._polish:
            polished = self._polished(u, f, lower, upper)
            if polished is not None:
                u = polished
                self.polished += 1
        reason = check_solution(self._model, u, lower, upper)
        if reason is not None:
            return QpResult(None, f"clarabel: {reason}", int(sol.iterations))
        return QpResult(u, "optimal", int(sol.iterations))

    def _polished(
        self, u: np.ndarray, f: np.ndarray, lower: np.ndarray, upper: np.ndarray
    ) -> np.ndarray | None:
        """The exact optimum on the active set guessed from ``u``, trying several thresholds."""
        rows = self._g @ u
        scale = np.maximum(1.0, np.abs(upper - lower))
        n = u.shape[0]
        for threshold in (1e-8, 1e-7, 1e-6, 1e-5, 1e-4, 1e-3):
            at_lo = np.abs(rows - lower) <= threshold * scale
            at_hi = ~at_lo & (np.abs(rows - upper) <= threshold * scale)
            active = np.flatnonzero(at_lo | at_hi)
            g_a = self._g[active]
            k = active.shape[0]
            kkt = np.zeros((n + k, n + k))
            kkt[:n, :n] = self._model.hessian
            kkt[:n, n:] = g_a.T
            kkt[n:, :n] = g_a
            rhs = np.concatenate([-f, np.where(at_lo[active], lower[active], upper[active])])
            try:
                sol = np.linalg.solve(kkt, rhs)
            except np.linalg.LinAlgError:
                continue
            u_exact, lam = sol[:n], sol[n:]
            # KKT signs: a lower bound pushes up (λ ≤ 0 in this convention), an upper one down.
            signs_ok = np.all(np.where(at_lo[active], lam <= 1e-9, lam >= -1e-9))
            if signs_ok and check_solution(self._model, u_exact, lower, upper) is None:
                return u_exact
        return None


def make_solver(name: str, model: CondensedModel, iter_limit: int = 1000) -> AxisQpSolver:
    """The solver named in the tracker configuration."""
    if name == "daqp":
        return DaqpSolver(model, iter_limit)
    if name == "clarabel":
        return ClarabelSolver(model)
    if name == "batchqp":
        from uavmpc.tracker.batchqp import BatchAxisSolver

        return BatchAxisSolver(model, iter_limit=iter_limit)
    raise ValueError(f"unknown QP solver {name!r} (known: daqp, clarabel, batchqp)")
