"""MPC trajectory tracker (SPEC §2): the virtual UAV, its model, its law and its state."""

from uavmpc.solvers import AxisQpSolver, ClarabelSolver, DaqpSolver, QpResult
from uavmpc.tracker.model import CondensedModel, braking_plan, discretize
from uavmpc.tracker.params import AXES, DynamicLimits, TrackerConfig
from uavmpc.tracker.tracker import (
    InvalidStateError,
    MpcTracker,
    Prediction,
    TrackerBatch,
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
    "TrackerBatch",
    "TrackerCommand",
    "TrackerConfig",
    "TrackerOutput",
    "braking_plan",
    "discretize",
]
