"""QP solvers for the tracker's axis problems, behind one contract (:mod:`.contract`).

- :mod:`.batchqp`: our compiled, batched, warm-started dual active-set solver (the default; it
  runs inside the tracker's compiled tick);
- :mod:`.daqp`: DAQP, the external dual active-set solver it was checked against;
- :mod:`.clarabel`: Clarabel (interior point), the independent reference of the benchmarks.

The solvers know nothing of the tracker: they take the QP's fixed matrices (:class:`QpMatrices`).
"""

from uavmpc.solvers.batchqp import BatchAxisSolver, BatchQpSolver, LdpData
from uavmpc.solvers.clarabel import ClarabelSolver
from uavmpc.solvers.contract import (
    FEASIBILITY_TOL,
    AxisQpSolver,
    QpMatrices,
    QpResult,
    check_solution,
)
from uavmpc.solvers.daqp import DaqpSolver

__all__ = [
    "FEASIBILITY_TOL",
    "AxisQpSolver",
    "BatchAxisSolver",
    "BatchQpSolver",
    "ClarabelSolver",
    "DaqpSolver",
    "LdpData",
    "QpMatrices",
    "QpResult",
    "check_solution",
]
