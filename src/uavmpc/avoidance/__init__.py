"""Decentralized collision avoidance (SPEC §5): proximity condition and resolution strategies."""

from uavmpc.avoidance.proximity import (
    align,
    align_batch,
    conflict_points,
    cylinder_conflicts,
    first_conflict_time,
)
from uavmpc.avoidance.strategy import (
    AvoidanceDecision,
    AvoidanceParams,
    EncounterStrategy,
    HeightOffsetStrategy,
    ResolutionStrategy,
)

__all__ = [
    "AvoidanceDecision",
    "AvoidanceParams",
    "EncounterStrategy",
    "HeightOffsetStrategy",
    "ResolutionStrategy",
    "align",
    "align_batch",
    "conflict_points",
    "cylinder_conflicts",
    "first_conflict_time",
]
