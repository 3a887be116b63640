"""Geometric tracking on SE(3) (Lee, Leok, McClamroch 2010) with integral terms (SPEC §3).

    e_p = p − p_d,  e_v = v − v_d
    F_d = m (a_d + g e₃) − K_p e_p − K_v e_v − R K_ib ∫ Rᵀ e_p dt − K_iw ∫ e_p dt
    b₃,d = F_d / ‖F_d‖ (tilt limited),  b₁,d from the desired heading,
    R_d = [b₂,d × b₃,d, b₂,d, b₃,d],  T_d = F_d · R e₃ (saturated)

The gains are diagonal (per axis); the body-frame integral's gain acts in the body frame
(before R). Anti-windup: each integral is clipped to its limit, and both stop integrating while
the thrust is saturated or the tilt limited (conditional integration), so they cannot grow while
they have no effect (e.g. during a large position step).
Runs at 100 Hz; outputs an :class:`~uavmpc.plant.interface.AttitudeTarget` (quaternion + thrust).

Two implementations of the same law, chosen by ``Se3Controller(..., backend=...)``: ``"numpy"``
(:meth:`Se3Controller._update_numpy`, plain and readable, the reference) and ``"numba"`` (the
default: :func:`uavmpc.plant.kernels.se3_kernel`, ≈ 5× faster; it lives with the other kernels
because numba's on-disk cache only notices edits to the file a kernel is defined in). A test
proves they agree to 1e-12.
"""

from __future__ import annotations

import math
from typing import Literal, Protocol

import numpy as np

from uavmpc.plant.airframe import G_MPS2, Airframe, Se3Gains
from uavmpc.plant.interface import AttitudeTarget, VehicleState, cross3, rot_to_quat
from uavmpc.plant.kernels import se3_kernel

_E3 = np.array([0.0, 0.0, 1.0])


class PositionCommand(Protocol):
    """What the controller needs of a command; :class:`uavmpc.tracker.tracker.TrackerCommand`
    has exactly these fields (ENU, SI)."""

    t_s: float
    position_m: np.ndarray
    velocity_mps: np.ndarray
    acceleration_mps2: np.ndarray
    heading_rad: float
    heading_rate_radps: float


def pack_gains(g: Se3Gains, mass_kg: float) -> np.ndarray:
    """(7, 3) table for :func:`~uavmpc.plant.kernels.se3_kernel`: rows K_p, K_v, K_iw, K_ib,
    world and body integral limits, [mass, g, tan(max_tilt)]."""
    return np.ascontiguousarray(np.vstack(
        [g.kp_n_per_m, g.kv_n_per_mps, g.ki_world_n_per_ms, g.ki_body_n_per_ms,
         g.integral_limit_world_ms, g.integral_limit_body_ms,
         [mass_kg, G_MPS2, math.tan(g.max_tilt_rad)]]
    ).astype(float))


class Se3Controller:
    """SE(3) controller for one airframe (gains from its ``[se3]`` section).

    Args:
        airframe: mass, thrust range and gains.
        period_s: control period, used as the integrators' step when ``update`` gets no dt.
        backend: ``"numba"`` (compiled kernel, the default) or ``"numpy"`` (the reference).
    """

    def __init__(
        self,
        airframe: Airframe,
        *,
        period_s: float = 0.01,
        backend: Literal["numba", "numpy"] = "numba",
    ) -> None:
        if not period_s > 0.0:
            raise ValueError(f"period_s must be > 0, got {period_s}")
        if backend not in ("numba", "numpy"):
            raise ValueError(f"backend must be 'numba' or 'numpy', got {backend!r}")
        self.backend = backend
        self.airframe = airframe
        self.gains = airframe.se3
        self.period_s = float(period_s)
        self.thrust_min_n = self.gains.thrust_min_fraction * airframe.max_thrust_n
        self.thrust_max_n = self.gains.thrust_max_fraction * airframe.max_thrust_n
        self.integral_world_ms = np.zeros(3)
        self.integral_body_ms = np.zeros(3)
        self.saturated = False
        """True when the last thrust was clipped to the airframe's range."""
        self.tilt_limited = False
        """True when the last force direction was limited to ``max_tilt_rad``."""
        self._packed = pack_gains(self.gains, airframe.mass_kg)

    def reset(self) -> None:
        """Clear the integrators (e.g. on take-off)."""
        self.integral_world_ms[:] = 0.0
        self.integral_body_ms[:] = 0.0
        self.saturated = False
        self.tilt_limited = False

    def update(
        self, command: PositionCommand, state: VehicleState, dt_s: float | None = None
    ) -> AttitudeTarget:
        """One control step: the attitude target for ``state`` to follow ``command``."""
        if self.backend != "numba":
            return self._update_numpy(command, state, dt_s)
        q = np.empty(4)
        ff = np.empty(3)
        # The integrals are updated in place (np.zeros(3) from __init__: float64, contiguous).
        thrust, self.saturated, self.tilt_limited = se3_kernel(
            state.position_m, state.velocity_mps, state.attitude_wxyz,
            np.asarray(command.position_m, dtype=float),
            np.asarray(command.velocity_mps, dtype=float),
            np.asarray(command.acceleration_mps2, dtype=float),
            float(command.heading_rad), float(command.heading_rate_radps),
            self.period_s if dt_s is None else float(dt_s),
            self._packed, self.thrust_min_n, self.thrust_max_n,
            self.integral_world_ms, self.integral_body_ms, q, ff,
        )
        return AttitudeTarget(attitude_wxyz=q, thrust_n=thrust, body_rates_ff_radps=ff)

    def _update_numpy(
        self, command: PositionCommand, state: VehicleState, dt_s: float | None = None
    ) -> AttitudeTarget:
        """The plain-numpy reference of :meth:`update` (``backend="numpy"``)."""
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
        # Integrate after the output (it uses the integrals up to the previous step), and only
        # when this output is unsaturated.
        if not (self.saturated or self.tilt_limited):
            lim_w, lim_b = g.integral_limit_world_ms, g.integral_limit_body_ms
            # (np.minimum/np.maximum: same as np.clip, a few µs cheaper on (3,) arrays)
            self.integral_world_ms = np.minimum(
                np.maximum(self.integral_world_ms + e_p * dt, -lim_w), lim_w
            )
            self.integral_body_ms = np.minimum(
                np.maximum(self.integral_body_ms + rot.T @ e_p * dt, -lim_b), lim_b
            )
        # Heading-rate feedforward: world-z rate ψ̇ seen in the desired body frame.
        ff = float(command.heading_rate_radps) * rot_d[2, :]
        return AttitudeTarget(attitude_wxyz=rot_to_quat(rot_d), thrust_n=clipped,
                              body_rates_ff_radps=ff)

    def _limit_tilt(self, force: np.ndarray) -> np.ndarray:
        """Keep the force within ``max_tilt_rad`` of vertical, keeping its vertical part (height
        has priority over horizontal acceleration) and never pointing it downwards."""
        fz_min = self.thrust_min_n
        fz = max(float(force[2]), fz_min)
        h = float(math.hypot(force[0], force[1]))
        h_max = fz * math.tan(self.gains.max_tilt_rad)
        self.tilt_limited = h > h_max or force[2] < fz_min
        if h > h_max:
            return np.array([force[0] * h_max / h, force[1] * h_max / h, fz])
        return np.array([force[0], force[1], fz])
