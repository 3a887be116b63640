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

import math
from dataclasses import dataclass

import numpy as np

from uavmpc.reference import Reference
from uavmpc.tracker.model import CondensedModel, braking_plan
from uavmpc.tracker.params import DynamicLimits, TrackerConfig
from uavmpc.tracker.qp import FEASIBILITY_TOL, AxisQpSolver, QpResult, make_solver
from uavmpc.tracker.qpdata import QpData, build_qp

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
        self._z_offset_m = 0.0
        self._set_limits(self.config.limits)
        # Constant matrices of the per-tick QP build, laid out for row-vector products.
        lengths = self.config.step_lengths_s
        vref_of_ref = np.zeros((m, m))  # vref = r @ D: backward differences, first one repeated
        for k in range(1, m):
            vref_of_ref[k - 1, k], vref_of_ref[k, k] = -1.0 / lengths[k], 1.0 / lengths[k]
        vref_of_ref[:, 0] = vref_of_ref[:, 1]
        mdl = self.model
        self._qp_data = QpData(
            f_state_t=np.ascontiguousarray(mdl.f_state.T),
            f_ref_t=np.ascontiguousarray(mdl.f_ref.T),
            vref_of_ref=vref_of_ref,
            f_vref_t=np.ascontiguousarray(mdl.f_vref.T),
            f_uprev=mdl.f_uprev.copy(),
            cfree_t=np.ascontiguousarray(mdl.constraint_free.T),
            neg_hinv=-mdl.hessian_inv,
            c_t=np.ascontiguousarray(mdl.constraint_matrix.T),
            use_vref=self.config.q_velocity > 0.0,
        )
        self._free_t = mdl.free.T.copy()
        self._forced_t = mdl.forced.T.copy()
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
        self._v_lo_list, self._v_hi_list = v_lo.tolist(), v_hi.tolist()
        self._a_lo_list, self._a_hi_list = a_lo.tolist(), a_hi.tolist()
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

    @property
    def z_offset_m(self) -> float:
        return self._z_offset_m

    def set_z_offset(self, z_offset_m: float) -> None:
        """Fly the reference shifted up by ``z_offset_m`` (collision avoidance's reshaping)."""
        dz = float(z_offset_m)
        if not np.isfinite(dz) or abs(dz) > 1.0e4:
            raise ValueError(f"z_offset_m must be finite and within ±1e4 m, got {z_offset_m!r}")
        self._z_offset_m = dz

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

    def limit_excess(self, state: np.ndarray | None = None) -> float:
        """How far ``state`` (default: the current one) lies outside the limits in force.

        The box covers ``v``, ``a`` and ``w = v + τa`` of every axis; 0 inside. Right after a
        tightening this is positive while the virtual UAV brakes back inside
        (``TrackerOutput.braking``); otherwise it is 0 up to the solver tolerance.
        """
        return self._limit_excess(self._state if state is None else state)

    def _limit_excess(self, s: np.ndarray) -> float:
        """How far state s (4, 3) lies outside the box of ``v``, ``a`` and ``w = v + τa``."""
        tau = self.config.tau_s
        worst = 0.0
        # Plain floats: twelve comparisons are cheaper than a dozen numpy calls, every tick.
        for (_, v, a), vl, vh, al, ah in zip(s.tolist(), self._v_lo_list, self._v_hi_list,
                                            self._a_lo_list, self._a_hi_list, strict=True):
            w = v + tau * a
            worst = max(worst, v - vh, vl - v, a - ah, al - a, w - vh, vl - w)
        return worst

    # ------------------------------------------------------------------ the tick
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
        if self._z_offset_m:
            out[:, 2] += self._z_offset_m
        return out

    def step(self) -> TrackerOutput:
        """Advance the virtual UAV by one tick and return the command and the prediction."""
        return step_trackers([self])[0]

    def _begin(self) -> _Tick:
        """First half of a tick: the reference over the horizon and the bounds in force."""
        tau = self.config.tau_s
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
        h += 2.0 * math.pi * round((float(s0[3, 0]) - float(h[0])) / (2.0 * math.pi))

        # Positions relative to the current one keep the QP data well scaled (10 km steps).
        p0 = s0[:, 0].copy()
        rel = s0.copy()
        rel[:, 0] = 0.0
        r_rel = ref.T - p0[:, None]  # (4, m)

        lower, upper = self._lower_nominal, self._upper_nominal
        braking = self._limit_excess(s0) > INSIDE_TOL
        brake_u = None
        if braking:
            brake_u, brake_s = braking_plan(self.model, rel, self._a_lo, self._a_hi)
            env = np.hstack([brake_u, brake_s[:, :, 1],
                             brake_s[:, :1, 1] + tau * brake_s[:, :1, 2]])
            lower = np.minimum(lower, env)
            upper = np.maximum(upper, env)
        return _Tick(times, p0, rel, r_rel, lower, upper, braking, brake_u)

    def _finish(self, tick: _Tick, f: np.ndarray, lower_qp: np.ndarray, upper_qp: np.ndarray,
                u_all: np.ndarray, excess: np.ndarray) -> TrackerOutput:
        """Second half: solve the axes whose unconstrained optimum breaks a bound, advance."""
        m = self._m
        rel, brake_u = tick.rel, tick.brake_u
        need_qp = [i for i, e in enumerate(excess.tolist()) if not e <= 0.0]  # NaN too
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
        if need_qp:
            # Never trust a solver's word alone: every solution must be finite and within bounds.
            rows = np.concatenate([u_all, u_all @ self._qp_data.c_t], axis=1)
            excess = np.maximum(lower_qp - rows, rows - upper_qp).max(axis=1)
            fallback = sorted(set(fallback) | {
                int(i) for i in need_qp if not excess[i] <= FEASIBILITY_TOL})
        if fallback:
            self.fallback_count += 1
            if brake_u is None:
                brake_u, _ = braking_plan(self.model, rel, self._a_lo, self._a_hi)
            u_all[fallback] = brake_u[fallback]

        plan = (rel @ self._free_t + u_all @ self._forced_t).reshape(N_AXES, m, 3)
        plan[:, :, 0] += tick.p0[:, None]
        new_state = plan[:, 0, :].copy()
        self._state = new_state
        self._u_prev = u_all[:, 0].copy()
        self._t = float(tick.times[0])

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
            times_s=tick.times,
            position_m=xyz[:, :, 0].T.copy(),
            velocity_mps=xyz[:, :, 1].T.copy(),
            acceleration_mps2=xyz[:, :, 2].T.copy(),
            heading_rad=plan[3, :, 0].copy(),
            heading_rate_radps=plan[3, :, 1].copy(),
        )
        return TrackerOutput(command, prediction, tuple(fallback), tick.braking, len(need_qp),
                             iterations)


@dataclass(frozen=True, eq=False)
class _Tick:
    """What the first half of a tick hands to the second (per tracker, 4 axes)."""

    times: np.ndarray
    p0: np.ndarray
    rel: np.ndarray
    r_rel: np.ndarray
    lower: np.ndarray
    upper: np.ndarray
    braking: bool
    brake_u: np.ndarray | None


def step_trackers(trackers: list[MpcTracker]) -> list[TrackerOutput]:
    """Step several trackers at once: each does its own per-UAV work, and the QP data of all
    their axes is built in one set of array products (the per-tick cost that dominates a world
    of many UAVs). ``[t.step() for t in trackers]`` gives the same results, tick for tick;
    ``MpcTracker.step`` is this function with one tracker.
    """
    if not trackers:
        return []
    first = trackers[0]
    if any(t.config != first.config for t in trackers[1:]):  # different matrices: one by one
        return [step_trackers([t])[0] for t in trackers]
    ticks = [t._begin() for t in trackers]
    if len(trackers) == 1:
        t, k = first, ticks[0]
        built = build_qp(t._qp_data, k.rel, k.r_rel, t._u_prev, t._v_lo, t._v_hi, k.lower,
                         k.upper)
        return [t._finish(k, *built)]
    built = build_qp(
        first._qp_data,
        np.concatenate([k.rel for k in ticks]),
        np.concatenate([k.r_rel for k in ticks]),
        np.concatenate([t._u_prev for t in trackers]),
        np.concatenate([t._v_lo for t in trackers]),
        np.concatenate([t._v_hi for t in trackers]),
        np.concatenate([k.lower for k in ticks]),
        np.concatenate([k.upper for k in ticks]),
    )
    outs = []
    for i, (t, k) in enumerate(zip(trackers, ticks, strict=True)):
        rows = slice(N_AXES * i, N_AXES * (i + 1))
        outs.append(t._finish(k, *(b[rows] for b in built)))
    return outs
