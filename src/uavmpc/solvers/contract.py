"""The contract every QP solver of the tracker honours (one axis, one problem at a time).

The problem is always ``min ½ Uᵀ H U + fᵀ U  s.t.  lower ≤ [U; C U] ≤ upper`` with H and C fixed
by the tracker's model (:class:`QpMatrices`); only ``f`` and the bounds change per tick.
The first ``m`` entries of ``lower``/``upper`` bound the inputs U, the others bound ``C U``.

Each backend checks its solver's status; the tracker then checks every returned solution
(finite, within bounds ± FEASIBILITY_TOL) for all axes at once before using it.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np

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


class QpMatrices(Protocol):
    """The fixed data of every QP of one kind: any object with these two arrays (the tracker's
    :class:`~uavmpc.tracker.model.CondensedModel` is one)."""

    # Read-only: a frozen dataclass (the model) provides them too.
    @property
    def hessian(self) -> np.ndarray:  # (m, m) H, symmetric positive definite
        ...

    @property
    def constraint_matrix(self) -> np.ndarray:  # (r, m) C
        ...


@runtime_checkable
class AxisQpSolver(Protocol):
    """Solves the tracker's QP for one axis, keeping any warm start between calls."""

    name: str

    def solve(self, f: np.ndarray, lower: np.ndarray, upper: np.ndarray) -> QpResult:
        """Solve with linear term f (m,) and bounds (m + rows of C,)."""
        ...


def check_solution(
    model: QpMatrices, u: np.ndarray, lower: np.ndarray, upper: np.ndarray
) -> str | None:
    """None if ``u`` is finite and within the bounds (± FEASIBILITY_TOL), else the reason."""
    rows = np.concatenate([u, model.constraint_matrix @ u])
    excess = float(np.maximum(lower - rows, rows - upper).max())
    if not excess <= FEASIBILITY_TOL:  # also catches NaN
        return "non-finite solution" if np.isnan(excess) else (
            f"solution violates its bounds by {excess:.3g}")
    return None


