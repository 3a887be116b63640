"""The avoidance round: who is due, their plans, their encounters, their decisions — and each
UAV's :class:`Steering`, what a decision sets on its tracker.

A round (:func:`avoidance_round`) runs over the rows of one batch of onboard stacks
(:class:`RoundBatch`; :class:`~uavmpc.onboard.OnboardBatch` is one): every row due hands its
plan of the last tick (:func:`avoidance_plans`), one finder call finds every row's encounters,
and the rows' strategies decide — in one compiled call
(:func:`~uavmpc.avoidance.decide.decide_rows`) when they are height-offset strategies bound to
the batch's :class:`~uavmpc.avoidance.strategy.StrategyTable`, else each by its own
``decide``. A stack ticking alone runs the same round over its one row.

The one decision path: a :class:`~uavmpc.avoidance.HeightOffsetStrategy` whose ``decide`` is
the class's own is decided by the compiled law; a subclass that overrides ``decide`` keeps a
row of its own and is decided by its override (:class:`Steering` binds only the former).
"""

from __future__ import annotations

import dataclasses
import functools
import math
from collections.abc import Mapping, Sequence
from typing import Protocol

import numba
import numpy as np

from uavmpc.avoidance.decide import (
    CALM_KIND,
    N_FLAGS,
    N_MASKS,
    NEW_KIND,
    EncounterRows,
    decide_rows,
)
from uavmpc.avoidance.encounters import EncounterFinder, Encounters, FoundRows
from uavmpc.avoidance.strategy import (
    CALM,
    HOLD_SPEED_MPS,
    AvoidanceDecision,
    EncounterStrategy,
    HeightOffsetStrategy,
    ResolutionStrategy,
    StrategyTable,
)
from uavmpc.comms.inbox import InboxTable
from uavmpc.jit import bound, kernel, thread_count
from uavmpc.reference import sample_reference
from uavmpc.tracker import DynamicLimits, MpcTracker, TrackerBatch
from uavmpc.tracker.kernels import ReferenceTable, TrackerConsts, TrackerRows, plan

#: How often the avoidance re-plans (the tracker ticks at 100 Hz, predictions arrive at 2 Hz).
AVOIDANCE_PERIOD_S = 0.1
#: Tolerance of the schedules (avoidance, broadcast) against round-off in the tick times.
SCHEDULE_TOL_S = 1e-9
#: A mission whose height changes by at most _LEVEL_DZ_M over _LEVEL_DT_S keeps its height
#: (a hold then keeps the mission's height, :meth:`Steering._rest_height_m`) [m, s].
_LEVEL_DZ_M, _LEVEL_DT_S = 1e-3, 0.1
#: The limits key (horizontal scale, climb speed, climb acceleration, holding) of the nominal
#: limits (:meth:`Steering.apply`).
_NOMINAL_KEY: tuple[float, float | None, float | None, bool] = (1.0, None, None, False)
#: A vertical speed this far over a limit outpaces it [m/s] (the tracker's own round-off).
_SPEED_TOL_MPS = 0.05
#: The mission's point is "over" the virtual UAV (or at its height) within this distance [m].
_OVER_M = 1.0


class RoundSchedule(Protocol):
    """When each row's avoidance is next due and whether it plans at all, (N,) each."""

    @property
    def next_avoidance_s(self) -> np.ndarray: ...

    @property
    def planning(self) -> np.ndarray: ...


class RoundSenders(Protocol):
    """What each row's broadcasts carry: here its priority (N,) int64."""

    @property
    def priority(self) -> np.ndarray: ...


class RoundBatch(Protocol):
    """The rows a round runs over (:class:`~uavmpc.onboard.OnboardBatch`): their virtual
    UAVs, schedules and priorities; ``holding`` the rows whose decision holds short;
    ``resting`` (N,) bool the rows come to rest and not decided since; ``radius_m`` (N,) and
    ``position_sigma_m`` (N, 2) [m] what widens each row's encounters; ``strategies`` the
    rows of their height-offset strategies."""

    tracker: TrackerBatch
    holding: set[int]
    resting: np.ndarray
    radius_m: np.ndarray
    position_sigma_m: np.ndarray
    strategies: StrategyTable | None

    @property
    def schedule(self) -> RoundSchedule: ...

    @property
    def senders(self) -> RoundSenders: ...

    def strategies_for(self, table: InboxTable) -> StrategyTable | None: ...


@kernel(allocates=True)
def avoidance_plans(idx: np.ndarray, trk: TrackerRows, refs: ReferenceTable,
                    consts: TrackerConsts, times_out: np.ndarray, pos_out: np.ndarray,
                    climbed_out: np.ndarray) -> None:
    """What rows ``idx`` (R,) hand their avoidance: each one's plan of its last tick (times
    ``times_out`` (R, m), positions ``pos_out`` (R, m, 3)) without the part of its z offset
    the virtual UAV has already climbed at each point (plan minus mission reference, clipped
    to [0, offset]). Subtracting the whole offset would put the early, still-climbing points
    below the mission and make the strategy climb again and again for a conflict the climb in
    progress already resolves. ``climbed_out`` (R,): the part of the offset climbed at the
    plan's first point (where a climb raised again starts from) [m]."""
    h = consts.horizon_s
    m = h.shape[0]
    out = np.empty((4, m, 3))
    nominal = np.empty((m, 4))
    for j in range(idx.shape[0]):
        i = idx[j]
        # The very plan the UAV broadcasts (one law: the positions are not summed again here).
        plan(trk.rel[i], trk.u_plan[i], trk.p0[i], consts.free_t, consts.forced_t, out)
        t0 = trk.t_s[i] - h[0]
        for k in range(m):
            times_out[j, k] = t0 + h[k]
            for ax in range(3):
                pos_out[j, k, ax] = out[ax, k, 0]
        offset = trk.z_offset_m[i]
        climbed_out[j] = offset
        if offset == 0.0:
            continue
        n_ref = refs.length[i, 0]
        if n_ref == 0:
            for k in range(m):
                pos_out[j, k, 2] -= offset
            continue
        a0 = refs.start[i, 0]
        sample_reference(refs.knots_s[a0:a0 + n_ref], refs.values[a0:a0 + n_ref],
                         refs.period_s[i, 0], refs.loop[i, 0], times_out[j], nominal)
        for k in range(m):
            up = min(max(pos_out[j, k, 2] - nominal[k, 2], 0.0), offset)
            if k == 0:
                climbed_out[j] = up
            pos_out[j, k, 2] -= up


@kernel(parallel=True)
def avoidance_plans_threads(idx: np.ndarray, trk: TrackerRows, refs: ReferenceTable,
                            consts: TrackerConsts, times_out: np.ndarray, pos_out: np.ndarray,
                            climbed_out: np.ndarray, blocks: int) -> None:
    """:func:`avoidance_plans` with the rows in ``blocks`` contiguous blocks, one per thread
    (each row's outputs are its own: the same for any number)."""
    r_count = idx.shape[0]
    nb = max(1, min(r_count, blocks))
    for b in numba.prange(nb):
        lo, hi = b * r_count // nb, (b + 1) * r_count // nb
        avoidance_plans(idx[lo:hi], trk, refs, consts, times_out[lo:hi], pos_out[lo:hi],
                        climbed_out[lo:hi])


@functools.lru_cache(maxsize=256)
def avoidance_limits(nominal: DynamicLimits, horizontal_scale: float,
                     climb_speed_mps: float | None, climb_accel_mps2: float | None,
                     holding: bool = False) -> DynamicLimits:
    """Nominal limits, horizontally tightened and with the climb lifted while avoiding; while
    holding short, the horizontal speed limit :data:`~uavmpc.avoidance.strategy.
    HOLD_SPEED_MPS` at the nominal acceleration (the tracker brakes as hard as it may).

    Remembered for the process (a frozen value of frozen inputs): a world's UAVs share a
    few nominal limits and switch between a few decisions' limits, and building one
    validates eight numbers (~13 µs). With a memo per stack, 454 of the 579 changes of
    limits in 4 s of the 300-UAV world built one."""
    limits = nominal.scaled(horizontal=horizontal_scale)
    if holding:
        limits = dataclasses.replace(limits, horizontal_speed_mps=HOLD_SPEED_MPS,
                                     horizontal_accel_mps2=nominal.horizontal_accel_mps2)
    if climb_speed_mps is None and climb_accel_mps2 is None:
        return limits
    # A climb lifted is braked as hard as it may start: a multirotor stops a climb by easing
    # its thrust. Found in the vertical stack swap (2 × 5): a climb at 5 m/s told to stop
    # where it was went on for 5 m at the nominal 1 m/s² downwards, into the UAV above.
    climb_accel = max(limits.ascend_accel_mps2, climb_accel_mps2 or 0.0)
    return DynamicLimits(
        limits.horizontal_speed_mps, limits.horizontal_accel_mps2,
        max(limits.ascend_speed_mps, climb_speed_mps or 0.0), climb_accel,
        limits.descend_speed_mps, max(limits.descend_accel_mps2, climb_accel),
        limits.heading_rate_radps, limits.heading_accel_radps2,
    )


class Steering:
    """One UAV's avoidance on its row of ``batch``: its strategy, the decision it steers by
    (:attr:`decision`), and what a decision sets on its ``tracker`` (z offset, limits, the
    height a hold keeps). ``avoiding`` (N,) bool: the batch's row-wise "avoiding now" counter
    input, written at each decision.

    A height-offset strategy deciding by the class's own ``decide`` is bound to the batch's
    strategy rows (the compiled round decides it); any other encounter strategy decides by
    its own code; a message strategy (``update`` only) is handed the inbox by its stack."""

    def __init__(self, strategy: ResolutionStrategy | None, tracker: MpcTracker,
                 batch: RoundBatch, row: int, table: InboxTable, uav_id: str, priority: int,
                 avoiding: np.ndarray) -> None:
        self.strategy = strategy
        self.tracker = tracker
        self.uav_id = uav_id
        self.priority = priority
        #: The decision it steers by (None before the first and after :meth:`release`).
        self.decision: AvoidanceDecision | None = None
        #: The limits it flies without a decision.
        self.nominal_limits = tracker.limits
        self._batch = batch
        self._row = row
        self._avoiding = avoiding
        self._table = table
        self._limits_key = _NOMINAL_KEY
        #: The acceleration of the last climb lifted [m/s²] (0: none yet), and whether a climb
        #: faster than the nominal limits is being braked at it (:meth:`apply`).
        self._lifted_accel_mps2 = 0.0
        self._braking = False
        self._decider = strategy if isinstance(strategy, EncounterStrategy) else None
        self._height: HeightOffsetStrategy | None = None
        if (isinstance(strategy, HeightOffsetStrategy)
                and type(strategy).decide is HeightOffsetStrategy.decide):
            home = batch.strategies_for(table)
            if home is not None:
                strategy.bind(home, row)
                self._height = strategy
        #: The finder of its own encounters (a stack ticking alone runs its rounds with it),
        #: or None without an encounter strategy.
        self.own_finder = self.finder()

    # ------------------------------------------------------------------ a round's calls
    def finder(self, use_index: bool | None = True) -> EncounterFinder | None:
        """A finder of its strategy's encounters among its inbox table's messages (for every
        row of the table when all its stacks fly the same parameters), or None without an
        encounter strategy."""
        if self._decider is None:
            return None
        return self._decider.finder(self._table, use_index=use_index)

    def overrides(self) -> dict[int, float]:
        """Its strategy's per-pair radii by its inbox table's columns (none without one)."""
        return {} if self._decider is None else self._decider.overrides(self._table)

    def due(self) -> bool:
        """Its avoidance runs at this tick (its period has passed on the tracker's clock)."""
        return bool(self.tracker.time_s
                    >= self._batch.schedule.next_avoidance_s[self._row] - SCHEDULE_TOL_S)

    def decide(self, plan_s: float, times_s: np.ndarray, found: Encounters,
               climbed_m: float, positions_m: np.ndarray | None = None,
               probes: list[Encounters] | None = None) -> None:
        """Steer by its encounter strategy's decision on ``found``, the encounters of its plan
        of times ``times_s`` (m,) and positions ``positions_m`` (m, 3) at ``plan_s``;
        ``probes``: while it holds short, the encounters of its :meth:`hold_probes`."""
        assert self._decider is not None, "decide: the strategy takes encounters"
        self._batch.resting[self._row] = False
        self.apply(self._decider.decide(plan_s, self.uav_id, self.priority, times_s, found,
                                        climbed_m=climbed_m, positions=positions_m,
                                        probes=probes))

    def rest(self, plan_s: float) -> bool:
        """Its round at ``plan_s`` when nobody is near or silent: if its strategy has nothing
        left to do (:meth:`~uavmpc.avoidance.EncounterStrategy.rest`), steered by the calm
        decision, marked resting, and True; else False, nothing done (:meth:`decide` must
        run)."""
        assert self._decider is not None, "rest: the strategy takes encounters"
        if not self._decider.rest(plan_s):
            return False
        self._batch.resting[self._row] = True
        self.apply(CALM)  # a climb still braking keeps it from resting
        return True

    def hold_probes(self, plan_s: float, times_s: np.ndarray, here_m: np.ndarray
                    ) -> np.ndarray | None:
        """While its strategy holds short: (D, m, 3) the plans it would fly going on now or
        later (:meth:`~uavmpc.avoidance.HeightOffsetStrategy.hold_probes`); else None."""
        return (None if self._decider is None
                else self._decider.hold_probes(plan_s, times_s, here_m))

    def steer_by_kind(self, kind: int, z_offset_m: float = 0.0, first_s: float = math.nan,
                      flags: np.ndarray | None = None, masks: np.ndarray | None = None,
                      ids: Sequence[str] = (), silent: tuple[str, ...] = ()) -> None:
        """Steer by what :func:`~uavmpc.avoidance.decide.decide_rows` said of its row
        (``kind``; for a new decision its fields, see
        :meth:`~uavmpc.avoidance.HeightOffsetStrategy.decision_of`)."""
        assert self._height is not None
        self.apply(self._height.decision_of(kind, z_offset_m, first_s, flags, masks, ids,
                                            silent))

    def limit_offset(self, ceiling_m: float) -> None:
        """Its avoidance climbs no higher than ``ceiling_m`` [m] over its mission (a
        geofence's ceiling); without an encounter strategy, nothing to limit."""
        if self._decider is not None:
            self._decider.limit_offset(ceiling_m)

    # ------------------------------------------------------------------ its tracker
    def apply(self, decision: AvoidanceDecision) -> None:
        """Steer by an avoidance decision: its z offset and limits from the next tick on."""
        if decision is self.decision and not self._braking:
            return  # steering by it already (only this and release() change what it sets)
        self.decision = decision
        tracker, row, batch = self.tracker, self._row, self._batch
        if decision.z_offset_m != tracker.z_offset_m:
            tracker.set_z_offset(decision.z_offset_m)
        if decision.holding:
            if row not in batch.holding:
                tracker.hold_height(self._rest_height_m())
            batch.holding.add(row)
        else:
            batch.holding.discard(row)
            tracker.hold_height(None)
        key = (decision.horizontal_scale, decision.climb_speed_mps, decision.climb_accel_mps2,
               decision.holding)
        if decision.climb_accel_mps2 is not None:
            self._lifted_accel_mps2 = decision.climb_accel_mps2
        # A climb lifted and then dropped is braked as hard as it started until the virtual
        # UAV is back within the nominal speeds. Found by the falsifier (walks, single-band
        # GNSS): a conflict over, the limits fell back to 1 m/s² while it climbed at 5 m/s,
        # and it went on 12 m past its offset, 2.9 m over the ceiling by its truth.
        self._braking = (decision.climb_speed_mps is None and self._lifted_accel_mps2 > 0.0
                         and self._outpaces_nominal())
        if self._braking:
            key = (key[0], None, self._lifted_accel_mps2, key[3])
            self._batch.resting[row] = False  # its next round looks again
        if key != self._limits_key:
            self._limits_key = key
            tracker.set_limits(avoidance_limits(self.nominal_limits, *key))
        self._avoiding[row] = bool(decision.avoiding)

    def release(self) -> None:
        """No decision any more (the vehicle is not ours to steer): nominal limits, no hold,
        not resting; the z offset is its stack's to reset."""
        self.decision = None
        self._batch.resting[self._row] = False
        self._batch.holding.discard(self._row)
        self.tracker.hold_height(None)
        self._avoiding[self._row] = False
        self._braking = False
        if self._limits_key != _NOMINAL_KEY:
            self._limits_key = _NOMINAL_KEY
            self.tracker.set_limits(self.nominal_limits)

    def _outpaces_nominal(self) -> bool:
        """The virtual UAV climbs or descends faster than its nominal limits allow."""
        limits = self.nominal_limits
        vz = float(self.tracker.state[2, 1])
        return (vz > limits.ascend_speed_mps + _SPEED_TOL_MPS
                or vz < -limits.descend_speed_mps - _SPEED_TOL_MPS)

    def _rest_height_m(self) -> float:
        """The height a hold keeps, in the mission's frame (before the offset). While the
        mission climbs or descends, where the virtual UAV's vertical motion comes to rest
        braking at its limits (a hold at the height of now would overshoot and come back);
        while the mission keeps its height (a go-to, a level path) right over the virtual
        UAV, the mission's height: a UAV held during its take-off still climbs to where its
        mission is (found on real PX4: held at its height mid take-off, a UAV flew its whole
        mission 2.5 m above the ground), or at the mission's height already (the part of
        the offset climbed aside). Not when the mission's point is elsewhere, at another
        height: found in the vertical stack swap (2 × 5), a UAV held long enough for its
        mission's point to reach its goal 22 m higher climbed straight up to it, into the
        UAV above."""
        tracker = self.tracker
        ref = tracker.reference
        state = tracker.state
        z, v = float(state[2, 0]), float(state[2, 1])
        if ref is not None:
            t = tracker.time_s
            at = ref.sample(np.array([t, t + _LEVEL_DT_S]))
            z_ref = float(at[0, 2])
            climbed = min(max(z - z_ref, 0.0), tracker.z_offset_m)
            over = math.hypot(float(at[0, 0] - state[0, 0]), float(at[0, 1] - state[1, 0]))
            if abs(float(at[1, 2]) - z_ref) <= _LEVEL_DZ_M and (
                    over <= _OVER_M or abs(z - climbed - z_ref) <= _OVER_M):
                return z_ref
        lim = tracker.limits
        brake = lim.descend_accel_mps2 if v > 0.0 else lim.ascend_accel_mps2
        return z + v * abs(v) / (2.0 * brake) - tracker.z_offset_m


def avoidance_round(batch: RoundBatch, steering: Sequence[Steering] | Mapping[int, Steering],
                    finder: EncounterFinder, rows: np.ndarray | None = None,
                    overrides: Sequence[dict[int, float]] | None = None) -> np.ndarray:
    """The avoidance of the rows of ``batch`` due now (among ``rows`` (R,), default all),
    each on its tracker's clock: their plans (:func:`avoidance_plans`), their encounters in
    one call of ``finder`` (one finder for the rows of one inbox table), and each one's own
    decision. ``steering[i]`` is row i's :class:`Steering`; ``overrides``: per row, its
    per-pair radii (default: asked of each). Returns the rows whose strategies decided (D,):
    every other row due is at rest (steered by :data:`~uavmpc.avoidance.strategy.CALM`)."""
    sched = batch.schedule
    trk = batch.tracker
    t = trk.rows.t_s
    if rows is None:
        due = np.flatnonzero(sched.planning & (t >= sched.next_avoidance_s - SCHEDULE_TOL_S))
    else:
        due = rows[sched.planning[rows] & (t[rows] >= sched.next_avoidance_s[rows]
                                           - SCHEDULE_TOL_S)]
    if not due.size:
        return due
    plan_s = t[due]
    sched.next_avoidance_s[due] = plan_s + AVOIDANCE_PERIOD_S
    m = trk.config.steps
    times = np.empty((due.size, m))
    own = np.empty((due.size, m, 3))
    climbed = np.empty(due.size)
    threads = thread_count()
    if threads > 1 and due.size > 1:
        bound(avoidance_plans_threads)(due, trk.rows, trk.table(), trk.consts, times, own,
                                       climbed, threads)
    else:
        bound(avoidance_plans)(due, trk.rows, trk.table(), trk.consts, times, own, climbed)
    which = due.tolist()
    # A UAV holding short also has its probes found (docs/safety.md, A6): the same receiver
    # row again, once per probe, after the plans of this round.
    held = []
    if batch.holding:
        for j, i in enumerate(which):
            if i in batch.holding:
                p = steering[i].hold_probes(float(plan_s[j]), times[j], own[j, 0])
                if p is not None:
                    held.append((j, p))
    # Per-pair radii are rare (a formation's): none to hand over when no row has any.
    ov: list[dict[int, float]] | None = (
        [steering[i].overrides() for i in which] if overrides is None
        else [overrides[i] for i in which] if any(overrides) else None)
    radius = batch.radius_m[due]
    sigma = batch.position_sigma_m[due]
    if held:
        at = [*range(due.size)] + [j for j, p in held for _ in range(p.shape[0])]
        found = finder.find_rows(due[at], times[at],
                                 np.concatenate([own, *(p for _, p in held)]), plan_s[at],
                                 radius[at], None if ov is None else [ov[j] for j in at],
                                 sigma[at])
    else:  # most rounds: the rows once each, as they are
        found = finder.find_rows(due, times, own, plan_s, radius, ov, sigma)
    quiet = found.quiet[:due.size]
    # Nobody near nor silent, and at rest since its last round: nothing happens to it
    # (rest is idempotent, RoundBatch.resting). Most UAVs, most rounds.
    cand = np.flatnonzero(~(quiet & batch.resting[due]))
    home = batch.strategies
    if home is not None and home.table is finder.table and home.bound[due[cand]].all():
        return _decide_round(batch, steering, home, found, due, cand, plan_s, times, own,
                             climbed, held)
    # Another encounter strategy: each decides by itself, from Encounters objects.
    probes: dict[int, list[Encounters]] = {}
    k = due.size
    for j, p in held:
        probes[j] = [found.encounters(q) for q in range(k, k + p.shape[0])]
        k += p.shape[0]
    decided = []
    for j in cand.tolist():
        i = which[j]
        if quiet[j] and steering[i].rest(float(plan_s[j])):
            continue  # come to rest now
        steering[i].decide(float(plan_s[j]), times[j], found.encounters(j), float(climbed[j]),
                           own[j], probes.get(j))
        decided.append(i)
    return np.array(decided, dtype=np.int64)


def _decide_round(batch: RoundBatch, steering: Sequence[Steering] | Mapping[int, Steering],
                  home: StrategyTable, found: FoundRows, due: np.ndarray, cand: np.ndarray,
                  plan_s: np.ndarray, times: np.ndarray, own: np.ndarray, climbed: np.ndarray,
                  held: list[tuple[int, np.ndarray]]) -> np.ndarray:
    """:func:`avoidance_round`'s decisions of the rows ``due[cand]`` in one compiled call
    (:func:`~uavmpc.avoidance.decide.decide_rows`: their strategies' state is ``home``'s
    rows); each then steers by its decision, made into an object only when it is not its
    last one. Returns the rows that decided (not come to rest)."""
    out = found.out
    f_count = found.due.shape[0]
    e_start = out.e_start[:f_count + 1]
    e_count = int(e_start[f_count])
    priority, avoiding = found.sender_flags()
    # A tie of priorities (which a valid set-up never has) is broken by id.
    receivers = np.repeat(found.due, np.diff(e_start))
    before_us = np.zeros(e_count, dtype=np.bool_)
    ties = np.flatnonzero(priority == batch.senders.priority[receivers])
    if ties.size:
        ids = home.ids
        for e in ties.tolist():
            before_us[e] = ids[out.e_col[e]] < steering[int(receivers[e])].uav_id
    q_lo = np.zeros(due.size, dtype=np.int64)
    q_hi = np.zeros(due.size, dtype=np.int64)
    has_probes = np.zeros(due.size, dtype=np.bool_)
    k = due.size
    for j, p in held:
        q_lo[j], q_hi[j], has_probes[j] = k, k + p.shape[0], True
        k += p.shape[0]
    rows = due[cand]
    d_count = rows.shape[0]
    kind = np.empty(d_count, dtype=np.int8)
    z = np.empty(d_count)
    first = np.empty(d_count)
    flags = np.empty((d_count, N_FLAGS), dtype=np.bool_)
    masks = np.empty((e_count, N_MASKS), dtype=np.bool_)
    strategy_rows = home.ensure(times.shape[1])
    bound(decide_rows)(
        strategy_rows, rows, plan_s[cand], times[cand], own[cand],
        np.ones(d_count, dtype=np.bool_), climbed[cand], batch.senders.priority[rows],
        EncounterRows(out.e_col[:e_count], out.e_silent[:e_count], out.e_near[:e_count],
                      out.e_announced[:e_count], out.e_dz[:e_count], out.e_dxy[:e_count],
                      out.e_hears[:e_count], out.e_widen_v[:e_count], priority, avoiding,
                      before_us),
        e_start, cand, q_lo[cand], q_hi[cand], has_probes[cand], out.s_start, out.s_col,
        kind, z, first, flags, masks)
    batch.resting[rows] = kind == CALM_KIND
    decided = []
    ids = home.ids
    kinds = kind.tolist()
    for j, i in enumerate(rows.tolist()):
        c = kinds[j]
        if c == NEW_KIND:
            f = int(cand[j])
            lo, hi = int(e_start[f]), int(e_start[f + 1])
            s_lo, s_hi = int(out.s_start[f]), int(out.s_start[f + 1])
            steering[i].steer_by_kind(
                c, float(z[j]), float(first[j]), flags[j], masks[lo:hi],
                tuple(map(ids.__getitem__, out.e_col[lo:hi].tolist())),
                tuple(map(ids.__getitem__, out.s_col[s_lo:s_hi].tolist())))
        else:
            steering[i].steer_by_kind(c)
        if c != CALM_KIND:
            decided.append(i)
    return np.array(decided, dtype=np.int64)
