"""The MPC tracker: a virtual UAV that flies any reference within its limits (SPEC §2).

Each tick (every ``first_step_s``, 10 ms by default) samples the reference over the horizon,
builds and solves the four axis QPs, and advances the virtual UAV by one step of the *same*
model; the new state is the command and the whole plan the stamped prediction. The law itself
is in :mod:`uavmpc.tracker.kernels`; this module holds its state and its Python faces:

- :class:`TrackerBatch`: N virtual UAVs of one configuration — their state record
  (:class:`~uavmpc.tracker.kernels.TrackerRows`), their references, their solvers — stepped
  together (:meth:`TrackerBatch.step`);
- :class:`MpcTracker`: one of them (a row of a batch, its own one-row batch by default), the
  API a mission or an onboard stack uses.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from uavmpc.jit import bind
from uavmpc.reference import Reference
from uavmpc.solvers import AxisQpSolver, BatchAxisSolver, ClarabelSolver, DaqpSolver, LdpData
from uavmpc.solvers.contract import QpResult
from uavmpc.tracker.kernels import (
    INSIDE_TOL,
    N_AXES,
    ReferenceTable,
    TrackerBundle,
    TrackerConsts,
    TrackerRows,
    advance_rows,
    limit_excess,
    make_bundle,
    plan,
    prepare_rows,
    scratch_floats,
    snapshot_row,
    tick_bundle,
    tick_rows,
)
from uavmpc.tracker.model import CondensedModel
from uavmpc.tracker.params import DynamicLimits, TrackerConfig


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
        fallback_axes: axes (0=x … 3=heading) whose QP failed and that brake instead.
        braking: the state was outside the limits in force (after a tightening) and is being
            brought back inside along the deceleration envelope.
        qp_solves: how many axes needed the QP solver (others used the unconstrained optimum).
        iterations: total solver iterations this tick.
        record: the tick's result as the kernels left it (:func:`snapshot_row`'s flat copy:
            state (4, 3), t_s, plan ``rel`` (4, 3), ``u`` (4, m), ``p0`` (4,)), from which
            :attr:`command` and :attr:`prediction` are formed on first use.
        consts: the tracker's constants (for the plan).
    """

    fallback_axes: tuple[int, ...]
    braking: bool
    qp_solves: int
    iterations: int
    record: np.ndarray = field(repr=False)
    consts: TrackerConsts = field(repr=False)

    @cached_property
    def command(self) -> TrackerCommand:
        """The new virtual-UAV state."""
        return command_of(self.record[:12].reshape(4, 3), float(self.record[12]))

    @cached_property
    def prediction(self) -> Prediction:
        """The plan whose first state is ``command``, stamped with absolute times."""
        r = self.record
        m = self.consts.horizon_s.shape[0]
        return prediction_of(r[13:25].reshape(4, 3), r[25:25 + 4 * m].reshape(4, m),
                             r[25 + 4 * m:29 + 4 * m], self.consts, float(r[12]))


def command_of(state: np.ndarray, t_s: float) -> TrackerCommand:
    """The controller's command from a virtual-UAV state (4, 3) at ``t_s``."""
    s = state
    return TrackerCommand(
        t_s=t_s, position_m=s[:3, 0].copy(), velocity_mps=s[:3, 1].copy(),
        acceleration_mps2=s[:3, 2].copy(),
        heading_rad=float((s[3, 0] + np.pi) % (2.0 * np.pi) - np.pi),
        heading_rate_radps=float(s[3, 1]), heading_accel_radps2=float(s[3, 2]))


def prediction_of(rel: np.ndarray, u: np.ndarray, p0: np.ndarray, consts: TrackerConsts,
                  t_s: float) -> Prediction:
    """The stamped plan of a tick (its record; see :class:`TrackerOutput`) that reached
    ``t_s``, the time of its first state."""
    out = np.empty((N_AXES, u.shape[1], 3))
    plan(np.ascontiguousarray(rel), np.ascontiguousarray(u), np.ascontiguousarray(p0),
         consts.free_t, consts.forced_t, out)
    return prediction_from(out, (t_s - consts.horizon_s[0]) + consts.horizon_s)


def prediction_from(out: np.ndarray, times_s: np.ndarray) -> Prediction:
    """The prediction of a plan ``out`` (4, m, 3) (:func:`~uavmpc.tracker.kernels.plan`)
    stamped ``times_s`` (m,) [s] (its own copies of both)."""
    xyz = out[:3]
    return Prediction(times_s=times_s.copy(), position_m=xyz[:, :, 0].T.copy(),
                      velocity_mps=xyz[:, :, 1].T.copy(),
                      acceleration_mps2=xyz[:, :, 2].T.copy(),
                      heading_rad=out[3, :, 0].copy(), heading_rate_radps=out[3, :, 1].copy())


def make_solver(name: str, model: CondensedModel, iter_limit: int = 1000) -> AxisQpSolver:
    """A Python solver for one axis by name (``"batchqp"`` here is the drop-in adapter of the
    compiled solver, one problem per call; the tracker itself runs it inline)."""
    if name == "daqp":
        return DaqpSolver(model, iter_limit)
    if name == "clarabel":
        return ClarabelSolver(model)
    if name == "batchqp":
        return BatchAxisSolver(model, iter_limit=iter_limit)
    raise ValueError(f"unknown QP solver {name!r} (known: batchqp, daqp, clarabel)")


def build_consts(config: TrackerConfig, model: CondensedModel) -> TrackerConsts:
    """The fixed data of the tracker's kernels for ``config``."""
    m = config.steps
    lengths = config.step_lengths_s
    vref_of_ref = np.zeros((m, m))  # vref = r @ D: backward differences, first one repeated
    for k in range(1, m):
        vref_of_ref[k - 1, k], vref_of_ref[k, k] = -1.0 / lengths[k], 1.0 / lengths[k]
    vref_of_ref[:, 0] = vref_of_ref[:, 1]
    c = np.ascontiguousarray
    ldp = LdpData.build(model.hessian, model.constraint_matrix)
    return TrackerConsts(
        horizon_s=c(config.horizon_times_s), step_len_s=c(lengths),
        t_grid_s=np.concatenate([[0.0], config.horizon_times_s]), tau_s=float(config.tau_s),
        f_state_t=c(model.f_state.T), f_ref_t=c(model.f_ref.T), vref_of_ref=vref_of_ref,
        f_vref_t=c(model.f_vref.T), f_uprev=model.f_uprev.copy(),
        cfree_t=c(model.constraint_free.T), c_t=c(model.constraint_matrix.T),
        neg_hinv=c(-model.hessian_inv), use_vref=bool(config.q_velocity > 0.0),
        free_t=c(model.free.T), forced_t=c(model.forced.T),
        **{f"ldp_{name}": value for name, value in ldp._asdict().items()},
        iter_limit=int(config.iter_limit),
    )


#: The fallback axes of a tick from their bits (axis a: bit a).
_AXES_OF_BITS = tuple(tuple(a for a in range(N_AXES) if bits >> a & 1)
                      for bits in range(1 << N_AXES))


def _row_indices(rows: object, n: int) -> np.ndarray:
    """``rows`` as the exact array type the bound kernels take, each index checked (the
    compiled code does not check bounds)."""
    idx = np.array(rows, dtype=np.int64).reshape(-1)
    if idx.size and (idx.min() < 0 or idx.max() >= n):
        raise IndexError(f"rows: indices must be in [0, {n}), got {rows!r}")
    return idx


def _table_type(table: ReferenceTable) -> tuple[object, ...]:
    return tuple((a.dtype, a.ndim, a.flags.c_contiguous, a.flags.writeable) for a in table)


class TrackerBatch:
    """N virtual UAVs of one configuration, stepped together by the tracker's kernels.

    Owns their state (:attr:`rows`, a :class:`~uavmpc.tracker.kernels.TrackerRows`), their
    references (packed into :meth:`table` for the kernels) and, for rows flown with a Python
    solver (DAQP, Clarabel, a test's), those solvers. Rows without Python solvers solve their
    QPs inside the compiled tick with the dual active-set solver (config ``solver =
    "batchqp"``, the default). A driver that ticks many UAVs in one compiled call (the
    simulated world) passes :attr:`rows`, :meth:`table` and :attr:`consts` to
    :func:`~uavmpc.tracker.kernels.tick_row`.

    Args:
        config: the set-up shared by all rows (default: packaged data/tracker.toml).
        n: number of rows.
    """

    def __init__(self, config: TrackerConfig | None = None, n: int = 1) -> None:
        if n < 1:
            raise ValueError(f"n: a batch needs at least one row, got {n}")
        self.config = config if config is not None else TrackerConfig.from_toml()
        self.model = CondensedModel.build(self.config)
        self.consts = build_consts(self.config, self.model)
        self.n = int(n)
        self.rows = TrackerRows.empty(self.n, self.config.steps)
        #: Per row: its Python axis solvers, or None (the compiled solver, inline).
        self.solvers: list[list[AxisQpSolver] | None] = [None] * self.n
        self._python_status: list[list[str]] = [["optimal"] * N_AXES for _ in range(self.n)]
        self.references: list[Reference | None] = [None] * self.n
        self.previous: list[Reference | None] = [None] * self.n
        self._table: ReferenceTable | None = None
        self._table_type: tuple[object, ...] | None = None
        self._kernels: tuple[Callable[..., None], ...] | None = None
        self._snapshot: Callable[..., tuple[bool, int, int, int]] | None = None
        self._alone: tuple[ReferenceTable, TrackerBundle] | None = None
        #: Work arrays of the kernels, allocated once (one row is ticked at a time): the
        #: buffers :func:`~uavmpc.tracker.kernels.scratch_views` cuts them from.
        self.scratch = (np.empty(scratch_floats(self.config.steps)),
                        np.zeros(2 * self.config.steps + 1, dtype=np.int8))
        self._inline = np.arange(self.n, dtype=np.int64)
        self._python = np.zeros(0, dtype=np.int64)
        if self.config.solver != "batchqp":
            for i in range(self.n):
                self.set_solvers(i, [make_solver(self.config.solver, self.model,
                                                 self.config.iter_limit)
                                     for _ in range(N_AXES)])
        for i in range(self.n):
            self.set_limits(i, self.config.limits)

    # ------------------------------------------------------------------ per-row inputs
    def set_solvers(self, row: int, solvers: list[AxisQpSolver] | None) -> None:
        """Solve row ``row``'s QPs with these Python solvers (one per axis), or inline (None)."""
        if solvers is not None and len(solvers) != N_AXES:
            raise ValueError(f"solvers: need one per axis ({N_AXES}), got {len(solvers)}")
        self.solvers[row] = list(solvers) if solvers is not None else None
        python = [i for i, s in enumerate(self.solvers) if s is not None]
        self._python = np.array(python, dtype=np.int64)
        self._inline = np.array([i for i in range(self.n) if self.solvers[i] is None],
                                dtype=np.int64)

    @property
    def all_inline(self) -> bool:
        """Every row solves its QPs inside the compiled tick (no Python solver set)."""
        return self._python.size == 0

    def set_limits(self, row: int, limits: DynamicLimits) -> None:
        """Row ``row`` flies within ``limits`` from its next tick on."""
        v_lo, v_hi = limits.velocity_bounds()
        a_lo, a_hi = limits.acceleration_bounds()
        r = self.rows
        r.v_lo[row], r.v_hi[row], r.a_lo[row], r.a_hi[row] = v_lo, v_hi, a_lo, a_hi

    def set_reference(self, row: int, reference: Reference) -> None:
        """Row ``row`` flies ``reference`` from its start on; before that, the current one."""
        r = self.rows
        current = self.references[row]
        pending = reference.start_s > r.t_s[row] and current is not None
        self.previous[row] = current if pending else None
        r.has_previous[row] = pending
        self.references[row] = reference
        self._table = None

    def table(self) -> ReferenceTable:
        """The references packed for the kernels (rebuilt after a change)."""
        if self._table is None:
            table = self._pack()
            if self._table_type != _table_type(table):
                self._kernels = None
                self._table_type = _table_type(table)
            self._table = table
        return self._table

    def _pack(self) -> ReferenceTable:
        n = self.n
        start = np.zeros((n, 2), dtype=np.int64)
        length = np.zeros((n, 2), dtype=np.int64)
        period = np.zeros((n, 2))
        loop = np.zeros((n, 2), dtype=np.bool_)
        knots, values = [], []
        offset = 0
        for i in range(n):
            slots = (self.references[i],
                     self.previous[i] if self.rows.has_previous[i] else None)
            for j, ref in enumerate(slots):
                if ref is None:
                    continue
                kn, va = ref.knots_s, ref.values
                knots.append(kn)
                values.append(va)
                start[i, j], length[i, j] = offset, kn.shape[0]
                period[i, j], loop[i, j] = ref.uniform_period_s, ref.loop
                offset += kn.shape[0]
        all_knots = np.concatenate(knots) if knots else np.zeros(1)
        all_values = np.ascontiguousarray(np.vstack(values)) if values else np.zeros((1, 4))
        return ReferenceTable(all_knots, all_values, start, length, period, loop)

    # ------------------------------------------------------------------ the tick
    def step(self, rows: np.ndarray | None = None) -> None:
        """One tick of the given rows (indices; default all)."""
        if rows is not None:
            rows = _row_indices(rows, self.n)
        table = self._table if self._table is not None else self.table()
        kernels = self._kernels
        if kernels is None:
            kernels = self._kernels = self._bind(table)
        tick, prepare, advance = kernels
        sc = self.scratch
        if rows is not None and not self._python.size:  # the common case, kept short
            tick(rows, self.rows, table, self.consts, *sc)
            return
        if rows is None:
            inline, python = self._inline, self._python
        elif self._python.size == 0:
            inline, python = rows, self._python
        else:
            has = np.array([self.solvers[i] is not None for i in rows], dtype=bool)
            inline, python = rows[~has], rows[has]
        if inline.size:
            tick(inline, self.rows, table, self.consts, *sc)
        if python.size:
            prepare(python, self.rows, table, self.consts, *sc)
            for i in python.tolist():
                self._solve_python(i)
            advance(python, self.rows, self.consts, *sc)

    def _bind(self, table: ReferenceTable) -> tuple[Callable[..., None], ...]:
        # Bound once per table: the record types are fixed, numba's per-call inference is not
        # free (≈ 6 µs for these records, a third of a tick).
        idx, sc = self._inline, self.scratch
        return (bind(tick_rows, idx, self.rows, table, self.consts, *sc),
                bind(prepare_rows, idx, self.rows, table, self.consts, *sc),
                bind(advance_rows, idx, self.rows, self.consts, *sc))

    def _solve_python(self, i: int) -> None:
        r = self.rows
        solvers = self.solvers[i]
        assert solvers is not None
        iterations = 0
        for axis in np.flatnonzero(r.need[i]).tolist():
            try:
                result = solvers[axis].solve(r.f[i, axis], r.lower[i, axis], r.upper[i, axis])
            except Exception as exc:  # a solver crash must not stop the virtual UAV
                result = QpResult(None, f"solver raised {type(exc).__name__}: {exc}", 0)
            iterations += result.iterations
            self._python_status[i][axis] = result.status
            if result.inputs is not None:
                r.u_plan[i, axis] = result.inputs
                r.solved[i, axis] = 1
        r.iterations[i] = iterations

    # ------------------------------------------------------------------ outputs
    def prediction(self, row: int) -> Prediction:
        """Row ``row``'s plan of its last tick, stamped (what it broadcasts)."""
        r = self.rows
        return prediction_of(r.rel[row], r.u_plan[row], r.p0[row], self.consts,
                             float(r.t_s[row]))

    def command(self, row: int) -> TrackerCommand:
        """Row ``row``'s current virtual-UAV state as the controller's command."""
        return command_of(self.rows.state[row], float(self.rows.t_s[row]))

    def output(self, row: int) -> TrackerOutput:
        """Everything row ``row``'s last tick produced (a snapshot: later ticks leave it)."""
        r = self.rows
        record = np.empty(29 + 4 * self.config.steps)
        if self._snapshot is None:
            self._snapshot = bind(snapshot_row, row, r, record)
        braking, solves, iterations, bits = self._snapshot(row, r, record)
        return TrackerOutput(_AXES_OF_BITS[bits], braking, solves, iterations, record,
                             self.consts)

    def step_output(self, row: int) -> TrackerOutput:
        """:meth:`step` of one row, then its :meth:`output` (one compiled call when the row
        solves inline: a tracker ticking alone)."""
        if self.solvers[row] is not None:
            self.step(np.array([row], dtype=np.int64))
            return self.output(row)
        table = self._table if self._table is not None else self.table()
        record = np.empty(29 + 4 * self.config.steps)
        if self._alone is None or self._alone[0] is not table:
            self._alone = (table, make_bundle(self.rows, table, self.consts, *self.scratch))
        braking, solves, iterations, bits = tick_bundle(row, self._alone[1], record)
        return TrackerOutput(_AXES_OF_BITS[bits], braking, solves, iterations, record,
                             self.consts)

    def solver_status(self, row: int) -> list[str]:
        """The status word of each axis' last solve on row ``row`` ("optimal" or why not)."""
        if self.solvers[row] is not None:
            return list(self._python_status[row])
        r = self.rows
        return ["batchqp failed" if r.need[row, a] and not r.solved[row, a] else "optimal"
                for a in range(N_AXES)]

    def limit_excess(self, row: int, state: np.ndarray | None = None) -> float:
        """How far ``state`` (default: row ``row``'s) lies outside that row's limits."""
        r = self.rows
        s = r.state[row] if state is None else np.ascontiguousarray(state, dtype=float)
        return float(limit_excess(s, r.v_lo[row], r.v_hi[row], r.a_lo[row], r.a_hi[row],
                                  self.consts.tau_s))


class MpcTracker:
    """Model-predictive trajectory tracker steering a virtual UAV (4 axes: x, y, z, heading).

    A view on one row of a :class:`TrackerBatch`: by default its own one-row batch; a driver
    that ticks many UAVs together passes ``batch`` and ``row``.

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
        batch: TrackerBatch | None = None,
        row: int = 0,
    ) -> None:
        if batch is None:
            batch = TrackerBatch(config, 1)
        elif config is not None and config != batch.config:
            raise ValueError("config: differs from the batch's (a batch has one set-up)")
        if not 0 <= row < batch.n:
            raise ValueError(f"row: must be in [0, {batch.n}), got {row}")
        self.batch = batch
        self.row = int(row)
        self._idx = np.array([row], dtype=np.int64)
        self.config = batch.config
        self.model = batch.model
        if solvers is not None:
            if len(solvers) != N_AXES:
                raise ValueError(f"solvers: need one per axis ({N_AXES}), got {len(solvers)}")
            batch.set_solvers(row, solvers)
        t0 = float(t0_s)
        if not np.isfinite(t0):
            raise InvalidStateError(f"t0_s must be finite, got {t0_s!r}")
        pos = np.asarray(position_m, dtype=float)
        if pos.shape != (3,) or not np.all(np.isfinite(pos)):
            raise InvalidStateError(f"position_m must be 3 finite numbers, got {position_m!r}")
        heading = float(heading_rad)
        if not np.isfinite(heading):
            raise InvalidStateError(f"heading_rad must be finite, got {heading_rad!r}")
        r = batch.rows
        r.state[row] = 0.0
        r.state[row, :3, 0] = pos
        r.state[row, 3, 0] = heading
        r.t_s[row] = t0
        r.u_prev[row] = 0.0
        r.z_offset_m[row] = 0.0
        r.hold_z_m[row] = np.nan
        self._limits = self.config.limits
        batch.set_limits(row, self._limits)

    # ------------------------------------------------------------------ inputs
    @property
    def time_s(self) -> float:
        """Absolute time of the current virtual state."""
        return float(self.batch.rows.t_s[self.row])

    @property
    def state(self) -> np.ndarray:
        """(4, 3) copy of the virtual state: rows x, y, z, heading; columns [p, v, a]."""
        return self.batch.rows.state[self.row].copy()

    @property
    def limits(self) -> DynamicLimits:
        return self._limits

    @property
    def reference(self) -> Reference | None:
        return self.batch.references[self.row]

    @property
    def fallback_count(self) -> int:
        """Ticks on which at least one axis fell back to braking (solver failure)."""
        return int(self.batch.rows.fallback_count[self.row])

    @property
    def last_solver_status(self) -> list[str]:
        """The last status word of each axis' solver ("optimal" or why it failed)."""
        return self.batch.solver_status(self.row)

    def set_limits(self, limits: DynamicLimits) -> None:
        """Change the dynamic limits, effective at the next tick (may be mid-flight)."""
        if not isinstance(limits, DynamicLimits):
            raise TypeError(f"limits must be a DynamicLimits, got {type(limits).__name__}")
        self._limits = limits
        self.batch.set_limits(self.row, limits)

    def set_reference(self, reference: Reference) -> None:
        """Fly ``reference`` from its start time on; before that, the current one still applies.

        Validation happens when the :class:`Reference` is built, so a bad trajectory never gets
        here and the tracker keeps flying its current plan.
        """
        if not isinstance(reference, Reference):
            raise TypeError(
                f"reference must be a uavmpc.Reference, got {type(reference).__name__}"
            )
        self.batch.set_reference(self.row, reference)

    @property
    def z_offset_m(self) -> float:
        return float(self.batch.rows.z_offset_m[self.row])

    def set_z_offset(self, z_offset_m: float) -> None:
        """Fly the reference shifted up by ``z_offset_m`` (collision avoidance's reshaping)."""
        dz = float(z_offset_m)
        if not np.isfinite(dz) or abs(dz) > 1.0e4:
            raise ValueError(f"z_offset_m must be finite and within ±1e4 m, got {z_offset_m!r}")
        self.batch.rows.z_offset_m[self.row] = dz

    @property
    def hold_z_m(self) -> float | None:
        """The height a hold keeps (before the offset) [m], or None."""
        z = float(self.batch.rows.hold_z_m[self.row])
        return None if np.isnan(z) else z

    def hold_height(self, z_m: float | None) -> None:
        """Fly at ``z_m`` [m] (before the offset) in place of the reference's heights, or
        (None) the reference's own again: a hold short stops vertically as well."""
        if z_m is None:
            self.batch.rows.hold_z_m[self.row] = np.nan
            return
        z = float(z_m)
        if not np.isfinite(z) or abs(z) > 1.0e4:
            raise ValueError(f"hold z_m must be finite and within ±1e4 m, got {z_m!r}")
        self.batch.rows.hold_z_m[self.row] = z

    def goto(self, x: float, y: float, z: float, heading: float = 0.0) -> None:
        """Fly to a point and hold it, starting now."""
        self.set_reference(Reference.goto(x, y, z, heading, start_s=self.time_s))

    def set_state(self, state: np.ndarray, t_s: float | None = None) -> None:
        """Replace the virtual state ((4, 3): rows x, y, z, heading; columns [p, v, a]), and
        its time when ``t_s`` is given.

        The state must lie inside the limits in force, including ``|v + τ a|`` (see
        :mod:`uavmpc.tracker.model`), so that the QP stays feasible.
        """
        if t_s is not None and not np.isfinite(float(t_s)):
            raise InvalidStateError(f"t_s must be finite, got {t_s!r}")
        s = np.asarray(state, dtype=float)
        if s.shape != (N_AXES, 3):
            raise InvalidStateError(f"state must have shape (4, 3), got {s.shape}")
        if not np.all(np.isfinite(s)):
            raise InvalidStateError("state contains NaN or inf")
        excess = self.limit_excess(s)
        if excess > INSIDE_TOL:
            raise InvalidStateError(
                f"state lies {excess:.3g} outside the limits in force "
                "(|v|, |a| and |v + τ·a| must respect the velocity/acceleration limits)"
            )
        self.batch.rows.state[self.row] = s
        if t_s is not None:
            self.batch.rows.t_s[self.row] = float(t_s)

    def limit_excess(self, state: np.ndarray | None = None) -> float:
        """How far ``state`` (default: the current one) lies outside the limits in force.

        The box covers ``v``, ``a`` and ``w = v + τa`` of every axis; 0 inside. Right after a
        tightening this is positive while the virtual UAV brakes back inside
        (``TrackerOutput.braking``); otherwise it is 0 up to the solver tolerance.
        """
        return self.batch.limit_excess(self.row, state)

    # ------------------------------------------------------------------ the tick
    def step(self) -> TrackerOutput:
        """Advance the virtual UAV by one tick and return the command and the prediction."""
        return self.batch.step_output(self.row)

    def prediction(self) -> Prediction:
        """The plan of the last tick (as in its output), stamped."""
        return self.batch.prediction(self.row)

    def command(self) -> TrackerCommand:
        """The current virtual-UAV state as the controller's command (as in the last output)."""
        return self.batch.command(self.row)
