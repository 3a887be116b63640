"""The plant: what the onboard stack flies (SPEC §4).

The contract is :class:`Plant` (give state, take attitude + thrust) with :class:`VehicleState`
and :class:`AttitudeTarget`; see :mod:`uavmpc.plant.interface`. Our simulator is
:class:`~uavmpc.plant.multirotor.Multirotor` (attitude loop + motors + rigid body), parameterized
by an :class:`~uavmpc.plant.airframe.Airframe` file; its state is a row of a :class:`PlantRows`
record, stepped by the compiled :func:`plant_step`.

The package depends on nothing of uavmpc but its configuration helpers and :mod:`uavmpc.jit`:
the onboard stack (control, tracker, …) builds on it, never the other way round.
"""

from __future__ import annotations

from uavmpc.plant.airframe import G_MPS2, Airframe, AttitudeGains, Se3Gains
from uavmpc.plant.interface import AttitudeTarget, Plant, VehicleState
from uavmpc.plant.kernels import (
    N_RIGID,
    attitude_target_ok,
    normalize_quat,
    plant_step,
    plant_step_motors,
)
from uavmpc.plant.multirotor import Multirotor
from uavmpc.plant.rows import PlantRows, copy_row
from uavmpc.plant.wind import Wind

__all__ = [
    "G_MPS2",
    "N_RIGID",
    "Airframe",
    "AttitudeGains",
    "AttitudeTarget",
    "Multirotor",
    "Plant",
    "PlantRows",
    "Se3Gains",
    "VehicleState",
    "Wind",
    "attitude_target_ok",
    "copy_row",
    "normalize_quat",
    "plant_step",
    "plant_step_motors",
]
