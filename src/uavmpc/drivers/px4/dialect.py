"""PX4's dialect of MAVLink: how it encodes flight modes, the constants its offboard mode
depends on, and readable names for MAVLink's enums (for reports and errors).

PX4 packs its mode into HEARTBEAT.custom_mode as bytes: main mode in bits 16–23, sub mode (of
AUTO) in bits 24–31 (PX4's ``px4_custom_mode.h``).
"""

from __future__ import annotations

from collections.abc import Sequence
from enum import IntEnum
from typing import Protocol

try:
    from pymavlink.dialects.v20 import common as mavlink
except ImportError:  # an optional extra: one line saying what to install
    raise ImportError("the PX4/MAVLink link needs pymavlink: pip install 'uavmpc[px4]'") from None

__all__ = ["COM_OF_LOSS_T_S", "OFFBOARD_STREAM_S", "AttitudeQuaternionMsg", "AutoSubMode",
           "CommandAckMsg", "CommandMsg", "ExtendedSysStateMsg", "GpsGlobalOriginMsg",
           "HeartbeatMsg", "LocalPositionNedMsg", "MainMode", "OdometryMsg", "ParamValueMsg",
           "Px4Mode", "SetAttitudeTargetMsg", "SetPositionTargetLocalNedMsg", "StatusTextMsg",
           "TimesyncMsg", "command_name", "mavlink", "result_name"]

#: PX4's default ``COM_OF_LOSS_T``: offboard setpoints older than this are a lost stream.
COM_OF_LOSS_T_S = 1.0
#: How long setpoints must have streamed before PX4 takes offboard mode (its commander's
#: hysteresis on "offboard available").
OFFBOARD_STREAM_S = 1.0
#: MAV_CMD_COMPONENT_ARM_DISARM param2 that forces a disarm in the air (PX4 and ArduPilot).
FORCE_DISARM = 21196.0


class MainMode(IntEnum):
    MANUAL = 1
    ALTCTL = 2
    POSCTL = 3
    AUTO = 4
    ACRO = 5
    OFFBOARD = 6
    STABILIZED = 7
    RATTITUDE_LEGACY = 8
    SIMPLE = 9
    TERMINATION = 10


class AutoSubMode(IntEnum):
    READY = 1
    TAKEOFF = 2
    LOITER = 3
    MISSION = 4
    RTL = 5
    LAND = 6
    FOLLOW_TARGET = 8
    PRECLAND = 9
    VTOL_TAKEOFF = 10


class Px4Mode:
    """A PX4 flight mode as (main, sub); ``custom_mode`` is its HEARTBEAT encoding."""

    __slots__ = ("main", "sub")

    def __init__(self, main: int, sub: int = 0) -> None:
        self.main = int(main)
        self.sub = int(sub)

    @classmethod
    def decode(cls, custom_mode: int) -> Px4Mode:
        return cls((int(custom_mode) >> 16) & 0xFF, (int(custom_mode) >> 24) & 0xFF)

    @property
    def custom_mode(self) -> int:
        return (self.main << 16) | (self.sub << 24)

    @property
    def is_offboard(self) -> bool:
        return self.main == MainMode.OFFBOARD

    def __eq__(self, other: object) -> bool:
        return isinstance(other, Px4Mode) and (self.main, self.sub) == (other.main, other.sub)

    def __hash__(self) -> int:
        return hash((self.main, self.sub))

    def __repr__(self) -> str:
        return f"Px4Mode({self})"

    def __str__(self) -> str:
        try:
            main = MainMode(self.main).name
        except ValueError:
            return f"main mode {self.main}, sub mode {self.sub}"
        if self.main != MainMode.AUTO:
            return main
        try:
            return f"AUTO.{AutoSubMode(self.sub).name}"
        except ValueError:
            return f"AUTO.{self.sub}"


OFFBOARD = Px4Mode(MainMode.OFFBOARD)
HOLD = Px4Mode(MainMode.AUTO, AutoSubMode.LOITER)
LAND = Px4Mode(MainMode.AUTO, AutoSubMode.LAND)
POSCTL = Px4Mode(MainMode.POSCTL)


def result_name(result: int) -> str:
    """``MAV_RESULT`` value → its name (e.g. ``MAV_RESULT_TEMPORARILY_REJECTED``)."""
    entry = mavlink.enums["MAV_RESULT"].get(int(result))
    return entry.name if entry is not None else f"MAV_RESULT {result}"


def command_name(command: int) -> str:
    """``MAV_CMD`` value → its name (e.g. ``MAV_CMD_DO_SET_MODE``)."""
    entry = mavlink.enums["MAV_CMD"].get(int(command))
    return entry.name if entry is not None else f"MAV_CMD {command}"


# --- the fields we read of each message ----------------------------------------------------
# pymavlink has no types: these say what a handler reads of the message its name dispatched to
# (a pymavlink message of that type has these among its fields). A char array arrives as str,
# or as bytes when it does not decode.


class HeartbeatMsg(Protocol):
    type: int
    autopilot: int
    base_mode: int
    custom_mode: int


class TimesyncMsg(Protocol):
    tc1: int
    ts1: int


class GpsGlobalOriginMsg(Protocol):
    latitude: int
    longitude: int
    altitude: int


class OdometryMsg(Protocol):
    time_usec: int
    frame_id: int
    child_frame_id: int
    x: float
    y: float
    z: float
    q: Sequence[float]
    vx: float
    vy: float
    vz: float
    rollspeed: float
    pitchspeed: float
    yawspeed: float
    pose_covariance: Sequence[float]


class _NedPositionVelocity(Protocol):
    """A position and velocity in PX4's local NED frame [m, m/s]."""

    x: float
    y: float
    z: float
    vx: float
    vy: float
    vz: float


class LocalPositionNedMsg(_NedPositionVelocity, Protocol):
    time_boot_ms: int


class AttitudeQuaternionMsg(Protocol):
    time_boot_ms: int
    q1: float
    q2: float
    q3: float
    q4: float
    rollspeed: float
    pitchspeed: float
    yawspeed: float


class CommandAckMsg(Protocol):
    command: int
    result: int


class ParamValueMsg(Protocol):
    param_id: str | bytes
    param_value: float


class ExtendedSysStateMsg(Protocol):
    landed_state: int


class StatusTextMsg(Protocol):
    text: str | bytes


class SetAttitudeTargetMsg(Protocol):
    type_mask: int
    q: Sequence[float]
    body_yaw_rate: float
    thrust: float


class SetPositionTargetLocalNedMsg(_NedPositionVelocity, Protocol):
    coordinate_frame: int
    type_mask: int
    afx: float
    afy: float
    afz: float
    yaw: float
    yaw_rate: float


class CommandMsg(Protocol):
    """COMMAND_LONG or COMMAND_INT."""

    command: int
    param1: float
    param2: float
    param3: float
    param4: float

    def get_srcSystem(self) -> int: ...

    def get_srcComponent(self) -> int: ...
