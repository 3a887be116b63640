"""The plant: what the onboard stack flies (SPEC §4).

The contract is :class:`Plant` (give state, take attitude + thrust) with :class:`VehicleState`
and :class:`AttitudeTarget`; see :mod:`uavmpc.plant.interface`. Our simulator is
:class:`~uavmpc.plant.multirotor.Multirotor` (attitude loop + motors + rigid body), parameterized
by an :class:`~uavmpc.plant.airframe.Airframe` file.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from uavmpc.plant.airframe import G_MPS2, Airframe, AttitudeGains, Se3Gains
from uavmpc.plant.interface import AttitudeTarget, Plant, VehicleState
from uavmpc.plant.sensors import GnssNoise
from uavmpc.plant.wind import Wind

if TYPE_CHECKING:
    from uavmpc.plant.multirotor import Multirotor

__all__ = [
    "G_MPS2",
    "Airframe",
    "AttitudeGains",
    "AttitudeTarget",
    "GnssNoise",
    "Multirotor",
    "Plant",
    "Se3Gains",
    "VehicleState",
    "Wind",
]


def __getattr__(name: str) -> Any:
    # Imported lazily: multirotor depends on uavmpc.control.attitude, which depends on
    # uavmpc.plant.airframe; an eager import here would make that a cycle.
    if name == "Multirotor":
        from uavmpc.plant.multirotor import Multirotor

        return Multirotor
    raise AttributeError(f"module 'uavmpc.plant' has no attribute {name!r}")
