"""Geometric tracking on SE(3) (Lee, Leok, McClamroch 2010) with integral terms (SPEC §3).

    e_p = p − p_d,  e_v = v − v_d
    F_d = m (a_d + g e₃) − K_p e_p − K_v e_v − R K_ib ∫ Rᵀ e_p dt − K_iw ∫ e_p dt
    b₃,d = F_d / ‖F_d‖ (tilt limited),  b₁,d from the desired heading,
    R_d = [b₂,d × b₃,d, b₂,d, b₃,d],  T_d = F_d · R e₃ (saturated)

The gains are diagonal (per axis); the body-frame integral's gain acts in the body frame
(before R). Anti-windup: each integral is clipped to its limit, and both stop integrating while
the thrust is saturated or the tilt limited (conditional integration), so they cannot grow while
they have no effect (e.g. during a large position step). The tilt limit keeps the force's
vertical part (height has priority over horizontal acceleration, and the force never points
downwards) and scales its horizontal part. The heading rate ψ̇ is fed forward as the world-z
rate seen in the desired body frame.
Runs at 100 Hz; outputs an :class:`~uavmpc.plant.interface.AttitudeTarget` (quaternion + thrust).

The law exists once, as the compiled :func:`se3_law`; :func:`se3_row` applies it to one row of a
:class:`ControlRows` record (the controllers' state: integrals and flags), and
:class:`Se3Controller` is a view on such a row. ``tests/oracles.py`` holds a plain-numpy
rendering that the tests compare it with.
"""

from __future__ import annotations

import math
from typing import Any, NamedTuple, Protocol

import numpy as np

from uavmpc.jit import kernel
from uavmpc.plant.airframe import G_MPS2, Airframe, Se3Gains
from uavmpc.plant.interface import AttitudeTarget, VehicleState
from uavmpc.plant.kernels import quat_rotation

__all__ = ["ControlRows", "PositionCommand", "Se3Controller", "pack_se3_gains", "se3_law",
           "se3_row"]


class PositionCommand(Protocol):
    """What the controller needs of a command; :class:`uavmpc.tracker.tracker.TrackerCommand`
    has exactly these fields (ENU, SI)."""

    # Read-only: a frozen dataclass (TrackerCommand) provides them too.
    @property
    def t_s(self) -> float: ...
    @property
    def position_m(self) -> np.ndarray: ...
    @property
    def velocity_mps(self) -> np.ndarray: ...
    @property
    def acceleration_mps2(self) -> np.ndarray: ...
    @property
    def heading_rad(self) -> float: ...
    @property
    def heading_rate_radps(self) -> float: ...


def pack_se3_gains(g: Se3Gains, mass_kg: float) -> np.ndarray:
    """(7, 3) table for :func:`se3_law`: rows K_p, K_v, K_iw, K_ib, world and body integral
    limits, [mass, g, tan(max_tilt)]."""
    return np.ascontiguousarray(np.vstack(
        [g.kp_n_per_m, g.kv_n_per_mps, g.ki_world_n_per_ms, g.ki_body_n_per_ms,
         g.integral_limit_world_ms, g.integral_limit_body_ms,
         [mass_kg, G_MPS2, math.tan(g.max_tilt_rad)]]
    ).astype(float))


class ControlRows(NamedTuple):
    """N SE(3) controllers, row i = one vehicle's (numba takes the record as an argument).

    State:
        integral_world_ms: (N, 3) ∫ e_p dt in the world frame [m s].
        integral_body_ms: (N, 3) ∫ Rᵀ e_p dt in the body frame [m s].
        saturated: (N,) bool, the last thrust was clipped to the range.
        tilt_limited: (N,) bool, the last force direction was limited to the max tilt.

    Constants (written once per row, :meth:`configure`):
        gains: (N, 7, 3) :func:`pack_se3_gains`' table.
        thrust_min_n, thrust_max_n: (N,) collective-thrust range [N].
    """

    integral_world_ms: np.ndarray
    integral_body_ms: np.ndarray
    saturated: np.ndarray
    tilt_limited: np.ndarray
    gains: np.ndarray
    thrust_min_n: np.ndarray
    thrust_max_n: np.ndarray

    @classmethod
    def empty(cls, n: int) -> ControlRows:
        """A record of ``n`` rows, all zero (a row is usable once :meth:`configure`'d)."""
        if n < 1:
            raise ValueError(f"need n ≥ 1 rows, got {n}")
        return cls(
            integral_world_ms=np.zeros((n, 3)), integral_body_ms=np.zeros((n, 3)),
            saturated=np.zeros(n, dtype=np.bool_), tilt_limited=np.zeros(n, dtype=np.bool_),
            gains=np.zeros((n, 7, 3)), thrust_min_n=np.zeros(n), thrust_max_n=np.zeros(n),
        )

    def configure(self, i: int, airframe: Airframe) -> None:
        """Write ``airframe``'s SE(3) gains and thrust range into row ``i`` and clear its
        state."""
        g = airframe.se3
        self.gains[i] = pack_se3_gains(g, airframe.mass_kg)
        self.thrust_min_n[i] = g.thrust_min_fraction * airframe.max_thrust_n
        self.thrust_max_n[i] = g.thrust_max_fraction * airframe.max_thrust_n
        self.reset(i)

    def reset(self, i: int) -> None:
        """Clear row ``i``'s integrals and flags."""
        self.integral_world_ms[i] = 0.0
        self.integral_body_ms[i] = 0.0
        self.saturated[i] = False
        self.tilt_limited[i] = False


@kernel(error_model="numpy")
def se3_law(
    p: np.ndarray,
    v: np.ndarray,
    q: np.ndarray,
    p_d: np.ndarray,
    v_d: np.ndarray,
    a_d: np.ndarray,
    psi: float,
    psi_rate: float,
    dt: float,
    gains: np.ndarray,
    thrust_min: float,
    thrust_max: float,
    iw: np.ndarray,
    ib: np.ndarray,
    q_out: np.ndarray,
    ff_out: np.ndarray,
) -> tuple[float, bool, bool]:
    """The SE(3) law (module docstring) for one vehicle.

    ``p``, ``v``, ``q``: the state's position [m], velocity [m/s] and attitude (w, x, y, z);
    ``p_d``, ``v_d``, ``a_d``, ``psi`` [rad], ``psi_rate`` [rad/s]: the command; ``dt`` [s] the
    integrators' step. ``gains``: :func:`pack_se3_gains`' (7, 3) table; ``thrust_min``,
    ``thrust_max`` [N] the thrust range. ``iw``, ``ib`` (3,): the world- and body-frame integrals
    [m s], updated in place after the output (it uses the integrals up to the previous step),
    and only when neither saturated nor tilt limited. Writes the desired quaternion into
    ``q_out`` (4,) and the body-rate feedforward into ``ff_out`` (3,); returns (clipped thrust,
    saturated, tilt limited).
    ``error_model="numpy"``: a degenerate (zero) force gives NaN as numpy does, not an exception.
    """
    r00, r01, r02, r10, r11, r12, r20, r21, r22 = quat_rotation(q[0], q[1], q[2], q[3])
    ep0 = p[0] - p_d[0]
    ep1 = p[1] - p_d[1]
    ep2 = p[2] - p_d[2]
    m = gains[6, 0]
    g = gains[6, 1]
    # R (K_ib ∫_body)
    b0 = gains[3, 0] * ib[0]
    b1 = gains[3, 1] * ib[1]
    b2 = gains[3, 2] * ib[2]
    f0 = (m * a_d[0] - gains[0, 0] * ep0 - gains[1, 0] * (v[0] - v_d[0])
          - (r00 * b0 + r01 * b1 + r02 * b2) - gains[2, 0] * iw[0])
    f1 = (m * a_d[1] - gains[0, 1] * ep1 - gains[1, 1] * (v[1] - v_d[1])
          - (r10 * b0 + r11 * b1 + r12 * b2) - gains[2, 1] * iw[1])
    f2 = (m * (a_d[2] + g) - gains[0, 2] * ep2 - gains[1, 2] * (v[2] - v_d[2])
          - (r20 * b0 + r21 * b1 + r22 * b2) - gains[2, 2] * iw[2])
    # Tilt limit: keep the vertical part (at least thrust_min), scale the horizontal one.
    fz = max(f2, thrust_min)
    h = math.hypot(f0, f1)
    h_max = fz * gains[6, 2]
    tilt_limited = h > h_max or f2 < thrust_min
    if h > h_max:
        f0 = f0 * h_max / h
        f1 = f1 * h_max / h
    f2 = fz
    nf = math.sqrt(f0 * f0 + f1 * f1 + f2 * f2)
    z0 = f0 / nf
    z1 = f1 / nf
    z2 = f2 / nf
    c = math.cos(psi)
    s = math.sin(psi)
    # b2 = b3 × b1c (b1c = [cos ψ, sin ψ, 0]), normalized; b1 = b2 × b3
    y0 = z1 * 0.0 - z2 * s
    y1 = z2 * c - z0 * 0.0
    y2 = z0 * s - z1 * c
    ny = math.sqrt(y0 * y0 + y1 * y1 + y2 * y2)
    y0 /= ny
    y1 /= ny
    y2 /= ny
    x0 = y1 * z2 - y2 * z1
    x1 = y2 * z0 - y0 * z2
    x2 = y0 * z1 - y1 * z0
    thrust = f0 * r02 + f1 * r12 + f2 * r22
    clipped = min(max(thrust, thrust_min), thrust_max)
    saturated = clipped != thrust
    if not (saturated or tilt_limited):
        e = (ep0, ep1, ep2)
        for i in range(3):
            lim = gains[4, i]
            iw[i] = min(max(iw[i] + e[i] * dt, -lim), lim)
        rte = (r00 * ep0 + r10 * ep1 + r20 * ep2,
               r01 * ep0 + r11 * ep1 + r21 * ep2,
               r02 * ep0 + r12 * ep1 + r22 * ep2)
        for i in range(3):
            lim = gains[5, i]
            ib[i] = min(max(ib[i] + rte[i] * dt, -lim), lim)
    ff_out[0] = psi_rate * x2
    ff_out[1] = psi_rate * y2
    ff_out[2] = psi_rate * z2
    # Quaternion of R_d = [b1, b2, b3] (columns), Shepperd's method as rot_to_quat.
    tr = x0 + y1 + z2
    if tr > max(x0, y1, z2):
        t = 2.0 * math.sqrt(1.0 + tr)
        qw, qx, qy, qz = 0.25 * t, (y2 - z1) / t, (z0 - x2) / t, (x1 - y0) / t
    elif x0 >= y1 and x0 >= z2:
        t = 2.0 * math.sqrt(1.0 + x0 - y1 - z2)
        qw, qx, qy, qz = (y2 - z1) / t, 0.25 * t, (y0 + x1) / t, (z0 + x2) / t
    elif y1 >= z2:
        t = 2.0 * math.sqrt(1.0 + y1 - x0 - z2)
        qw, qx, qy, qz = (z0 - x2) / t, (y0 + x1) / t, 0.25 * t, (z1 + y2) / t
    else:
        t = 2.0 * math.sqrt(1.0 + z2 - x0 - y1)
        qw, qx, qy, qz = (x1 - y0) / t, (z0 + x2) / t, (z1 + y2) / t, 0.25 * t
    nq = math.sqrt(qw * qw + qx * qx + qy * qy + qz * qz)
    if qw < 0.0:
        nq = -nq
    q_out[0] = qw / nq
    q_out[1] = qx / nq
    q_out[2] = qy / nq
    q_out[3] = qz / nq
    return clipped, saturated, tilt_limited


@kernel
def se3_row(
    i: int,
    rows: Any,
    p: np.ndarray,
    v: np.ndarray,
    q: np.ndarray,
    cmd_p: np.ndarray,
    cmd_v: np.ndarray,
    cmd_a: np.ndarray,
    psi: float,
    psi_rate: float,
    dt: float,
    q_out: np.ndarray,
    ff_out: np.ndarray,
) -> float:
    """:func:`se3_law` with row ``i`` of ``rows`` (a :class:`ControlRows`): its gains, thrust
    range and integrals, which it updates with the flags. Returns the thrust [N]; writes the
    target quaternion into ``q_out`` (4,) and the body-rate feedforward into ``ff_out`` (3,)."""
    thrust, saturated, limited = se3_law(
        p, v, q, cmd_p, cmd_v, cmd_a, psi, psi_rate, dt, rows.gains[i], rows.thrust_min_n[i],
        rows.thrust_max_n[i], rows.integral_world_ms[i], rows.integral_body_ms[i], q_out, ff_out,
    )
    rows.saturated[i] = saturated
    rows.tilt_limited[i] = limited
    return thrust


class Se3Controller:
    """SE(3) controller for one airframe (gains from its ``[se3]`` section): a view on one row
    of a :class:`ControlRows` record.

    Args:
        airframe: mass, thrust range and gains.
        period_s: control period, used as the integrators' step when ``update`` gets no dt.
        rows: the record to be a view on (None: a 1-row record of its own). Its row ``row`` is
            overwritten with this controller's constants and a cleared state.
        row: which row of ``rows``.
    """

    def __init__(
        self,
        airframe: Airframe,
        *,
        period_s: float = 0.01,
        rows: ControlRows | None = None,
        row: int = 0,
    ) -> None:
        if not period_s > 0.0:
            raise ValueError(f"period_s must be > 0, got {period_s}")
        if rows is None:
            rows, row = ControlRows.empty(1), 0
        elif not 0 <= row < rows.saturated.shape[0]:
            raise ValueError(f"row {row} is not in a record of {rows.saturated.shape[0]} rows")
        self.airframe = airframe
        self.gains = airframe.se3
        self.period_s = float(period_s)
        self._rows = rows
        self._row = int(row)
        rows.configure(self._row, airframe)

    @property
    def rows(self) -> ControlRows:
        """The record holding this controller's state (shared when a driver batches)."""
        return self._rows

    @property
    def row(self) -> int:
        """This controller's row in :attr:`rows`."""
        return self._row

    @property
    def integral_world_ms(self) -> np.ndarray:
        """(3,) world-frame integral ∫ e_p dt [m s] (a copy)."""
        return self._rows.integral_world_ms[self._row].copy()

    @property
    def integral_body_ms(self) -> np.ndarray:
        """(3,) body-frame integral ∫ Rᵀ e_p dt [m s] (a copy)."""
        return self._rows.integral_body_ms[self._row].copy()

    @property
    def saturated(self) -> bool:
        """True when the last thrust was clipped to the airframe's range."""
        return bool(self._rows.saturated[self._row])

    @property
    def tilt_limited(self) -> bool:
        """True when the last force direction was limited to ``max_tilt_rad``."""
        return bool(self._rows.tilt_limited[self._row])

    @property
    def thrust_min_n(self) -> float:
        """Lowest collective thrust commanded [N]."""
        return float(self._rows.thrust_min_n[self._row])

    @property
    def thrust_max_n(self) -> float:
        """Highest collective thrust commanded [N]."""
        return float(self._rows.thrust_max_n[self._row])

    def reset(self) -> None:
        """Clear the integrators and flags (e.g. on take-off)."""
        self._rows.reset(self._row)

    def update(
        self, command: PositionCommand, state: VehicleState, dt_s: float | None = None
    ) -> AttitudeTarget:
        """One control step: the attitude target for ``state`` to follow ``command``."""
        # Fresh output arrays each call: the target must not alias another one.
        q = np.empty(4)
        ff = np.empty(3)
        thrust = se3_row(
            self._row, self._rows, state.position_m, state.velocity_mps, state.attitude_wxyz,
            np.asarray(command.position_m, dtype=float),
            np.asarray(command.velocity_mps, dtype=float),
            np.asarray(command.acceleration_mps2, dtype=float),
            float(command.heading_rad), float(command.heading_rate_radps),
            self.period_s if dt_s is None else float(dt_s), q, ff,
        )
        return AttitudeTarget(attitude_wxyz=q, thrust_n=thrust, body_rates_ff_radps=ff)
