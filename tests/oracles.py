"""Plain-numpy renderings of the plant's and the SE(3) controller's laws (test helpers only).

The laws live once in src/, as compiled kernels (:mod:`uavmpc.plant.kernels`,
:mod:`uavmpc.plant.attitude`, :mod:`uavmpc.control.se3`). These oracles say the same thing in
readable vector algebra; the tests fly both and compare, so a slip in either shows up.
"""

from __future__ import annotations

import math

import numpy as np

from uavmpc.control.se3 import PositionCommand
from uavmpc.plant import G_MPS2, Airframe, AttitudeTarget, VehicleState, Wind
from uavmpc.plant.interface import cross3, quat_to_rot, rot_to_quat
from uavmpc.plant.kernels import N_RIGID

_E3 = np.array([0.0, 0.0, 1.0])


# --------------------------------------------------------------------------------- quaternions
def quat_mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product a ⊗ b of (w, x, y, z) quaternions."""
    aw, av = a[0], a[1:]
    bw, bv = b[0], b[1:]
    return np.concatenate([[aw * bw - av @ bv], aw * bv + bw * av + np.cross(av, bv)])


def quat_conj(q: np.ndarray) -> np.ndarray:
    return np.array([q[0], -q[1], -q[2], -q[3]])


# ------------------------------------------------------------------------------ attitude loop
class Mixer:
    """Collective thrust and body torques → rotor-speed commands for one airframe.

    Attributes:
        inverse: (n, 4) pseudo-inverse of the allocation matrix: ω² = inverse @ [T, τx, τy, τz].
        lo_radps2, hi_radps2: allowed range of ω² while flying (idle² … max²) [(rad/s)²].
    """

    def __init__(self, airframe: Airframe) -> None:
        self.inverse = np.linalg.pinv(airframe.allocation())
        self.lo_radps2 = airframe.omega_idle_radps**2
        self.hi_radps2 = airframe.omega_max_radps**2

    def mix(self, thrust_n: float, torque_nm: np.ndarray) -> np.ndarray:
        """(n,) rotor-speed commands [rad/s]; on saturation the yaw torque gives way first."""
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


def weighted_target(q: np.ndarray, qd: np.ndarray, yaw_weight: float) -> np.ndarray:
    """PX4's yaw de-prioritization: turn the thrust axis first, then ``yaw_weight`` of the rest
    of the heading error."""
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
    """The attitude loop of :func:`uavmpc.plant.attitude.attitude_kernel`.

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
        """(n,) rotor-speed commands [rad/s] for one control period ``dt_s``."""
        g = self.gains
        qd = weighted_target(attitude_wxyz, target_wxyz, g.yaw_weight)
        qe = quat_mul(quat_conj(attitude_wxyz), qd)  # error in the body frame
        if qe[0] < 0.0:  # the short way round
            qe = -qe
        angle_p = g.angle_p_per_s / np.array([1.0, 1.0, g.yaw_weight])
        rate_sp = angle_p * 2.0 * qe[1:] + rates_ff_radps
        rate_sp = np.clip(rate_sp, -g.max_rate_radps, g.max_rate_radps)
        err = rate_sp - body_rates_radps
        last = body_rates_radps if self.last_rates is None else self.last_rates
        rate_dot = (body_rates_radps - last) / dt_s
        alpha = g.rate_p_per_s * err + self.integral - g.rate_d * rate_dot
        if not freeze_integral:
            lim = g.rate_integral_limit_radps2
            self.integral = np.clip(self.integral + g.rate_i_per_s2 * err * dt_s, -lim, lim)
        self.last_rates = body_rates_radps.copy()
        w = body_rates_radps
        torque = self.inertia @ alpha + np.cross(w, self.inertia @ w)
        return self.mixer.mix(thrust_n, torque)


# -------------------------------------------------------------------------------------- plant
def rhs_numpy(x: np.ndarray, cmd: np.ndarray, af: Airframe, wind: np.ndarray) -> np.ndarray:
    """ẋ for state ``x`` (13 + n,) and rotor commands ``cmd`` (n,) [rad/s]."""
    v, q, w, rotors = x[3:6], x[6:10], x[10:13], x[N_RIGID:]
    rot = quat_to_rot(q)
    wrench = af.allocation() @ rotors**2  # [T, τx, τy, τz]
    f_body = np.array([0.0, 0.0, wrench[0]]) - af.drag_n_per_mps * (rot.T @ (v - wind))
    acc = rot @ f_body / af.mass_kg - np.array([0.0, 0.0, G_MPS2])
    qdot = 0.5 * np.array([-q[1:] @ w, *(q[0] * w + np.cross(q[1:], w))])
    j = af.inertia_kgm2
    wdot = np.linalg.solve(j, wrench[1:] - np.cross(w, j @ w))
    rdot = (np.clip(cmd, 0.0, af.omega_max_radps) - rotors) / af.motor_tau_s
    return np.concatenate([v, acc, qdot, wdot, rdot])


def ground_numpy(x: np.ndarray, af: Airframe) -> bool:
    """Flat-ground contact at z = 0 (modifies ``x``); True when the vehicle rests."""
    if x[2] > 0.0:
        return False
    x[2] = 0.0
    x[5] = max(x[5], 0.0)
    rot = quat_to_rot(x[6:10])
    if af.k_f * np.sum(x[N_RIGID:] ** 2) * rot[2, 2] >= af.mass_kg * G_MPS2:
        return False
    yaw = math.atan2(rot[1, 0], rot[0, 0])
    x[3:6] = 0.0
    x[6:10] = [math.cos(0.5 * yaw), 0.0, 0.0, math.sin(0.5 * yaw)]
    x[10:13] = 0.0
    return True


class MultirotorOracle:
    """:class:`uavmpc.plant.Multirotor` in numpy: the same constructor (without ``rows``),
    ``state``, ``step``, ``step_motors``, ``rotor_speeds_radps``, ``landed``, ``set_state``;
    the state vector is :attr:`x` (13 + n,)."""

    def __init__(
        self,
        airframe: Airframe,
        *,
        position_m: np.ndarray | tuple[float, float, float] = (0.0, 0.0, 0.0),
        yaw_rad: float = 0.0,
        wind: Wind | None = None,
        substep_s: float = 0.002,
        t0_s: float = 0.0,
        rotors_at_hover: bool | None = None,
    ) -> None:
        self.airframe = airframe
        self.wind = wind
        self.substep_s = float(substep_s)
        self.t_s = float(t0_s)
        self.x = np.zeros(N_RIGID + airframe.n_rotors)
        self.x[0:3] = np.asarray(position_m, dtype=float)
        self.x[6] = math.cos(0.5 * yaw_rad)
        self.x[9] = math.sin(0.5 * yaw_rad)
        if rotors_at_hover is None:
            rotors_at_hover = self.x[2] > 0.0
        if rotors_at_hover:
            self.x[N_RIGID:] = airframe.hover_omega_radps
        self.landed = False
        self._controller = AttitudeController(airframe)
        self._ground_once()

    def state(self) -> VehicleState:
        x = self.x
        return VehicleState(self.t_s, x[0:3].copy(), x[3:6].copy(), x[6:10].copy(),
                            x[10:13].copy())

    def step(self, target: AttitudeTarget, dt_s: float) -> VehicleState:
        qd = np.asarray(target.attitude_wxyz, dtype=float)
        ff = np.asarray(target.body_rates_ff_radps, dtype=float)
        thrust = float(target.thrust_n)
        norm = math.sqrt(float(qd @ qd))
        if not (0.9 < norm < 1.1 and math.isfinite(thrust) and np.isfinite(ff).all()):
            raise ValueError(f"invalid attitude target: {target}")
        self._advance(dt_s, None, qd / norm, thrust, ff)
        return self.state()

    def step_motors(self, omega_cmd_radps: np.ndarray, dt_s: float) -> VehicleState:
        cmd = np.asarray(omega_cmd_radps, dtype=float).reshape(self.airframe.n_rotors)
        self._advance(dt_s, cmd, np.array([1.0, 0.0, 0.0, 0.0]), 0.0, np.zeros(3))
        return self.state()

    @property
    def rotor_speeds_radps(self) -> np.ndarray:
        return self.x[N_RIGID:].copy()

    def set_state(
        self, state: VehicleState, rotor_speeds_radps: np.ndarray | None = None
    ) -> None:
        self.t_s = float(state.t_s)
        self.x[0:3] = state.position_m
        self.x[3:6] = state.velocity_mps
        self.x[6:10] = np.asarray(state.attitude_wxyz) / np.linalg.norm(state.attitude_wxyz)
        self.x[10:13] = state.body_rates_radps
        if rotor_speeds_radps is not None:
            self.x[N_RIGID:] = rotor_speeds_radps
        self._controller.reset()
        self.landed = False
        self._ground_once()

    def _ground_once(self) -> None:
        if self.x[2] <= 0.0:
            self.landed = ground_numpy(self.x, self.airframe)

    def _advance(self, dt_s: float, direct_cmd: np.ndarray | None, qd: np.ndarray,
                 thrust: float, ff: np.ndarray) -> None:
        n_sub = round(dt_s / self.substep_s)
        if n_sub < 1 or abs(n_sub * self.substep_s - dt_s) > 1e-9:
            raise ValueError(f"dt_s={dt_s} is not a whole number of substeps")
        wind = self.wind.update(dt_s) if self.wind is not None else np.zeros(3)
        af, h, x = self.airframe, self.substep_s, self.x
        cmd = direct_cmd
        for _ in range(n_sub):
            if direct_cmd is None:
                cmd = self._controller.update(
                    x[6:10], x[10:13], qd, thrust, ff, h, freeze_integral=self.landed
                )
            k1 = rhs_numpy(x, cmd, af, wind)
            k2 = rhs_numpy(x + 0.5 * h * k1, cmd, af, wind)
            k3 = rhs_numpy(x + 0.5 * h * k2, cmd, af, wind)
            k4 = rhs_numpy(x + h * k3, cmd, af, wind)
            x += h / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
            x[6:10] /= np.linalg.norm(x[6:10])
            self.landed = ground_numpy(x, af)
        self.t_s += n_sub * self.substep_s


# ------------------------------------------------------------------------------------- SE(3)
class Se3Oracle:
    """:class:`uavmpc.control.Se3Controller` in numpy: ``update``, ``reset`` and the
    attributes ``integral_world_ms``, ``integral_body_ms``, ``saturated``, ``tilt_limited``."""

    def __init__(self, airframe: Airframe, *, period_s: float = 0.01) -> None:
        self.airframe = airframe
        self.gains = airframe.se3
        self.period_s = float(period_s)
        self.thrust_min_n = self.gains.thrust_min_fraction * airframe.max_thrust_n
        self.thrust_max_n = self.gains.thrust_max_fraction * airframe.max_thrust_n
        self.reset()

    def reset(self) -> None:
        self.integral_world_ms = np.zeros(3)
        self.integral_body_ms = np.zeros(3)
        self.saturated = False
        self.tilt_limited = False

    def update(self, command: PositionCommand, state: VehicleState,
               dt_s: float | None = None) -> AttitudeTarget:
        g = self.gains
        dt = self.period_s if dt_s is None else float(dt_s)
        rot = state.rotation()
        e_p = state.position_m - np.asarray(command.position_m, dtype=float)
        e_v = state.velocity_mps - np.asarray(command.velocity_mps, dtype=float)
        m = self.airframe.mass_kg
        force = (
            m * (np.asarray(command.acceleration_mps2, dtype=float) + G_MPS2 * _E3)
            - g.kp_n_per_m * e_p
            - g.kv_n_per_mps * e_v
            - rot @ (g.ki_body_n_per_ms * self.integral_body_ms)
            - g.ki_world_n_per_ms * self.integral_world_ms
        )
        force = self._limit_tilt(force)
        b3 = force / np.linalg.norm(force)
        psi = float(command.heading_rad)
        b1c = np.array([math.cos(psi), math.sin(psi), 0.0])
        b2 = cross3(b3, b1c)
        b2 /= np.linalg.norm(b2)  # b3 is within 80° of vertical, so never parallel to b1c
        rot_d = np.column_stack([cross3(b2, b3), b2, b3])
        thrust = float(force @ (rot @ _E3))
        clipped = min(max(thrust, self.thrust_min_n), self.thrust_max_n)
        self.saturated = clipped != thrust
        # Integrate after the output, and only when this output is unsaturated.
        if not (self.saturated or self.tilt_limited):
            lim_w, lim_b = g.integral_limit_world_ms, g.integral_limit_body_ms
            self.integral_world_ms = np.clip(self.integral_world_ms + e_p * dt, -lim_w, lim_w)
            self.integral_body_ms = np.clip(self.integral_body_ms + rot.T @ e_p * dt,
                                            -lim_b, lim_b)
        # Heading-rate feedforward: world-z rate ψ̇ seen in the desired body frame.
        ff = float(command.heading_rate_radps) * rot_d[2, :]
        return AttitudeTarget(attitude_wxyz=rot_to_quat(rot_d), thrust_n=clipped,
                              body_rates_ff_radps=ff)

    def _limit_tilt(self, force: np.ndarray) -> np.ndarray:
        """Within ``max_tilt_rad`` of vertical, keeping the vertical part (≥ thrust_min)."""
        fz_min = self.thrust_min_n
        fz = max(float(force[2]), fz_min)
        h = float(math.hypot(force[0], force[1]))
        h_max = fz * math.tan(self.gains.max_tilt_rad)
        self.tilt_limited = h > h_max or force[2] < fz_min
        if h > h_max:
            return np.array([force[0] * h_max / h, force[1] * h_max / h, fz])
        return np.array([force[0], force[1], fz])


def align_batch(other_times_s: np.ndarray, other_positions_m: np.ndarray,
                at_times_s: np.ndarray, extrapolate_s: float) -> tuple[np.ndarray, np.ndarray]:
    """Numpy oracle of :func:`uavmpc.avoidance.proximity.align_into` for k predictions:
    positions (k, m, 3) and known (k, m)."""
    times = np.asarray(other_times_s, dtype=float)
    pos = np.asarray(other_positions_m, dtype=float)
    at = np.asarray(at_times_s, dtype=float)
    n = times.shape[1]
    count = (times[:, None, :] <= at[None, :, None]).sum(axis=2)
    j = np.clip(count - 1, 0, n - 2)
    t0 = np.take_along_axis(times, j, axis=1)
    t1 = np.take_along_axis(times, j + 1, axis=1)
    p0 = np.take_along_axis(pos, j[..., None], axis=1)
    p1 = np.take_along_axis(pos, (j + 1)[..., None], axis=1)
    w = np.maximum((at[None, :] - t0) / (t1 - t0), 0.0)
    return p0 + w[..., None] * (p1 - p0), at[None, :] <= times[:, -1:] + extrapolate_s
