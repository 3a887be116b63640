"""The one boundary between the onboard stack and any plant (SPEC §4): give state, take attitude +
thrust.

Everything onboard (avoidance, tracker, SE(3) controller) talks to the aircraft only through
:class:`Plant`. Our simulator (:class:`uavmpc.plant.multirotor.Multirotor`) puts the attitude
controller, the motors and the rigid body behind it; a different simulator or a real autopilot
over MAVLink (``SET_ATTITUDE_TARGET`` + odometry) can stand in without touching the stack.

Conventions: SI units, world frame ENU (z up), body frame FLU (x forward, y left, z up),
quaternions scalar-first ``(w, x, y, z)`` rotating body vectors into the world frame.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol, runtime_checkable

import numpy as np


@dataclass(frozen=True, eq=False)
class VehicleState:
    """The vehicle's (true or estimated) state.

    Attributes:
        t_s: time of the state [s].
        position_m: (3,) centre of mass in the world frame ENU [m].
        velocity_mps: (3,) velocity in the world frame [m/s].
        attitude_wxyz: (4,) unit quaternion (w, x, y, z), body → world.
        body_rates_radps: (3,) angular velocity in the body frame FLU [rad/s].
    """

    t_s: float
    position_m: np.ndarray
    velocity_mps: np.ndarray
    attitude_wxyz: np.ndarray
    body_rates_radps: np.ndarray

    def rotation(self) -> np.ndarray:
        """(3, 3) rotation matrix R (body → world) of ``attitude_wxyz``."""
        return quat_to_rot(self.attitude_wxyz)


@dataclass(frozen=True, eq=False)
class AttitudeTarget:
    """What the position controller asks of the attitude loop (MAVLink ``SET_ATTITUDE_TARGET``).

    Attributes:
        attitude_wxyz: (4,) desired unit quaternion (w, x, y, z), body → world.
        thrust_n: desired collective thrust along body z [N] (not normalized).
        body_rates_ff_radps: (3,) body-rate feedforward [rad/s] added to the attitude loop's
            rate setpoint (e.g. the heading rate); zeros if unused.
    """

    attitude_wxyz: np.ndarray
    thrust_n: float
    body_rates_ff_radps: np.ndarray = field(default_factory=lambda: np.zeros(3))


@runtime_checkable
class Plant(Protocol):
    """A vehicle the onboard stack can fly: our simulator, another one, or a real autopilot."""

    def state(self) -> VehicleState:
        """The current state (the true one in simulation)."""
        ...

    def step(self, target: AttitudeTarget, dt_s: float) -> VehicleState:
        """Hold ``target`` for ``dt_s`` seconds (attitude loop + motors + vehicle), return the
        state at the end."""
        ...


def heading_of(q: np.ndarray) -> np.ndarray | float:
    """Heading (yaw about world z) [rad] of quaternions ``(w, x, y, z)``, shape (..., 4)."""
    q = np.asarray(q)
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    return np.arctan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


def quat_to_rot(q: np.ndarray) -> np.ndarray:
    """(3, 3) rotation matrix of a unit quaternion ``(w, x, y, z)``."""
    w, x, y, z = q
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def rot_to_quat(r: np.ndarray) -> np.ndarray:
    """Unit quaternion ``(w, x, y, z)`` with w ≥ 0 of a (3, 3) rotation matrix (Shepperd's
    method: pick the largest diagonal term so the square root is well conditioned)."""
    tr = r[0, 0] + r[1, 1] + r[2, 2]
    if tr > max(r[0, 0], r[1, 1], r[2, 2]):
        s = 2.0 * np.sqrt(1.0 + tr)
        q = np.array([0.25 * s, (r[2, 1] - r[1, 2]) / s, (r[0, 2] - r[2, 0]) / s,
                      (r[1, 0] - r[0, 1]) / s])
    elif r[0, 0] >= r[1, 1] and r[0, 0] >= r[2, 2]:
        s = 2.0 * np.sqrt(1.0 + r[0, 0] - r[1, 1] - r[2, 2])
        q = np.array([(r[2, 1] - r[1, 2]) / s, 0.25 * s, (r[0, 1] + r[1, 0]) / s,
                      (r[0, 2] + r[2, 0]) / s])
    elif r[1, 1] >= r[2, 2]:
        s = 2.0 * np.sqrt(1.0 + r[1, 1] - r[0, 0] - r[2, 2])
        q = np.array([(r[0, 2] - r[2, 0]) / s, (r[0, 1] + r[1, 0]) / s, 0.25 * s,
                      (r[1, 2] + r[2, 1]) / s])
    else:
        s = 2.0 * np.sqrt(1.0 + r[2, 2] - r[0, 0] - r[1, 1])
        q = np.array([(r[1, 0] - r[0, 1]) / s, (r[0, 2] + r[2, 0]) / s,
                      (r[1, 2] + r[2, 1]) / s, 0.25 * s])
    q /= np.linalg.norm(q)
    return q if q[0] >= 0.0 else -q


def cross3(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a × b for (3,) vectors; ≈ 10× faster than ``np.cross`` on such small arrays."""
    return np.array(
        [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
    )


def yaw_quat(yaw_rad: float) -> np.ndarray:
    """Quaternion of a pure rotation by ``yaw_rad`` about world z."""
    return np.array([np.cos(0.5 * yaw_rad), 0.0, 0.0, np.sin(0.5 * yaw_rad)])
