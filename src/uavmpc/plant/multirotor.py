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
attitude loop's integrator is frozen, like an autopilot's landed state. A moving landing deck
(a square on a ground vehicle, :meth:`Multirotor.set_deck`) is a second surface: the same
inelastic contact on its top, resting means being carried along with it, and a rotor disc that
meets its edge from below the top is counted as a strike (:func:`~uavmpc.plant.kernels.
deck_contact`). Cutting the motors (:meth:`Multirotor.cut_motors`) lets the rotors spin down.

The laws are the compiled kernels of :mod:`uavmpc.plant.kernels` and
:mod:`uavmpc.plant.attitude`; the state lives in a row of a :class:`~uavmpc.plant.rows.PlantRows`
record. A :class:`Multirotor` is a view on one row: of a 1-row record of its own, or of a record
a batched driver allocated for many vehicles (``rows=``, ``row=``) and may step with
:func:`~uavmpc.plant.kernels.plant_step` itself.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

import numpy as np

from uavmpc.jit import bind
from uavmpc.plant.airframe import Airframe
from uavmpc.plant.ground_vehicle import DeckTouch
from uavmpc.plant.interface import AttitudeTarget, VehicleState
from uavmpc.plant.kernels import (
    N_RIGID,
    attitude_target_ok,
    fly_target,
    normalize_quat,
    plant_step_motors,
    settle,
)
from uavmpc.plant.rows import PlantRows
from uavmpc.plant.wind import Wind

__all__ = ["N_RIGID", "Multirotor"]


class Multirotor:
    """Simulated multirotor behind the :class:`~uavmpc.plant.interface.Plant` protocol: a view
    on one row of a :class:`~uavmpc.plant.rows.PlantRows` record.

    Args:
        airframe: parameters and attitude-loop gains.
        position_m: (3,) initial position (ENU) [m].
        yaw_rad: initial heading (level attitude).
        wind: wind model (None: still air); advanced by each step, the object's own.
        substep_s: integration and attitude-loop step (≤ 2 ms).
        t0_s: initial time [s].
        rotors_at_hover: start the rotors at hover speed (default: when above the ground).
        rows: the record to be a view on (None: a 1-row record of its own). Its row ``row`` is
            overwritten with this vehicle's airframe constants and initial state.
        row: which row of ``rows``.
    """

    def __init__(
        self,
        airframe: Airframe,
        *,
        position_m: np.ndarray | Sequence[float] = (0.0, 0.0, 0.0),
        yaw_rad: float = 0.0,
        wind: Wind | None = None,
        substep_s: float = 0.002,
        t0_s: float = 0.0,
        rotors_at_hover: bool | None = None,
        rows: PlantRows | None = None,
        row: int = 0,
    ) -> None:
        if not 0.0 < substep_s <= 0.002 + 1e-12:
            raise ValueError(f"substep_s must be in (0, 0.002], got {substep_s}")
        if rows is None:
            rows, row = PlantRows.empty(1, airframe.n_rotors), 0
        elif not 0 <= row < rows.t_s.shape[0]:
            raise ValueError(f"row {row} is not in a record of {rows.t_s.shape[0]} rows")
        self.airframe = airframe
        self.wind = wind
        self.substep_s = float(substep_s)
        self._rows = rows
        self._row = int(row)
        self._fly: Callable[..., bool] | None = None
        rows.configure(self._row, airframe, self.substep_s)
        rows.t_s[self._row] = float(t0_s)
        x = rows.x[self._row]
        x[0:3] = np.asarray(position_m, dtype=float)
        x[6] = math.cos(0.5 * yaw_rad)
        x[9] = math.sin(0.5 * yaw_rad)
        if rotors_at_hover is None:
            rotors_at_hover = x[2] > 0.0
        if rotors_at_hover:
            x[N_RIGID:N_RIGID + airframe.n_rotors] = airframe.hover_omega_radps
        settle(self._row, rows)

    # -- the record this object views ----------------------------------------------------------

    @property
    def rows(self) -> PlantRows:
        """The record holding this vehicle's state (shared with others when a driver batches)."""
        return self._rows

    @property
    def row(self) -> int:
        """This vehicle's row in :attr:`rows`."""
        return self._row

    @property
    def t_s(self) -> float:
        """Simulated time [s]."""
        return float(self._rows.t_s[self._row])

    # -- Plant protocol ------------------------------------------------------------------------

    def state(self) -> VehicleState:
        """The true state (copies)."""
        x = self._rows.x[self._row]
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
        # Copies: the quaternion is normalised in place, the caller's target stays as it was.
        qd = np.array(target.attitude_wxyz, dtype=float).reshape(4)
        ff = np.array(target.body_rates_ff_radps, dtype=float).reshape(3)
        thrust = float(target.thrust_n)
        if not attitude_target_ok(qd, thrust, ff):  # before the wind moves on
            raise ValueError(f"invalid attitude target: {target}")
        n_sub = self.hold_wind(dt_s)
        if self._fly is None:  # the record's types are fixed: infer them once (jit.bind)
            self._fly = bind(fly_target, self._row, self._rows, n_sub, qd, thrust, ff)
        self._fly(self._row, self._rows, n_sub, qd, thrust, ff)
        return self.state()

    # -- extras for tests and other simulators ------------------------------------------------

    def step_motors(self, omega_cmd_radps: np.ndarray, dt_s: float) -> VehicleState:
        """Command rotor speeds directly (the attitude loop is bypassed) for ``dt_s``."""
        cmd = np.asarray(omega_cmd_radps, dtype=float).reshape(self.airframe.n_rotors)
        n_sub = self.hold_wind(dt_s)
        plant_step_motors(self._row, self._rows, n_sub, cmd)
        return self.state()

    @property
    def rotor_speeds_radps(self) -> np.ndarray:
        """(n,) current rotor speeds [rad/s]."""
        return self._rows.x[self._row, N_RIGID:N_RIGID + self.airframe.n_rotors].copy()

    @property
    def landed(self) -> bool:
        """True while the vehicle rests on the ground or on a deck."""
        return bool(self._rows.landed[self._row])

    @property
    def armed(self) -> bool:
        """False once the motors were cut (:meth:`cut_motors`)."""
        return bool(self._rows.armed[self._row])

    def cut_motors(self, cut: bool = True) -> None:
        """Cut the motors (the rotors spin down whatever is commanded), or run them again."""
        self._rows.armed[self._row] = 0.0 if cut else 1.0

    def set_deck(self, deck_row: np.ndarray | None) -> None:
        """The moving deck the contact knows, as it is now (``GroundVehicle.deck_row``), or
        None for none; a driver moving the deck writes it before each step."""
        row = self._rows.deck[self._row]
        if deck_row is None:
            row[:] = 0.0
            return
        d = np.asarray(deck_row, dtype=float).reshape(row.shape)
        if not np.all(np.isfinite(d)):
            raise ValueError(f"deck row: not finite ({d.tolist()})")
        row[:] = d

    def deck_touch(self) -> DeckTouch:
        """What it did on the deck so far."""
        return DeckTouch.from_row(self._rows.touch[self._row])

    def set_state(
        self, state: VehicleState, rotor_speeds_radps: np.ndarray | None = None
    ) -> None:
        """Overwrite the state (e.g. to start from a given motion); resets the attitude loop."""
        rows, i = self._rows, self._row
        x = rows.x[i]
        rows.t_s[i] = float(state.t_s)
        x[0:3] = state.position_m
        x[3:6] = state.velocity_mps
        q = np.array(state.attitude_wxyz, dtype=float).reshape(4)
        normalize_quat(q)
        x[6:10] = q
        x[10:13] = state.body_rates_radps
        if rotor_speeds_radps is not None:
            x[N_RIGID:N_RIGID + self.airframe.n_rotors] = rotor_speeds_radps
        rows.ctrl[i] = 0.0
        rows.landed[i] = 0.0
        settle(i, rows)

    def substeps(self, dt_s: float) -> int:
        """How many substeps ``dt_s`` is.

        Raises:
            ValueError: ``dt_s`` is not a whole number of substeps.
        """
        n = round(dt_s / self.substep_s)
        if n < 1 or abs(n * self.substep_s - dt_s) > 1e-9:
            raise ValueError(f"dt_s={dt_s} is not a whole number of substeps of {self.substep_s}")
        return n

    # -- internals --------------------------------------------------------------------------------

    def hold_wind(self, dt_s: float) -> int:
        """Advance the wind by ``dt_s`` and hold it in the row for the next step; returns the
        step's substeps. :meth:`step` calls it; a driver that steps the row with
        :func:`~uavmpc.plant.kernels.plant_step` itself calls it before."""
        n_sub = self.substeps(dt_s)
        wind = self.rows.wind_mps[self._row]
        if self.wind is not None:
            wind[:] = self.wind.update(dt_s)
        else:
            wind[:] = 0.0
        return n_sub
