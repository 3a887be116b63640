"""The MPC tracker: a virtual UAV that flies any reference within its limits (SPEC §2).

Each :meth:`MpcTracker.step` (every ``first_step_s``, 10 ms by default):

1. samples the reference at the horizon's times (holding, looping or switching references),
2. unwraps the heading reference the short way round from the current heading,
3. builds the four axis QPs (only the linear term and the bounds change),
4. solves them (unconstrained shortcut when no bound is active, else the QP solver),
5. advances the virtual UAV by one step of the *same* model, and returns the new state as the
   command plus the whole plan as the stamped prediction.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from uavmpc.reference import Reference
from uavmpc.tracker.model import CondensedModel, braking_plan
from uavmpc.tracker.params import DynamicLimits, TrackerConfig
from uavmpc.tracker.qp import FEASIBILITY_TOL, AxisQpSolver, QpResult, make_solver

N_AXES = 4
#: State components outside the limit box by less than this count as inside (solver round-off).
INSIDE_TOL = 1e-9
#: Headings are kept continuous; re-centred by whole turns past this magnitude.
HEADING_RECENTER_RAD = 64.0 * np.pi


class InvalidStateError(ValueError):
    """A virtual-UAV state that cannot be taken (wrong shape, not finite, outside the limits)."""


@dataclass(frozen=True, eq=False)
class TrackerCommand:
    """The virtual UAV's state: the command for the controller (ENU world frame, SI).

    Attributes:
        t_s: absolute time of this state.
        position_m, velocity_mps, acceleration_mps2: (3,) each.
        heading_rad: in [-π, π).
        heading_rate_radps, heading_accel_radps2: heading derivatives.
    """

    t_s: float
    position_m: np.ndarray
    velocity_mps: np.ndarray
    acceleration_mps2: np.ndarray
    heading_rad: float
    heading_rate_radps: float
    heading_accel_radps2: float


@dataclass(frozen=True, eq=False)
class Prediction:
    """The virtual UAV's plan over the horizon, stamped with absolute times.

    Attributes:
        times_s: (m,) absolute times; the first equals the command's ``t_s``.
        position_m, velocity_mps, acceleration_mps2: (m, 3).
        heading_rad: (m,) continuous (not wrapped) heading.
        heading_rate_radps: (m,).
    """

    times_s: np.ndarray
    position_m: np.ndarray
    velocity_mps: np.ndarray
    acceleration_mps2: np.ndarray
    heading_rad: np.ndarray
    heading_rate_radps: np.ndarray


@dataclass(frozen=True, eq=False)
class TrackerOutput:
    """Everything one tick produces.

    Attributes:
        command: the new virtual-UAV state.
        prediction: the plan whose first state is ``command``.
        fallback_axes: axes (0=x … 3=heading) whose QP failed and that brake instead.
        braking: the state was outside the limits in force (after a tightening) and is being
            brought back inside along the deceleration envelope.
        qp_solves: how many axes needed the QP solver (others used the unconstrained optimum).
        iterations: total solver iterations this tick.
    """

    command: TrackerCommand
    prediction: Prediction
    fallback_axes: tuple[int, ...]
    braking: bool
    qp_solves: int
    iterations: int


class MpcTracker:
    """Model-predictive trajectory tracker steering a virtual UAV (4 axes: x, y, z, heading).

    Example:
        >>> tracker = MpcTracker(position_m=(0.0, 0.0, 2.0))
        >>> tracker.set_reference(Reference.goto(50.0, 0.0, 2.0))
        >>> out = tracker.step()      # call every config.first_step_s seconds
        >>> out.command.velocity_mps  # doctest: +SKIP
    """

    def __init__(
        self,
        config: TrackerConfig | None = None,
        *,
        position_m: tuple[float, float, float] | np.ndarray = (0.0, 0.0, 0.0),
        heading_rad: float = 0.0,
        t0_s: float = 0.0,
        solvers: list[AxisQpSolver] | None = None,
    ) -> None:
        self.config = config if config is not None else TrackerConfig.from_toml()
        self.model = CondensedModel.build(self.config)
        m = self.config.steps
        if solvers is None:
            solvers = [
                make_solver(self.config.solver, self.model, self.config.iter_limit)
                for _ in range(N_AXES)
            ]
        if len(solvers) != N_AXES:
            raise ValueError(f"solvers: need one per axis ({N_AXES}), got {len(solvers)}")
        self._solvers = solvers
        t0 = float(t0_s)
        if not np.isfinite(t0):
            raise InvalidStateError(f"t0_s must be finite, got {t0_s!r}")
        self._t = t0
        self._dt = self.config.first_step_s
        self._horizon = self.config.horizon_times_s
        self._state = np.zeros((N_AXES, 3))
        self._u_prev = np.zeros(N_AXES)
        pos = np.asarray(position_m, dtype=float)
        if pos.shape != (3,) or not np.all(np.isfinite(pos)):
            raise InvalidStateError(f"position_m must be 3 finite numbers, got {position_m!r}")
        self._state[:3, 0] = pos
        self._state[3, 0] = float(heading_rad)
        if not np.isfinite(self._state[3, 0]):
            raise InvalidStateError(f"heading_rad must be finite, got {heading_rad!r}")
        self._reference: Reference | None = None
        self._previous_reference: Reference | None = None
        self._set_limits(self.config.limits)
        # Precomputed views used every tick.
        self._neg_hinv = -self.model.hessian_inv
        self._c_t = self.model.constraint_matrix.T.copy()
        self._cfree_t = self.model.constraint_free.T.copy()
        self._fstate_t = self.model.f_state.T.copy()
        self._fref_t = self.model.f_ref.T.copy()
        self._fvref_t = self.model.f_vref.T.copy()
        self._use_vref = self.config.q_velocity > 0.0
        # vref = r @ D: backward differences of the sampled reference (first one repeated).
        lengths = self.config.step_lengths_s
        diff = np.zeros((m, m))
        for k in range(1, m):
            diff[k - 1, k], diff[k, k] = -1.0 / lengths[k], 1.0 / lengths[k]
        diff[:, 0] = diff[:, 1]
        self._vref_of_ref = diff
        self._free_t = self.model.free.T.copy()
        self._forced_t = self.model.forced.T.copy()
        self._a0_t = self.model.a_steps[0].T.copy()
        self._b0 = self.model.b_steps[0].copy()
        self._m = m
        #: Ticks on which at least one axis fell back to braking (solver failure).
        self.fallback_count = 0
        #: The last status word of each axis' solver ("optimal" or why it failed).
        self.last_solver_status = ["optimal"] * N_AXES

    # ------------------------------------------------------------------ inputs
    @property
    def time_s(self) -> float:
        """Absolute time of the current virtual state."""
        return self._t

    @property
    def state(self) -> np.ndarray:
        """(4, 3) copy of the virtual state: rows x, y, z, heading; columns [p, v, a]."""
        return self._state.copy()

    @property
    def limits(self) -> DynamicLimits:
        return self._limits

    @property
    def reference(self) -> Reference | None:
        return self._reference

    def set_limits(self, limits: DynamicLimits) -> None:
        """Change the dynamic limits, effective at the next tick (may be mid-flight)."""
        if not isinstance(limits, DynamicLimits):
            raise TypeError(f"limits must be a DynamicLimits, got {type(limits).__name__}")
        self._set_limits(limits)

    def _set_limits(self, limits: DynamicLimits) -> None:
        m = self.config.steps
        v_lo, v_hi = limits.velocity_bounds()
        a_lo, a_hi = limits.acceleration_bounds()
        self._limits = limits
        self._v_lo, self._v_hi, self._a_lo, self._a_hi = v_lo, v_hi, a_lo, a_hi
        self._vaw_lo = np.stack([v_lo, a_lo, v_lo], axis=1)
        self._vaw_hi = np.stack([v_hi, a_hi, v_hi], axis=1)
        # Row layout of the bounds: [u_1..u_m | v_1..v_m | w_1] per axis (see tracker.model).
        self._lower_nominal = np.hstack([np.repeat(a_lo[:, None], m, 1),
                                         np.repeat(v_lo[:, None], m + 1, 1)])
        self._upper_nominal = np.hstack([np.repeat(a_hi[:, None], m, 1),
                                         np.repeat(v_hi[:, None], m + 1, 1)])

    def set_reference(self, reference: Reference) -> None:
        """Fly ``reference`` from its start time on; before that, the current one still applies.

        Validation happens when the :class:`Reference` is built, so a bad trajectory never gets
        here and the tracker keeps flying its current plan.
        """
        if not isinstance(reference, Reference):
            raise TypeError(
                f"reference must be a uavmpc.Reference, got {type(reference).__name__}"
            )
        if reference.start_s > self._t and self._reference is not None:
            self._previous_reference = self._reference
        else:
            self._previous_reference = None
        self._reference = reference

    def goto(self, x: float, y: float, z: float, heading: float = 0.0) -> None:
        """Fly to a point and hold it, starting now."""
        self.set_reference(Reference.goto(x, y, z, heading, start_s=self._t))

    def set_state(self, state: np.ndarray) -> None:
        """Replace the virtual state ((4, 3): rows x, y, z, heading; columns [p, v, a]).

        The state must lie inside the limits in force, including ``|v + τ a|`` (see
        :mod:`uavmpc.tracker.model`), so that the QP stays feasible.
        """
        s = np.asarray(state, dtype=float)
        if s.shape != (N_AXES, 3):
            raise InvalidStateError(f"state must have shape (4, 3), got {s.shape}")
        if not np.all(np.isfinite(s)):
            raise InvalidStateError("state contains NaN or inf")
        excess = self._limit_excess(s)
        if excess > INSIDE_TOL:
            raise InvalidStateError(
                f"state lies {excess:.3g} outside the limits in force "
                "(|v|, |a| and |v + τ·a| must respect the velocity/acceleration limits)"
            )
        self._state = s.copy()

    def _limit_excess(self, s: np.ndarray) -> float:
        """How far state s (4, 3) lies outside the box of ``v``, ``a`` and ``w = v + τa``."""
        vaw = np.empty((N_AXES, 3))
        vaw[:, :2] = s[:, 1:]
        vaw[:, 2] = s[:, 1] + self.config.tau_s * s[:, 2]
        return max(float(np.maximum(vaw - self._vaw_hi, self._vaw_lo - vaw).max()), 0.0)

    # ------------------------------------------------------------------ the tick
    def _bound_excess(self, u: np.ndarray, lower: np.ndarray, upper: np.ndarray) -> np.ndarray:
        """(4,) largest bound violation of each axis' inputs u (4, m); NaN if u is not finite."""
        rows = np.concatenate([u, u @ self._c_t], axis=1)
        return np.maximum(lower - rows, rows - upper).max(axis=1)

    def _sample_reference(self, times: np.ndarray) -> np.ndarray:
        """(m, 4) reference at absolute ``times``; holds the current position if none."""
        ref, prev = self._reference, self._previous_reference
        if ref is None:
            return np.broadcast_to(self._state[:, 0], (times.shape[0], N_AXES)).copy()
        out = ref.sample(times)
        if prev is not None:
            if self._t >= ref.start_s:
                self._previous_reference = None
            else:
                early = times < ref.start_s
                out[early] = prev.sample(times[early])
        return out

    def step(self) -> TrackerOutput:
        """Advance the virtual UAV by one tick and return the command and the prediction."""
        m, tau = self._m, self.config.tau_s
        s0 = self._state
        if abs(s0[3, 0]) > HEADING_RECENTER_RAD:
            s0[3, 0] -= 2.0 * np.pi * np.round(s0[3, 0] / (2.0 * np.pi))
        times = self._t + self._horizon
        ref = self._sample_reference(times)
        # Heading: the short way round from the current heading. A Reference stores its headings
        # unwrapped, so one whole-turn shift suffices unless two references meet in the horizon.
        h = ref[:, 3]
        if self._previous_reference is not None:
            h[1:] = h[0] + np.cumsum((np.diff(h) + np.pi) % (2.0 * np.pi) - np.pi)
        h += 2.0 * np.pi * np.round((s0[3, 0] - h[0]) / (2.0 * np.pi))

        # Positions relative to the current one keep the QP data well scaled (10 km steps).
        p0 = s0[:, 0].copy()
        rel = s0.copy()
        rel[:, 0] = 0.0
        r_rel = ref.T - p0[:, None]  # (4, m)
        f = rel @ self._fstate_t + r_rel @ self._fref_t + self._u_prev[:, None] * self.model.f_uprev
        if self._use_vref:
            # The reference's own velocity, clipped: a jump in it is not a speed to match.
            vref = r_rel @ self._vref_of_ref
            np.minimum(vref, self._v_hi[:, None], out=vref)
            np.maximum(vref, self._v_lo[:, None], out=vref)
            f += vref @ self._fvref_t
        rows_free = rel @ self._cfree_t  # (4, m + 1)

        lower, upper = self._lower_nominal, self._upper_nominal
        braking = self._limit_excess(s0) > INSIDE_TOL
        brake_u = None
        if braking:
            brake_u, brake_s = braking_plan(self.model, rel, self._a_lo, self._a_hi)
            env = np.hstack([brake_u, brake_s[:, :, 1],
                             brake_s[:, :1, 1] + tau * brake_s[:, :1, 2]])
            lower = np.minimum(lower, env)
            upper = np.maximum(upper, env)
        lower_qp = lower.copy()
        upper_qp = upper.copy()
        lower_qp[:, m:] -= rows_free
        upper_qp[:, m:] -= rows_free

        # Unconstrained optimum first: when it respects every bound it is the QP's solution.
        u_all = f @ self._neg_hinv
        need_qp = np.flatnonzero(self._bound_excess(u_all, lower_qp, upper_qp) > 0.0)
        fallback: list[int] = []
        iterations = 0
        for axis in need_qp:
            try:
                result = self._solvers[axis].solve(f[axis], lower_qp[axis], upper_qp[axis])
            except Exception as exc:  # a solver crash must not stop the virtual UAV
                result = QpResult(None, f"solver raised {type(exc).__name__}: {exc}", 0)
            iterations += result.iterations
            self.last_solver_status[axis] = result.status
            if result.inputs is not None:
                u_all[axis] = result.inputs
            else:
                fallback.append(int(axis))
        if need_qp.size:
            # Never trust a solver's word alone: every solution must be finite and within bounds.
            excess = self._bound_excess(u_all, lower_qp, upper_qp)
            fallback = sorted(set(fallback) | {
                int(i) for i in need_qp if not excess[i] <= FEASIBILITY_TOL})
        if fallback:
            self.fallback_count += 1
            if brake_u is None:
                brake_u, _ = braking_plan(self.model, rel, self._a_lo, self._a_hi)
            u_all[fallback] = brake_u[fallback]

        plan = (rel @ self._free_t + u_all @ self._forced_t).reshape(N_AXES, m, 3)
        plan[:, :, 0] += p0[:, None]
        new_state = plan[:, 0, :].copy()
        self._state = new_state
        self._u_prev = u_all[:, 0].copy()
        self._t = float(times[0])

        hd = new_state[3]
        command = TrackerCommand(
            t_s=self._t,
            position_m=new_state[:3, 0].copy(),
            velocity_mps=new_state[:3, 1].copy(),
            acceleration_mps2=new_state[:3, 2].copy(),
            heading_rad=float((hd[0] + np.pi) % (2.0 * np.pi) - np.pi),
            heading_rate_radps=float(hd[1]),
            heading_accel_radps2=float(hd[2]),
        )
        xyz = plan[:3]
        prediction = Prediction(
            times_s=times,
            position_m=xyz[:, :, 0].T.copy(),
            velocity_mps=xyz[:, :, 1].T.copy(),
            acceleration_mps2=xyz[:, :, 2].T.copy(),
            heading_rad=plan[3, :, 0].copy(),
            heading_rate_radps=plan[3, :, 1].copy(),
        )
        return TrackerOutput(command, prediction, tuple(fallback), braking, int(need_qp.size),
                             iterations)
