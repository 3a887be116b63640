"""DAQP (dual active set, exact), the tracker's external reference solver."""

from __future__ import annotations

from typing import Any

import numpy as np

from uavmpc.solvers.contract import QpMatrices, QpResult


class DaqpSolver:
    """DAQP (dual active set, exact), warm-started from the previous tick's working set."""

    name = "daqp"

    def __init__(self, model: QpMatrices, iter_limit: int = 1000) -> None:
        import daqp

        self._daqp = daqp
        self._model = model
        self._iter_limit = iter_limit
        self._qp: Any = None  # a daqp.Model once set up (daqp has no type hints)

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
            self._qp.update(f=f, bupper=upper, blower=lower)
        u, _, flag, info = self._qp.solve()
        iterations = int(info.get("iterations", 0))
        if flag != 1:
            self._qp = None  # a failed workspace is not a good warm start
            return QpResult(None, f"daqp exitflag {flag}", iterations)
        return QpResult(np.asarray(u, dtype=float), "optimal", iterations)
