"""MPC trajectory tracker (SPEC §2): the virtual UAV, its model, its QP and its solvers."""

from uavmpc.tracker.model import CondensedModel, braking_plan, discretize
from uavmpc.tracker.params import AXES, DynamicLimits, TrackerConfig
from uavmpc.tracker.qp import AxisQpSolver, ClarabelSolver, DaqpSolver, QpResult
from uavmpc.tracker.tracker import (
    InvalidStateError,
    MpcTracker,
    Prediction,
    TrackerCommand,
    TrackerOutput,
)

__all__ = [
    "AXES",
    "AxisQpSolver",
    "ClarabelSolver",
    "CondensedModel",
    "DaqpSolver",
    "DynamicLimits",
    "InvalidStateError",
    "MpcTracker",
    "Prediction",
    "QpResult",
    "TrackerCommand",
    "TrackerConfig",
    "TrackerOutput",
    "braking_plan",
    "discretize",
]
