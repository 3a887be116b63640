"""Clarabel (interior point): an independent reference solver for the tracker's QPs."""

from __future__ import annotations

import numpy as np

from uavmpc.solvers.contract import QpMatrices, QpResult, check_solution


class ClarabelSolver:
    """Clarabel (interior point): an independent reference, tight tolerances, no warm start.

    An interior-point solution is accurate only to its tolerance, and this Hessian has flat
    directions (late inputs barely matter), so with ``polish`` the active set Clarabel found is
    solved exactly as an equality-constrained QP (its KKT system); the polished solution is kept
    when it is feasible and its multipliers have the right signs, i.e. when it is the exact
    optimum. Degenerate active sets (dependent rows) are left unpolished.
    """

    name = "clarabel"

    def __init__(self, model: QpMatrices, tol: float = 1e-10, polish: bool = True) -> None:
        import clarabel
        from scipy import sparse

        self._clarabel = clarabel
        self._model = model
        m = model.hessian.shape[0]
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
