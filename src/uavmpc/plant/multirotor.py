"""6-DoF multirotor plant: attitude loop + motors + rigid body + drag + wind + ground (SPEC §4).

State vector x (13 + n,): position (3) and velocity (3) in the world frame ENU [m, m/s],
attitude quaternion (4) (w, x, y, z) body → world, body rates (3) in FLU [rad/s], rotor
speeds (n) [rad/s].

Dynamics:
    ṗ = v
    m v̇ = R (Σ k_f ωᵢ²) e₃ − R D Rᵀ (v − wind) − m g e₃
    q̇ = ½ q ⊗ (0, Ω)
    J Ω̇ = τ − Ω × J Ω,   τ from rotor positions (thrust) and spins (drag torque k_m ωᵢ²)
    ω̇ᵢ = (sat(ω_cmd,i) − ωᵢ) / τ_motor

Integration: classical RK4 with a fixed substep (2 ms default), the quaternion renormalized
after each step. RK4 rather than semi-implicit Euler because a tumbling body's angular momentum
and the quaternion's norm drift visibly with first-order schemes at 2 ms, while RK4's error at
rates of a few rad/s is ~1e-10 per step; its four evaluations cost little once compiled. The
attitude controller runs once per substep (zero-order hold of the rotor commands), wind is held
over one :meth:`Multirotor.step` call.

Ground contact (z = 0, flat): after each substep the height is clamped to 0 and a downward
velocity removed (inelastic: no bounce, no NaN). If in contact the thrust cannot lift the
vehicle, it rests: velocity and rates are zeroed and roll/pitch levelled (yaw kept), and the
attitude loop's integrator is frozen, like an autopilot's landed state.

Two implementations: a compiled one (:mod:`uavmpc.plant.kernels`, numba, default) and plain
numpy here (``backend="numpy"``, readable, the reference); a test proves they agree to 1e-9.
"""

from __future__ import annotations

import math
from typing import Literal

import numpy as np

from uavmpc.control.attitude import AttitudeController, Mixer, pack_gains
from uavmpc.plant.airframe import G_MPS2, Airframe
from uavmpc.plant.interface import AttitudeTarget, VehicleState, quat_to_rot
from uavmpc.plant.kernels import N_RIGID, run_substeps
from uavmpc.plant.wind import Wind

Backend = Literal["numba", "numpy"]
__all__ = ["N_RIGID", "Backend", "Multirotor", "ground_numpy", "rhs_numpy"]


# --------------------------------------------------------------------------------------------
# Plain numpy path (reference)
# --------------------------------------------------------------------------------------------


_rot = quat_to_rot  # the same matrix as the contract's; one definition


def rhs_numpy(x: np.ndarray, cmd: np.ndarray, af: Airframe, wind: np.ndarray) -> np.ndarray:
    """ẋ for state ``x`` (13 + n,) and rotor commands ``cmd`` (n,) [rad/s] (readable version)."""
    v, q, w, rotors = x[3:6], x[6:10], x[10:13], x[N_RIGID:]
    rot = _rot(q)
    wrench = af.allocation() @ rotors**2  # [T, τx, τy, τz]
    f_body = np.array([0.0, 0.0, wrench[0]]) - af.drag_n_per_mps * (rot.T @ (v - wind))
    acc = rot @ f_body / af.mass_kg - np.array([0.0, 0.0, G_MPS2])
    qdot = 0.5 * np.array(
        [
            -q[1:] @ w,
            *(q[0] * w + np.cross(q[1:], w)),
        ]
    )
    j = af.inertia_kgm2
    wdot = np.linalg.solve(j, wrench[1:] - np.cross(w, j @ w))
    rdot = (np.clip(cmd, 0.0, af.omega_max_radps) - rotors) / af.motor_tau_s
    return np.concatenate([v, acc, qdot, wdot, rdot])


def ground_numpy(x: np.ndarray, af: Airframe) -> bool:
    """Numpy version of the ground contact (see the module docstring); modifies ``x``."""
    if x[2] > 0.0:
        return False
    x[2] = 0.0
    x[5] = max(x[5], 0.0)
    rot = _rot(x[6:10])
    if af.k_f * np.sum(x[N_RIGID:] ** 2) * rot[2, 2] >= af.mass_kg * G_MPS2:
        return False
    yaw = math.atan2(rot[1, 0], rot[0, 0])
    x[3:6] = 0.0
    x[6:10] = [math.cos(0.5 * yaw), 0.0, 0.0, math.sin(0.5 * yaw)]
    x[10:13] = 0.0
    return True


# --------------------------------------------------------------------------------------------
# The plant
# --------------------------------------------------------------------------------------------


class Multirotor:
    """Simulated multirotor behind the :class:`~uavmpc.plant.interface.Plant` protocol.

    Args:
        airframe: parameters and attitude-loop gains.
        position_m: (3,) initial position (ENU) [m].
        yaw_rad: initial heading (level attitude).
        wind: wind model (None: still air).
        substep_s: integration and attitude-loop step (≤ 2 ms).
        t0_s: initial time [s].
        rotors_at_hover: start the rotors at hover speed (default: when above the ground).
        backend: ``"numba"`` (fast) or ``"numpy"`` (reference).
    """

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
        backend: Backend = "numba",
    ) -> None:
        if not 0.0 < substep_s <= 0.002 + 1e-12:
            raise ValueError(f"substep_s must be in (0, 0.002], got {substep_s}")
        if backend not in ("numba", "numpy"):
            raise ValueError(f"backend must be 'numba' or 'numpy', got {backend!r}")
        self.airframe = airframe
        self.wind = wind
        self.substep_s = float(substep_s)
        self.backend: Backend = backend
        self.t_s = float(t0_s)
        n = airframe.n_rotors
        self._x = np.zeros(N_RIGID + n)
        self._x[0:3] = np.asarray(position_m, dtype=float)
        self._x[6] = math.cos(0.5 * yaw_rad)
        self._x[9] = math.sin(0.5 * yaw_rad)
        if rotors_at_hover is None:
            rotors_at_hover = self._x[2] > 0.0
        if rotors_at_hover:
            self._x[N_RIGID:] = airframe.hover_omega_radps
        # Compiled-path parameter arrays, packed once.
        self._phys = np.array(
            [airframe.mass_kg, G_MPS2, airframe.motor_tau_s, airframe.omega_max_radps,
             *airframe.drag_n_per_mps]
        )
        self._inertia = np.ascontiguousarray(airframe.inertia_kgm2, dtype=float)
        self._inertia_inv = np.linalg.inv(self._inertia)
        self._alloc = np.ascontiguousarray(airframe.allocation())
        self._gains = pack_gains(airframe.attitude)
        mixer = Mixer(airframe)
        self._mix_inv = np.ascontiguousarray(mixer.inverse)
        self._lo, self._hi = mixer.lo_radps2, mixer.hi_radps2
        self._ctrl = np.zeros(7)
        self._landed = np.zeros(1)
        self._controller = AttitudeController(airframe)  # numpy path
        self._ground_once()

    # -- Plant protocol ------------------------------------------------------------------------

    def state(self) -> VehicleState:
        """The true state (copies)."""
        x = self._x
        return VehicleState(
            t_s=self.t_s,
            position_m=x[0:3].copy(),
            velocity_mps=x[3:6].copy(),
            attitude_wxyz=x[6:10].copy(),
            body_rates_radps=x[10:13].copy(),
        )

    def step(self, target: AttitudeTarget, dt_s: float) -> VehicleState:
        """Fly ``target`` for ``dt_s`` (a whole number of substeps) and return the new state.

        Raises:
            ValueError: a target that is not finite or whose quaternion is far from unit length
                (fail fast instead of integrating NaN).
        """
        qd = np.asarray(target.attitude_wxyz, dtype=float)
        ff = np.asarray(target.body_rates_ff_radps, dtype=float)
        thrust = float(target.thrust_n)
        norm = math.sqrt(float(qd @ qd))
        if not (0.9 < norm < 1.1 and math.isfinite(thrust) and np.isfinite(ff).all()):
            raise ValueError(f"invalid attitude target: {target}")
        self._advance(dt_s, False, self._no_cmd(), qd / norm, thrust, ff)
        return self.state()

    # -- extras for tests and other simulators ------------------------------------------------

    def step_motors(self, omega_cmd_radps: np.ndarray, dt_s: float) -> VehicleState:
        """Command rotor speeds directly (the attitude loop is bypassed) for ``dt_s``."""
        cmd = np.asarray(omega_cmd_radps, dtype=float).reshape(self.airframe.n_rotors)
        self._advance(dt_s, True, cmd, np.array([1.0, 0.0, 0.0, 0.0]), 0.0, np.zeros(3))
        return self.state()

    @property
    def rotor_speeds_radps(self) -> np.ndarray:
        """(n,) current rotor speeds [rad/s]."""
        return self._x[N_RIGID:].copy()

    @property
    def landed(self) -> bool:
        """True while the vehicle rests on the ground."""
        return bool(self._landed[0])

    def set_state(
        self, state: VehicleState, rotor_speeds_radps: np.ndarray | None = None
    ) -> None:
        """Overwrite the state (e.g. to start from a given motion); resets the attitude loop."""
        self.t_s = float(state.t_s)
        self._x[0:3] = state.position_m
        self._x[3:6] = state.velocity_mps
        self._x[6:10] = np.asarray(state.attitude_wxyz) / np.linalg.norm(state.attitude_wxyz)
        self._x[10:13] = state.body_rates_radps
        if rotor_speeds_radps is not None:
            self._x[N_RIGID:] = rotor_speeds_radps
        self._ctrl[:] = 0.0
        self._controller.reset()
        self._landed[0] = 0.0
        self._ground_once()

    # -- internals --------------------------------------------------------------------------------

    def _no_cmd(self) -> np.ndarray:
        return np.zeros(self.airframe.n_rotors)

    def _ground_once(self) -> None:
        if self._x[2] <= 0.0:
            self._landed[0] = 1.0 if ground_numpy(self._x, self.airframe) else 0.0

    def _substeps(self, dt_s: float) -> int:
        n = round(dt_s / self.substep_s)
        if n < 1 or abs(n * self.substep_s - dt_s) > 1e-9:
            raise ValueError(f"dt_s={dt_s} is not a whole number of substeps of {self.substep_s}")
        return n

    def _advance(
        self, dt_s: float, direct: bool, cmd: np.ndarray, qd: np.ndarray, thrust: float,
        ff: np.ndarray,
    ) -> None:
        n_sub = self._substeps(dt_s)
        wind = self.wind.update(dt_s) if self.wind is not None else np.zeros(3)
        if self.backend == "numba":
            run_substeps(
                self._x, self._ctrl, self._landed, n_sub, self.substep_s, direct, cmd, qd,
                thrust, ff, wind, self._phys, self._inertia, self._inertia_inv, self._alloc,
                self._gains, self._mix_inv, self._lo, self._hi,
            )
        else:
            self._advance_numpy(n_sub, direct, cmd, qd, thrust, ff, wind)
        self.t_s += n_sub * self.substep_s

    def _advance_numpy(
        self, n_sub: int, direct: bool, cmd: np.ndarray, qd: np.ndarray, thrust: float,
        ff: np.ndarray, wind: np.ndarray,
    ) -> None:
        af, h, x = self.airframe, self.substep_s, self._x
        for _ in range(n_sub):
            if not direct:
                cmd = self._controller.update(
                    x[6:10], x[10:13], qd, thrust, ff, h, freeze_integral=self.landed
                )
            k1 = rhs_numpy(x, cmd, af, wind)
            k2 = rhs_numpy(x + 0.5 * h * k1, cmd, af, wind)
            k3 = rhs_numpy(x + 0.5 * h * k2, cmd, af, wind)
            k4 = rhs_numpy(x + h * k3, cmd, af, wind)
            x += h / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
            x[6:10] /= np.linalg.norm(x[6:10])
            self._landed[0] = 1.0 if ground_numpy(x, af) else 0.0
