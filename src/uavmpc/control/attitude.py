"""Autopilot-like attitude controller (SPEC §4), in the structure of PX4's multicopter loops:

    quaternion attitude error (tilt first, yaw weighted) → body-rate setpoint (P, rate-limited,
    + feedforward)
    → rate PID (D on the measured rate) → torques (× inertia, + gyroscopic term)
    → mixer (rotor geometry, yaw authority given up first on saturation) → rotor-speed commands.

It runs at every plant substep (500 Hz by default), inside the plant: the onboard stack only
sends an :class:`~uavmpc.plant.interface.AttitudeTarget`.

Two implementations of the same law: :class:`AttitudeController` here (plain numpy, readable, the
reference) and :func:`uavmpc.plant.kernels.attitude_kernel` (numba, called from the plant's
compiled loop; it lives with the other kernels because numba's on-disk cache only notices edits
to the file a kernel is defined in). A test proves they agree to 1e-9.
"""

from __future__ import annotations

import math

import numpy as np

from uavmpc.plant.airframe import Airframe, AttitudeGains
from uavmpc.plant.interface import quat_to_rot


class Mixer:
    """Maps collective thrust and body torques to rotor-speed commands for one airframe.

    Attributes:
        inverse: (n, 4) pseudo-inverse of the allocation matrix: ω² = inverse @ [T, τx, τy, τz].
        lo_radps2, hi_radps2: allowed range of ω² while flying (idle² … max²) [(rad/s)²].
    """

    def __init__(self, airframe: Airframe) -> None:
        self.inverse = np.linalg.pinv(airframe.allocation())
        self.lo_radps2 = airframe.omega_idle_radps**2
        self.hi_radps2 = airframe.omega_max_radps**2

    def mix(self, thrust_n: float, torque_nm: np.ndarray) -> np.ndarray:
        """(n,) rotor-speed commands [rad/s] for the collective thrust [N] and body torque [N·m].

        On saturation the yaw torque is scaled down first (as PX4 does): losing yaw for a moment
        is harmless, losing roll/pitch is not. What remains out of range is clipped.
        """
        u = self.inverse @ np.array([thrust_n, torque_nm[0], torque_nm[1], 0.0])
        u_yaw = self.inverse[:, 3] * torque_nm[2]
        scale = 1.0
        over = (u_yaw > 0.0) & (u + u_yaw > self.hi_radps2)
        under = (u_yaw < 0.0) & (u + u_yaw < self.lo_radps2)
        if over.any():
            room = (self.hi_radps2 - u[over]) / u_yaw[over]
            scale = min(scale, float(np.min(np.maximum(0.0, room))))
        if under.any():
            room = (self.lo_radps2 - u[under]) / u_yaw[under]
            scale = min(scale, float(np.min(np.maximum(0.0, room))))
        u = np.clip(u + scale * u_yaw, self.lo_radps2, self.hi_radps2)
        return np.sqrt(u)


def pack_gains(g: AttitudeGains) -> np.ndarray:
    """(7, 3) gain table for :func:`attitude_kernel`: rows angle P (yaw already divided by the
    yaw weight), max rate, rate P, rate I, rate D, integral limit, [yaw weight, 0, 0]."""
    return np.vstack(
        [_angle_gain(g), g.max_rate_radps, g.rate_p_per_s, g.rate_i_per_s2, g.rate_d,
         g.rate_integral_limit_radps2, [g.yaw_weight, 0.0, 0.0]]
    ).astype(float)


def _angle_gain(g: AttitudeGains) -> np.ndarray:
    # The yaw-weighted target only carries yaw_weight of the yaw error; dividing the yaw gain by
    # it keeps the small-error yaw response at angle_p (as PX4 does).
    return g.angle_p_per_s / np.array([1.0, 1.0, g.yaw_weight])


def weighted_target(q: np.ndarray, qd: np.ndarray, yaw_weight: float) -> np.ndarray:
    """PX4's yaw de-prioritization: the target reached by first turning the thrust axis the
    shortest way onto the desired one, then only ``yaw_weight`` of the remaining heading error.

    Correcting a combined tilt + heading error along the single shortest rotation would swing the
    thrust axis sideways (and beyond its target tilt) while turning; this keeps it on course.
    """
    ez, ezd = quat_to_rot(q)[:, 2], quat_to_rot(qd)[:, 2]
    cr = np.cross(ez, ezd)
    red = np.concatenate([[ez @ ezd + 1.0], cr])  # half-way quaternion from ez to ezd
    red /= np.linalg.norm(red)
    if abs(red[1]) > 1.0 - 1e-5 or abs(red[2]) > 1.0 - 1e-5:
        return qd  # thrust axes opposite: the full error already turns the right way
    red = quat_mul(red, q)
    mix = quat_mul(quat_conj(red), qd)  # remaining pure heading rotation
    if mix[0] < 0.0:
        mix = -mix
    w0 = min(max(mix[0], -1.0), 1.0)
    w3 = min(max(mix[3], -1.0), 1.0)
    return quat_mul(
        red, np.array([math.cos(yaw_weight * math.acos(w0)), 0.0, 0.0,
                       math.sin(yaw_weight * math.asin(w3))])
    )


class AttitudeController:
    """Plain-numpy attitude controller (the reference implementation of :func:`attitude_kernel`).

    State: the rate integrator (3,) [rad/s²] and the last measured rate (3,) for the D term.
    """

    def __init__(self, airframe: Airframe) -> None:
        self.gains = airframe.attitude
        self.inertia = airframe.inertia_kgm2
        self.mixer = Mixer(airframe)
        self.integral = np.zeros(3)
        self.last_rates: np.ndarray | None = None

    def reset(self) -> None:
        self.integral = np.zeros(3)
        self.last_rates = None

    def update(
        self,
        attitude_wxyz: np.ndarray,
        body_rates_radps: np.ndarray,
        target_wxyz: np.ndarray,
        thrust_n: float,
        rates_ff_radps: np.ndarray,
        dt_s: float,
        *,
        freeze_integral: bool = False,
    ) -> np.ndarray:
        """(n,) rotor-speed commands [rad/s] for one control period ``dt_s``.

        ``freeze_integral`` holds the rate integrator (set while the vehicle rests on the
        ground, where the rates cannot follow and the integrator would wind up).
        """
        g = self.gains
        qd = weighted_target(attitude_wxyz, target_wxyz, g.yaw_weight)
        qe = quat_mul(quat_conj(attitude_wxyz), qd)  # error in the body frame
        if qe[0] < 0.0:  # the short way round
            qe = -qe
        rate_sp = _angle_gain(g) * 2.0 * qe[1:] + rates_ff_radps
        rate_sp = np.clip(rate_sp, -g.max_rate_radps, g.max_rate_radps)
        err = rate_sp - body_rates_radps
        last = body_rates_radps if self.last_rates is None else self.last_rates
        rate_dot = (body_rates_radps - last) / dt_s
        # D on the measurement, not the error: a setpoint step does not kick the motors.
        alpha = g.rate_p_per_s * err + self.integral - g.rate_d * rate_dot
        if not freeze_integral:
            lim = g.rate_integral_limit_radps2
            self.integral = np.clip(self.integral + g.rate_i_per_s2 * err * dt_s, -lim, lim)
        self.last_rates = body_rates_radps.copy()
        w = body_rates_radps
        torque = self.inertia @ alpha + np.cross(w, self.inertia @ w)
        return self.mixer.mix(thrust_n, torque)


def quat_mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product a ⊗ b of (w, x, y, z) quaternions."""
    aw, av = a[0], a[1:]
    bw, bv = b[0], b[1:]
    return np.concatenate([[aw * bw - av @ bv], aw * bv + bw * av + np.cross(av, bv)])


def quat_conj(q: np.ndarray) -> np.ndarray:
    return np.array([q[0], -q[1], -q[2], -q[3]])
