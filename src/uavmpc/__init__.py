"""uavmpc: several multirotor UAVs in one airspace without mid-air collisions.

Data flows once per UAV: mission reference → collision avoidance → MPC tracker (virtual UAV)
→ SE(3) controller → attitude controller and plant. See SPEC.md and docs/.
"""

from uavmpc.config import ConfigError
from uavmpc.reference import InvalidReferenceError, Reference
from uavmpc.tracker import DynamicLimits, MpcTracker, TrackerConfig

__version__ = "0.1.0"

__all__ = [
    "ConfigError",
    "DynamicLimits",
    "InvalidReferenceError",
    "MpcTracker",
    "Reference",
    "TrackerConfig",
    "__version__",
]
