"""One UAV's whole program (SPEC §1): inbox → avoidance → MPC tracker → SE(3) controller.

:class:`OnboardStack` is what runs on a UAV's own computer, behind one small interface::

    out = stack.tick(now_s, estimate, received)   # every 10 ms
    out.target      # AttitudeTarget for the plant side (simulator or autopilot)
    out.outgoing    # the prediction message to broadcast (bytes, signed with a key), or None

It owns everything per UAV: its inbox (decoding, validation, signatures), its avoidance
schedule (10 Hz) and strategy, its tracker and controller, its broadcast phase and period
(2 Hz), and its statistics. Drivers — the simulated world, a network node, a single flight —
are a clock, a transport and a plant around N stacks.

A driver that ticks many UAVs in one compiled call (the simulated world) splits :meth:`tick`
into its three phases: :meth:`OnboardStack.receive` and :meth:`OnboardStack.plan` per UAV
(the avoidance of every UAV due at once: :func:`~uavmpc.avoidance.round.avoidance_round`
over their :class:`~uavmpc.avoidance.round.Steering`), then the numerical part of
every UAV at once (:func:`onboard_row` on the rows of an :class:`OnboardBatch`, the same
function :meth:`tick` runs on its own row), then the broadcasts of every UAV due at once
(:func:`broadcast`, what :meth:`OnboardStack.emit` runs for its own row).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from typing import Any, NamedTuple

import numba
import numpy as np

from uavmpc.avoidance import (
    AvoidanceParams,
    ResolutionStrategy,
)
from uavmpc.avoidance.encounters import heard_columns
from uavmpc.avoidance.round import (
    AVOIDANCE_PERIOD_S,
    SCHEDULE_TOL_S,
    Steering,
    avoidance_plans,
    avoidance_round,
)
from uavmpc.avoidance.strategy import (
    StrategyTable,
)
from uavmpc.comms.auth import Identity, Roster, seal, sign
from uavmpc.comms.inbox import InboxRows, InboxTable, Store, fill_slot
from uavmpc.comms.link import PREDICTION_CHANNEL, Inbox
from uavmpc.comms.message import (
    MAX_HEARD,
    MAX_MESSAGE_BYTES,
    PredictionMessage,
    encode,
    fields_valid,
    from_prediction,
    write_message,
)
from uavmpc.control.se3 import ControlRows, Se3Controller, se3_row
from uavmpc.jit import bind, bound, cycle_count, kernel, thread_count
from uavmpc.plant import Airframe, AttitudeTarget, VehicleState
from uavmpc.plant.interface import heading_of
from uavmpc.reference import Reference
from uavmpc.tracker import (
    MpcTracker,
    Prediction,
    TrackerBatch,
    TrackerCommand,
    TrackerConfig,
)
from uavmpc.tracker.kernels import (
    ReferenceTable,
    Scratch,
    TrackerConsts,
    TrackerRows,
    limit_excess,
    plan,
    scratch_views,
    tick_row,
)
from uavmpc.tracker.tracker import TrackerOutput, prediction_from

#: Predictions are broadcast at 2 Hz (SPEC §5.1).
BROADCAST_PERIOD_S = 0.5
#: A virtual-UAV state outside its limits by more than this (when not braking) is a violation.
LIMIT_TOL = 1e-6


class StackStats(NamedTuple):
    """What N stacks counted, one row each (updated by :func:`onboard_row`).

    Attributes:
        ticks: (N,) int64 control periods flown.
        err_sq_sum_m2: (N,) Σ ‖estimate − virtual UAV‖² at each tick, before it [m²].
        max_z_offset_m: (N,) the largest avoidance offset in force [m].
        avoiding: (N,) bool the avoidance's current verdict (written by the stack).
        avoiding_ticks: (N,) int64 ticks flown while avoiding.
        limit_violations: (N,) int64 ticks whose new virtual state left the limits in force by
            more than :data:`LIMIT_TOL` (braking back in after a tightening is not one).
        max_limit_excess: (N,) the largest such excess.
    """

    ticks: np.ndarray
    err_sq_sum_m2: np.ndarray
    max_z_offset_m: np.ndarray
    avoiding: np.ndarray
    avoiding_ticks: np.ndarray
    limit_violations: np.ndarray
    max_limit_excess: np.ndarray

    @classmethod
    def empty(cls, n: int) -> StackStats:
        return cls(np.zeros(n, dtype=np.int64), np.zeros(n), np.zeros(n),
                   np.zeros(n, dtype=np.bool_), np.zeros(n, dtype=np.int64),
                   np.zeros(n, dtype=np.int64), np.zeros(n))


@kernel
def onboard_pre(i: int, trk: TrackerRows, stats: StackStats, p: np.ndarray) -> None:
    """Row i before its tracker ticks: the tracking error of the estimate position ``p`` (3,)
    against the virtual UAV of the same time."""
    s = trk.state[i]
    e0 = p[0] - s[0, 0]
    e1 = p[1] - s[1, 0]
    e2 = p[2] - s[2, 0]
    stats.err_sq_sum_m2[i] += e0 * e0 + e1 * e1 + e2 * e2


@kernel
def onboard_post(i: int, trk: TrackerRows, consts: TrackerConsts, ctl: ControlRows,
                 stats: StackStats, p: np.ndarray, v: np.ndarray, q: np.ndarray, dt: float,
                 q_out: np.ndarray, ff_out: np.ndarray, cmd: np.ndarray) -> float:
    """Row i after its tracker ticked: SE(3) control of the estimate (``p``, ``v``, ``q``)
    towards the new virtual-UAV state, and the bookkeeping. Returns the thrust [N]; writes the
    attitude target into ``q_out`` (4,) and the body-rate feedforward into ``ff_out`` (3,).
    ``cmd`` (3, 3): work array (the virtual UAV's position, velocity and acceleration)."""
    s = trk.state[i]
    heading = (s[3, 0] + np.pi) % (2.0 * np.pi) - np.pi
    for d in range(3):  # the state's columns as contiguous rows, as the law takes them
        for ax in range(3):
            cmd[d, ax] = s[ax, d]
    thrust = se3_row(i, ctl, p, v, q, cmd[0], cmd[1], cmd[2], heading, s[3, 1], dt, q_out,
                     ff_out)
    stats.ticks[i] += 1
    stats.max_z_offset_m[i] = max(stats.max_z_offset_m[i], trk.z_offset_m[i])
    if stats.avoiding[i]:
        stats.avoiding_ticks[i] += 1
    if not trk.braking[i]:
        ex = limit_excess(s, trk.v_lo[i], trk.v_hi[i], trk.a_lo[i], trk.a_hi[i], consts.tau_s)
        stats.max_limit_excess[i] = max(stats.max_limit_excess[i], ex)
        if ex > LIMIT_TOL:
            stats.limit_violations[i] += 1
    return thrust


@kernel
def onboard_row(i: int, trk: TrackerRows, refs: ReferenceTable, consts: TrackerConsts,
                ctl: ControlRows, stats: StackStats, p: np.ndarray, v: np.ndarray,
                q: np.ndarray, dt: float, sc: Scratch, q_out: np.ndarray,
                ff_out: np.ndarray, cmd: np.ndarray, cycles: np.ndarray) -> float:
    """The numerical part of row i's tick: bookkeeping, tracker (with the compiled solver),
    SE(3) controller. ``sc``: :func:`~uavmpc.tracker.kernels.make_scratch`'s work arrays;
    ``cmd``: :func:`onboard_post`'s.
    ``cycles``: (0,) int64, or (4,) or longer to add the CPU cycles of the tracker's stages
    (:func:`~uavmpc.tracker.kernels.tick_row`) to its first three and those of the control
    and bookkeeping to the fourth."""
    timed = cycles.shape[0] > 0
    c0 = cycle_count() if timed else 0
    onboard_pre(i, trk, stats, p)
    c1 = cycle_count() if timed else 0
    tick_row(i, trk, refs, consts, sc, cycles)
    c2 = cycle_count() if timed else 0
    thrust = onboard_post(i, trk, consts, ctl, stats, p, v, q, dt, q_out, ff_out, cmd)
    if timed:
        cycles[3] += (c1 - c0) + (cycle_count() - c2)
    return thrust


@kernel(allocates=True)
def onboard_one(i: int, trk: TrackerRows, refs: ReferenceTable, consts: TrackerConsts,
                ctl: ControlRows, stats: StackStats, p: np.ndarray, v: np.ndarray,
                q: np.ndarray, dt: float, buf: np.ndarray, skip: np.ndarray, q_out: np.ndarray,
                ff_out: np.ndarray) -> float:
    """:func:`onboard_row` for one stack ticking alone (work arrays from the batch's buffers,
    :func:`~uavmpc.tracker.kernels.scratch_views`)."""
    sc = scratch_views(buf, skip, consts.horizon_s.shape[0])
    return onboard_row(i, trk, refs, consts, ctl, stats, p, v, q, dt, sc, q_out, ff_out,
                       np.empty((3, 3)), np.empty(0, dtype=np.int64))


class SentRows(NamedTuple):
    """What N stacks broadcast last, one row each (written by :func:`broadcast_rows`).

    Attributes:
        plan: (N, 4, m, 3) its plan per axis (x, y, z, heading) and step [p, v, a]
            (:func:`~uavmpc.tracker.kernels.plan`); times_s: (N, m) its times [s, the
            stack's clock].
        heard: (N, :data:`~uavmpc.comms.message.MAX_HEARD`) int64 the inbox columns its heard
            list named, the first ``heard_count`` (N,) of them.
        stamp_s: (N,) its stamp [s, the stack's clock]; avoiding: (N,) bool its flag;
            priority: (N,) int64; sigma_m: (N, 2) its position uncertainty, horizontal and
            vertical 1σ [m].
    """

    plan: np.ndarray
    times_s: np.ndarray
    heard: np.ndarray
    heard_count: np.ndarray
    stamp_s: np.ndarray
    avoiding: np.ndarray
    priority: np.ndarray
    sigma_m: np.ndarray

    @classmethod
    def empty(cls, n: int, m: int) -> SentRows:
        return cls(np.zeros((n, 4, m, 3)), np.zeros((n, m)),
                   np.zeros((n, MAX_HEARD), dtype=np.int64), np.zeros(n, dtype=np.int64),
                   np.zeros(n), np.zeros(n, dtype=np.bool_), np.zeros(n, dtype=np.int64),
                   np.zeros((n, 2)))


class SenderRows(NamedTuple):
    """What N stacks put in every broadcast that does not change from one to the next, one row
    each (written by each stack when it is made).

    Attributes:
        inbox_row: (N,) int64 its row of its inbox table; priority: (N,) int64 its priority
            (one int64 does not hold: a value the message gate refuses, so that the checked
            path names it); counts_heard: (N,) bool its messages list whom it hears, with
            its finder's ``use_received``: (N,) bool, ``timeout_s``: (N,) and
            ``silent_hold_s``: (N,) [s] (:func:`~uavmpc.avoidance.encounters.heard_columns`).
    """

    inbox_row: np.ndarray
    priority: np.ndarray
    counts_heard: np.ndarray
    use_received: np.ndarray
    timeout_s: np.ndarray
    silent_hold_s: np.ndarray

    @classmethod
    def empty(cls, n: int) -> SenderRows:
        return cls(np.zeros(n, dtype=np.int64), np.zeros(n, dtype=np.int64),
                   np.zeros(n, dtype=np.bool_), np.zeros(n, dtype=np.bool_), np.zeros(n),
                   np.zeros(n))


@kernel(allocates=True)
def broadcast_rows(idx: np.ndarray, trk: TrackerRows, consts: TrackerConsts,
                   senders: SenderRows, stamp_s: np.ndarray, avoiding: np.ndarray,
                   sigma_m: np.ndarray, rows: InboxRows, store: Store, entries: np.ndarray,
                   sent: SentRows, out: np.ndarray, length: np.ndarray) -> None:
    """The broadcasts of rows ``idx`` (R,) in one call: each one's plan of its last tick into
    ``sent`` (the very plan :func:`avoidance_plans` hands the avoidance), its heard list (the
    columns of its inbox row that :func:`~uavmpc.avoidance.encounters.heard_columns` counts,
    with its finder's parameters: ``senders``), and its message's bytes into ``out[j]``
    (:func:`~uavmpc.comms.message.write_message`, stamped ``stamp_s[j]``, flag
    ``avoiding[j]``, its priority and ``sigma_m``), their number into ``length[j]``. A
    message :func:`~uavmpc.comms.message.fields_valid` refuses (a plan not finite or out of
    bounds, an uncertainty out of range, an id no message may carry: an all-zero entry of
    ``entries``, the table's :attr:`~uavmpc.comms.inbox.InboxTable.entries`) is not written:
    ``length[j] = -1``, and the caller builds it the checked way, which names the problem."""
    h = consts.horizon_s
    m = h.shape[0]
    pos = np.empty((m, 3))
    floats = np.empty(3)
    for j in range(idx.shape[0]):
        i = idx[j]
        r = senders.inbox_row[i]
        priority = senders.priority[i]
        p = sent.plan[i]
        plan(trk.rel[i], trk.u_plan[i], trk.p0[i], consts.free_t, consts.forced_t, p)
        times = sent.times_s[i]
        t0 = trk.t_s[i] - h[0]
        for k in range(m):
            times[k] = t0 + h[k]
            for ax in range(3):
                pos[k, ax] = p[ax, k, 0]
        sent.heard_count[i] = 0
        sent.stamp_s[i] = stamp_s[j]
        sent.avoiding[i] = avoiding[j]
        sent.priority[i] = priority
        sent.sigma_m[i, 0] = sigma_m[i, 0]
        sent.sigma_m[i, 1] = sigma_m[i, 1]
        own = entries[rows.own_col[r]]
        if not fields_valid(own[0], priority, stamp_s[j], sigma_m[i, 0], sigma_m[i, 1],
                            times, pos):
            length[j] = -1
            continue
        n = 0
        if senders.counts_heard[i]:
            n = heard_columns(rows, store, r, stamp_s[j], senders.use_received[i],
                              senders.timeout_s[i], senders.silent_hold_s[i], pos[0, 0],
                              pos[0, 1], sent.heard[i])
        sent.heard_count[i] = n
        floats[0] = stamp_s[j]
        floats[1] = sigma_m[i, 0]
        floats[2] = sigma_m[i, 1]
        length[j] = write_message(out[j], own, avoiding[j], priority, floats, times, pos,
                                  entries, sent.heard[i, :n])


@kernel(parallel=True)
def broadcast_rows_threads(idx: np.ndarray, trk: TrackerRows, consts: TrackerConsts,
                           senders: SenderRows, stamp_s: np.ndarray, avoiding: np.ndarray,
                           sigma_m: np.ndarray, rows: InboxRows, store: Store,
                           entries: np.ndarray, sent: SentRows, out: np.ndarray,
                           length: np.ndarray, blocks: int) -> None:
    """:func:`broadcast_rows` with the rows in ``blocks`` contiguous blocks, one per thread:
    each row's outputs are its own, so the bytes are the same for any number."""
    r_count = idx.shape[0]
    nb = max(1, min(r_count, blocks))
    for b in numba.prange(nb):
        lo, hi = b * r_count // nb, (b + 1) * r_count // nb
        broadcast_rows(idx[lo:hi], trk, consts, senders, stamp_s[lo:hi], avoiding[lo:hi],
                       sigma_m, rows, store, entries, sent, out[lo:hi], length[lo:hi])


@kernel
def store_sent(store: Store, slots: np.ndarray, cols: np.ndarray, sent: SentRows,
               rows: np.ndarray) -> None:
    """The messages rows ``rows`` (R,) broadcast last (``sent``), into store ``slots`` (R,)
    (reserved: :meth:`~uavmpc.comms.inbox.InboxTable.reserve`) with their senders' columns
    ``cols`` (R,): field for field what their bytes decode to (the heard list as the
    columns it was written from)."""
    m = sent.times_s.shape[1]
    for j in range(rows.shape[0]):
        i = rows[j]
        slot = slots[j]
        for k in range(m):
            store.times_s[slot, k] = sent.times_s[i, k]
            for ax in range(3):
                store.positions_m[slot, k, ax] = sent.plan[i, ax, k, 0]
        n = sent.heard_count[i]
        store.heard_n[slot] = n
        for k in range(n):
            store.heard_col[slot, k] = sent.heard[i, k]
        fill_slot(store, slot, cols[j], m, sent.stamp_s[i], sent.priority[i], sent.avoiding[i],
                  sent.sigma_m[i, 0], sent.sigma_m[i, 1])


def _as_int64(priority: object) -> int:
    """A stack's priority as the compiled gate takes it: anything but an integer that int64
    holds as one the gate refuses, so the checked path names it."""
    if (isinstance(priority, bool) or not isinstance(priority, int | np.integer)
            or not -(2**63) <= int(priority) < 2**63):
        return 2**62  # outside int32: fields_valid refuses it
    return int(priority)


def broadcast(batch: OnboardBatch, stacks: Sequence[OnboardStack],
              now_s: np.ndarray) -> list[bytes]:
    """The broadcasts of ``stacks`` (rows of ``batch`` with one inbox table, each due),
    stamped ``now_s`` (R,) each on its own clock: one compiled call
    (:func:`broadcast_rows`, on the threads when there are several), then each stack's
    bookkeeping
    (:meth:`OnboardStack.sent`). Returns each one's bytes, signed or sealed when the stack
    has a key or an identity."""
    r_count = len(stacks)
    table = stacks[0].inbox.table
    flags = [s.flag_up for s in stacks]
    stamp = np.ascontiguousarray(now_s, dtype=float)
    out = np.empty((r_count, MAX_MESSAGE_BYTES), dtype=np.uint8)
    length = np.empty(r_count, dtype=np.int64)
    trk = batch.tracker
    args = (np.array([s.row for s in stacks], dtype=np.int64), trk.rows, trk.consts,
            batch.senders, stamp, np.array(flags, dtype=np.bool_), batch.position_sigma_m,
            table.rows, table.store, table.entries, batch.sent, out, length)
    threads = thread_count()
    if threads > 1 and r_count > 1:
        bound(broadcast_rows_threads)(*args, threads)
    else:
        bound(broadcast_rows)(*args)
    n = length.tolist()
    now = stamp.tolist()
    return [s.sent(now[j], out[j, :n[j]].tobytes() if n[j] >= 0 else None, flags[j])
            for j, s in enumerate(stacks)]


class Schedule(NamedTuple):
    """When N stacks next plan and broadcast, one row each (written by the stacks; a driver
    ticking many reads them to find who is due).

    Attributes:
        next_avoidance_s: (N,) the next avoidance update, on the stack's tracker clock [s].
        next_broadcast_s: (N,) the next broadcast, on the stack's clock [s].
        planning: (N,) bool the stack runs an avoidance it steers by (a strategy, the vehicle
            is its to steer, its tracker has ticked).
    """

    next_avoidance_s: np.ndarray
    next_broadcast_s: np.ndarray
    planning: np.ndarray

    @classmethod
    def empty(cls, n: int) -> Schedule:
        return cls(np.zeros(n), np.zeros(n), np.zeros(n, dtype=np.bool_))


@kernel
def broadcasts_due(sched: Schedule, offsets_s: np.ndarray, now_s: float, rows_out: np.ndarray,
                   stamps_out: np.ndarray) -> int:
    """The rows whose broadcast is due at world time ``now_s``, each on its own clock (the
    world's plus ``offsets_s`` (N,) [s]), in row order into ``rows_out`` (N,) with their
    clocks into ``stamps_out`` (N,); returns how many."""
    n = 0
    for i in range(offsets_s.shape[0]):
        own = now_s + offsets_s[i]
        if own >= sched.next_broadcast_s[i] - SCHEDULE_TOL_S:
            rows_out[n] = i
            stamps_out[n] = own
            n += 1
    return n


@kernel
def next_broadcast_s(sched: Schedule, offsets_s: np.ndarray) -> float:
    """The first world time [s] any row's next broadcast is due at (each row on its own
    clock: the world's plus ``offsets_s`` (N,) [s])."""
    first = np.inf
    for i in range(offsets_s.shape[0]):
        first = min(first, sched.next_broadcast_s[i] - offsets_s[i])
    return first


class OnboardBatch:
    """The numerical state of N onboard stacks of one tracker set-up, one row each.

    Attributes:
        tracker: their virtual UAVs (:class:`~uavmpc.tracker.TrackerBatch`).
        control: their SE(3) controllers' state (:class:`~uavmpc.control.se3.ControlRows`).
        stats: their counters (:class:`StackStats`).
        position_sigma_m: (N, 2) each one's position uncertainty, horizontal and vertical 1σ
            [m] (0: flying on the true state or a centimetre-class fix): what its predictions
            state and its avoidance widens its pairs by (docs/safety.md, A3). Set by the
            driver that knows its estimator.
    """

    def __init__(self, tracker_config: TrackerConfig | None = None, n: int = 1) -> None:
        self.tracker = TrackerBatch(tracker_config, n)
        self.control = ControlRows.empty(n)
        self.stats = StackStats.empty(n)
        self.schedule = Schedule.empty(n)
        #: What each row broadcast last (:func:`broadcast`).
        self.sent = SentRows.empty(n, self.tracker.config.steps)
        #: What each row's broadcasts carry that does not change (written by its stack).
        self.senders = SenderRows.empty(n)
        self.position_sigma_m = np.zeros((n, 2))
        #: The rows whose last avoidance decision holds short
        #: (:attr:`~uavmpc.avoidance.AvoidanceDecision.holding`): only their strategies have
        #: :meth:`~uavmpc.avoidance.EncounterStrategy.hold_probes` to find.
        self.holding: set[int] = set()
        #: (N,) bool the row's strategy came to rest at a round with nobody near or silent
        #: (:meth:`~uavmpc.avoidance.round.Steering.rest`) and has not decided since. Rest
        #: is idempotent (:meth:`~uavmpc.avoidance.EncounterStrategy.rest`): a round that
        #: finds nobody near or silent again changes nothing for it, and is not asked of it.
        self.resting = np.zeros(n, dtype=np.bool_)
        #: (N,) each row's conflict cylinder radius (its stack's ``params.radius_m``) [m].
        self.radius_m = np.zeros(n)
        #: The state of the rows' height-offset strategies, one row each, its columns those
        #: of the first inbox table a stack binds it with (:meth:`strategies_for`).
        self.strategies: StrategyTable | None = None
        self.n = n
        self._one: tuple[ReferenceTable, Callable[..., Any]] | None = None

    def strategies_for(self, table: InboxTable) -> StrategyTable | None:
        """The rows its stacks' height-offset strategies live in when their inbox table is
        ``table`` (made with the first one asked for); None for another table (such a
        strategy keeps a row of its own and decides by itself)."""
        if self.strategies is None:
            self.strategies = StrategyTable(self.n, table)
        return self.strategies if self.strategies.table is table else None

    @property
    def inline(self) -> bool:
        """Every row solves its QPs inside the compiled tick (no Python solver)."""
        return self.tracker.all_inline

    def tick_row(self, row: int, p: np.ndarray, v: np.ndarray, q: np.ndarray, dt: float,
                 q_out: np.ndarray, ff_out: np.ndarray) -> float:
        """The numerical part of one row's tick (see :func:`onboard_row`); returns the thrust."""
        t = self.tracker
        if t.solvers[row] is not None:  # a Python solver: the same kernels, in three calls
            onboard_pre(row, t.rows, self.stats, p)
            t.step(np.array([row], dtype=np.int64))
            return float(onboard_post(row, t.rows, t.consts, self.control, self.stats, p, v, q,
                                      dt, q_out, ff_out, np.empty((3, 3))))
        table = t.table()
        if self._one is None or self._one[0] is not table:
            self._one = (table, bind(onboard_one, row, t.rows, table, t.consts, self.control,
                                     self.stats, p, v, q, dt, *t.scratch, q_out, ff_out))
        return float(self._one[1](row, t.rows, table, t.consts, self.control, self.stats, p, v,
                                  q, dt, *t.scratch, q_out, ff_out))


@dataclass(frozen=True, eq=False)
class OnboardOutput:
    """What one tick of the stack produced.

    Attributes:
        target: attitude and collective thrust for the plant side.
        outgoing: the prediction message to broadcast now (wire bytes, signed when the stack
            has a key), or None.
    """

    target: AttitudeTarget
    outgoing: bytes | None = None


@dataclass(frozen=True)
class StackReport:
    """One stack's statistics (serialised at the edge: ``dataclasses.asdict``).

    Attributes:
        uav_id: who.
        ticks: control periods flown; flight_s: their duration [s].
        tracking_rmse_m: RMS distance of the estimate from the virtual UAV [m].
        max_z_offset_m: the largest avoidance offset [m]; avoidance_active_s: time avoiding.
        limit_violations, max_limit_excess: see :class:`StackStats`.
        tracker_fallbacks: ticks on which an axis braked because its QP failed.
        predictions_sent: broadcasts; messages_accepted, messages_superseded: inbox counters;
        messages_rejected: rejected messages by reason.
    """

    uav_id: str
    ticks: int
    flight_s: float
    tracking_rmse_m: float
    max_z_offset_m: float
    avoidance_active_s: float
    limit_violations: int
    max_limit_excess: float
    tracker_fallbacks: int
    predictions_sent: int
    messages_accepted: int
    messages_superseded: int
    messages_rejected: dict[str, int] = field(default_factory=dict)

    @property
    def messages_rejected_total(self) -> int:
        return sum(self.messages_rejected.values())


class OnboardStack:
    """Inbox, avoidance, tracker and SE(3) controller of one UAV, ticked at the tracker's rate.

    Args:
        airframe: the aircraft (mass, thrust range, SE(3) gains).
        tracker_config: MPC set-up and nominal limits (default: packaged data/tracker.toml;
            with ``batch``, the batch's).
        position_m, heading_rad, t0_s: the initial virtual-UAV state (usually the UAV's own).
        uav_id, priority: identity on the link (lower priority number = higher priority).
        avoidance: a resolution strategy (:class:`~uavmpc.avoidance.ResolutionStrategy`: it
            is handed the messages; an :class:`~uavmpc.avoidance.EncounterStrategy` is handed
            its encounters), or None to fly without avoidance (the broadcast flag is then
            down: others treat this UAV as non-cooperative and yield to it).
        params: the avoidance parameters the inbox applies too (message age, time reference);
            default: the strategy's, else the reference design's.
        key: the swarm's shared key: outgoing predictions are signed, unsigned or forged ones
            rejected (:mod:`uavmpc.comms.auth`).
        identity, roster: per-member identities instead of a key: outgoing predictions are
            sealed with this UAV's own identity (whose id must be ``uav_id``), incoming ones
            accepted only when signed by the roster's UAV they claim to be from.
        broadcast_phase_s: first broadcast at ``t0_s + broadcast_phase_s``, then every
            ``broadcast_period_s`` (UAVs spread their phases over the period).
        batch, row: the row of an :class:`OnboardBatch` this stack's numbers live in (default:
            a batch of its own).
    """

    def __init__(
        self,
        airframe: Airframe,
        tracker_config: TrackerConfig | None = None,
        *,
        position_m: tuple[float, float, float] | np.ndarray = (0.0, 0.0, 0.0),
        heading_rad: float = 0.0,
        t0_s: float = 0.0,
        uav_id: str = "uav",
        priority: int = 0,
        avoidance: ResolutionStrategy | None = None,
        params: AvoidanceParams | None = None,
        key: bytes | None = None,
        identity: Identity | None = None,
        roster: Roster | None = None,
        broadcast_period_s: float = BROADCAST_PERIOD_S,
        broadcast_phase_s: float = 0.0,
        batch: OnboardBatch | None = None,
        row: int = 0,
        inbox_table: InboxTable | None = None,
    ) -> None:
        if batch is None:
            batch = OnboardBatch(tracker_config, 1)
        if not broadcast_period_s > 0.0:
            raise ValueError(f"broadcast_period_s must be > 0, got {broadcast_period_s}")
        self.batch = batch
        self.row = int(row)
        self.airframe = airframe
        self.uav_id = uav_id
        self._priority = priority
        self.tracker = MpcTracker(batch.tracker.config, position_m=position_m,
                                  heading_rad=heading_rad, t0_s=t0_s, batch=batch.tracker,
                                  row=self.row)
        self.period_s = self.tracker.config.first_step_s
        self.controller = Se3Controller(airframe, period_s=self.period_s, rows=batch.control,
                                        row=self.row)
        self.avoidance = avoidance
        if params is None:
            params = avoidance.params if avoidance is not None else AvoidanceParams()
        self.params = params
        batch.radius_m[self.row] = params.radius_m
        if (identity is None) != (roster is None):
            raise ValueError("identities need both this UAV's identity and the roster")
        if identity is not None and identity.member_id != uav_id:
            raise ValueError(f"identity {identity.member_id!r} cannot sign as {uav_id!r}")
        self.key = key
        self.identity = identity
        self.inbox = Inbox(uav_id, time_reference=params.time_reference,
                           max_age_s=params.timeout_s, key=key, table=inbox_table,
                           row=self.row, roster=roster)
        #: Its avoidance: the decision it steers by and what that sets on its tracker
        #: (:class:`~uavmpc.avoidance.round.Steering`; a round of many rows calls it).
        self.steering = Steering(avoidance, self.tracker, batch, self.row, self.inbox.table,
                                 uav_id, priority, batch.stats.avoiding)
        # Its messages list whom its finder counts (docs/safety.md, A2); without one, nobody.
        f = self.steering.own_finder
        senders = batch.senders
        senders.inbox_row[self.row] = self.inbox.row
        senders.priority[self.row] = _as_int64(priority)
        senders.counts_heard[self.row] = f is not None
        senders.use_received[self.row] = f is not None and f.use_received
        senders.timeout_s[self.row] = f.timeout_s if f is not None else 0.0
        senders.silent_hold_s[self.row] = f.silent_hold_s if f is not None else 0.0
        self.broadcast_period_s = float(broadcast_period_s)
        sched = batch.schedule
        sched.next_broadcast_s[self.row] = float(t0_s) + float(broadcast_phase_s)
        sched.next_avoidance_s[self.row] = float(t0_s)
        #: How many predictions it has broadcast.
        self.predictions_sent = 0
        #: False while the vehicle is not ours to steer (:meth:`follow`): no avoidance, and
        #: the broadcast flag down.
        self.cooperative = True
        self._ticked = False
        sched.planning[self.row] = False
        batch.resting[self.row] = False
        self._idx = np.array([self.row], dtype=np.int64)
        for name in StackStats._fields:
            getattr(batch.stats, name)[self.row] = 0

    # ------------------------------------------------------------------ the interface
    def set_mission(self, reference: Reference) -> None:
        """Fly a new desired trajectory (validated when the Reference was built)."""
        self.tracker.set_reference(reference)

    def tick(self, now_s: float, estimate: VehicleState,
             received: Iterable[bytes] = ()) -> OnboardOutput:
        """One control period at ``now_s``: take the received messages, reshape the reference
        if the avoidance is due, advance the virtual UAV, steer the real one towards it, and
        broadcast the plan when due."""
        p = _estimate_part(estimate, "position_m", 3)
        v = _estimate_part(estimate, "velocity_mps", 3)
        q_now = _estimate_part(estimate, "attitude_wxyz", 4)
        self.receive(now_s, received)
        self.plan(now_s)
        q = np.empty(4)
        ff = np.empty(3)
        thrust = self.batch.tick_row(self.row, p, v, q_now, self.period_s, q, ff)
        target = AttitudeTarget(attitude_wxyz=q, thrust_n=thrust, body_rates_ff_radps=ff)
        return OnboardOutput(target, self.emit(now_s))

    def follow(self, now_s: float, estimate: VehicleState) -> None:
        """The vehicle is not ours to steer (its autopilot holds it after a failsafe, a pilot
        took it over): re-anchor the virtual UAV at its measured state, holding there, so that
        the plan we broadcast says what it will really do — and broadcast with the avoidance
        flag down from now on, since it will not yield (others avoid it)."""
        p = _estimate_part(estimate, "position_m", 3)
        v = _estimate_part(estimate, "velocity_mps", 3)
        heading = float(heading_of(_estimate_part(estimate, "attitude_wxyz", 4)))
        self.cooperative = False
        self.batch.schedule.planning[self.row] = False
        self.steering.release()
        lo, hi = self.tracker.limits.velocity_bounds()
        state = np.zeros((4, 3))
        state[:3, 0] = p
        state[:3, 1] = np.clip(v, lo[:3] * (1.0 - 1e-6), hi[:3] * (1.0 - 1e-6))
        now_heading = self.tracker.state[3, 0]  # continuous: keep its turns
        state[3, 0] = now_heading + (heading - now_heading + np.pi) % (2.0 * np.pi) - np.pi
        self.tracker.set_z_offset(0.0)
        self.tracker.set_state(state, now_s)
        self.tracker.set_reference(Reference.goto(p[0], p[1], p[2], state[3, 0], start_s=now_s))

    # ------------------------------------------------------------------ the phases
    def receive(self, now_s: float, received: Iterable[bytes]) -> list[PredictionMessage | None]:
        """Verify, decode and validate what arrived; one entry per datagram: the message it
        kept, or None (rejected, counted by reason, or older than what it holds)."""
        return [self.inbox.accept(data, now_s) for data in received]

    def plan(self, now_s: float) -> None:
        """Avoidance (every :data:`AVOIDANCE_PERIOD_S`, once there is a plan): the z offset
        and the limits for the next tracker tick."""
        steering = self.steering
        if steering.own_finder is not None:  # the encounters found for it: a round of one row
            avoidance_round(self.batch, {self.row: steering}, steering.own_finder,
                            rows=self._idx)
            return
        if self.avoidance is None or not self.cooperative or not self._ticked:
            return
        plan_s = self.tracker.time_s
        if not steering.due():
            return
        self.batch.schedule.next_avoidance_s[self.row] = plan_s + AVOIDANCE_PERIOD_S
        trk = self.batch.tracker
        times = np.empty((1, trk.config.steps))
        own = np.empty((1, trk.config.steps, 3))
        climbed = np.empty(1)
        avoidance_plans(self._idx, trk.rows, trk.table(), trk.consts, times, own, climbed)
        # only ``update``: the messages
        steering.apply(self.avoidance.update(plan_s, self.uav_id, self.priority, times[0],
                                             own[0], self.inbox.latest))

    def emit(self, now_s: float) -> bytes | None:
        """After the tick: the prediction message when a broadcast is due (stamped ``now_s``)."""
        self.mark_ticked()
        if now_s < self.batch.schedule.next_broadcast_s[self.row] - SCHEDULE_TOL_S:
            return None
        return broadcast(self.batch, (self,), np.array([now_s]))[0]

    @property
    def priority(self) -> int:
        """Its priority on the link, as given (fixed: its broadcasts carry it,
        :attr:`OnboardBatch.senders`)."""
        return self._priority  # type: ignore[no-any-return]

    @property
    def flag_up(self) -> bool:
        """What its messages' flag says: "I will make way" (it runs avoidance on a vehicle
        it steers), down while its hold cannot (:attr:`AvoidanceDecision.stuck`)."""
        decision = self.steering.decision
        stuck = decision is not None and decision.stuck
        return self.avoidance is not None and self.cooperative and not stuck

    def sent(self, now_s: float, data: bytes | None, avoiding: bool) -> bytes:
        """Its broadcast at ``now_s`` (:func:`broadcast`) with the flag ``avoiding``
        (:attr:`flag_up`): ``data``, the bytes written from its row of
        :attr:`OnboardBatch.sent`; or ``data`` None to build the message the checked way
        (raises :class:`~uavmpc.comms.message.InvalidMessageError` naming what is wrong).
        Returns the bytes to send (signed or sealed with its key or identity)."""
        self.batch.schedule.next_broadcast_s[self.row] += self.broadcast_period_s
        if data is None:  # raises, naming the field the compiled checks stopped at
            data = encode(from_prediction(
                self.tracker.prediction(), uav_id=self.uav_id, priority=self.priority,
                stamp_s=now_s, avoiding=avoiding, heard=self.heard,
                position_sigma_m=self.position_sigma_m))
        if self.key is not None:
            data = sign(data, self.key)
        elif self.identity is not None:
            # Stamps order a sender's predictions; the sequence number is the count.
            data = seal(data, PREDICTION_CHANNEL, self.identity, self.predictions_sent)
        self.predictions_sent += 1
        return data

    @property
    def heard(self) -> tuple[str, ...]:
        """The ids its last message listed as heard (docs/safety.md, A2)."""
        sent = self.batch.sent
        cols = sent.heard[self.row, :sent.heard_count[self.row]].tolist()
        return tuple(map(self.inbox.table.ids.__getitem__, cols))

    @property
    def last_broadcast(self) -> Prediction | None:
        """The prediction of its last broadcast (None before the first)."""
        if not self.predictions_sent:
            return None
        sent = self.batch.sent
        return prediction_from(sent.plan[self.row], sent.times_s[self.row])

    def mark_ticked(self) -> None:
        """The stack's row has ticked (a driver ticking many rows at once says so)."""
        if not self._ticked:
            self._ticked = True
            self.batch.schedule.planning[self.row] = (self.avoidance is not None
                                                      and self.cooperative)

    # ------------------------------------------------------------------ views
    @property
    def position_sigma_m(self) -> tuple[float, float]:
        """The position uncertainty it states: (horizontal, vertical) 1σ [m]. Set from now
        on in its broadcasts, which every receiver widens the pair's cylinder by, and in its
        own encounters (docs/safety.md, A3; :mod:`uavmpc.assumptions`)."""
        sigma = self.batch.position_sigma_m[self.row]
        return float(sigma[0]), float(sigma[1])

    @position_sigma_m.setter
    def position_sigma_m(self, sigma_m: tuple[float, float]) -> None:
        sigma_h_m, sigma_v_m = sigma_m
        if not (math.isfinite(sigma_h_m) and math.isfinite(sigma_v_m)
                and sigma_h_m >= 0.0 and sigma_v_m >= 0.0):
            raise ValueError(f"position_sigma_m: 1σ must be finite and ≥ 0, got "
                             f"({sigma_h_m}, {sigma_v_m})")
        self.batch.position_sigma_m[self.row, 0] = sigma_h_m
        self.batch.position_sigma_m[self.row, 1] = sigma_v_m

    @property
    def last_output(self) -> TrackerOutput | None:
        """The tracker's last tick (None before the first)."""
        return self.tracker.batch.output(self.row) if self._ticked else None

    def command(self) -> TrackerCommand:
        """The virtual UAV's current state: the command the controller follows."""
        return self.tracker.command()

    def report(self) -> StackReport:
        """The statistics so far."""
        st = self.batch.stats
        i = self.row
        ticks = int(st.ticks[i])
        return StackReport(
            uav_id=self.uav_id, ticks=ticks, flight_s=ticks * self.period_s,
            tracking_rmse_m=float(np.sqrt(st.err_sq_sum_m2[i] / max(ticks, 1))),
            max_z_offset_m=float(st.max_z_offset_m[i]),
            avoidance_active_s=int(st.avoiding_ticks[i]) * self.period_s,
            limit_violations=int(st.limit_violations[i]),
            max_limit_excess=float(st.max_limit_excess[i]),
            tracker_fallbacks=self.tracker.fallback_count,
            predictions_sent=self.predictions_sent, messages_accepted=self.inbox.accepted,
            messages_superseded=self.inbox.superseded,
            messages_rejected=dict(self.inbox.rejected))


def _estimate_part(estimate: VehicleState, name: str, n: int) -> np.ndarray:
    """A fresh, writable float64 (n,) copy of one field of the estimate (the exact array type
    the bound kernels take), or a ValueError naming the field."""
    try:
        out = np.array(getattr(estimate, name), dtype=float).reshape(n)
    except (AttributeError, TypeError, ValueError):
        raise ValueError(f"estimate.{name}: must be {n} numbers, got "
                         f"{getattr(estimate, name, None)!r}") from None
    if not np.all(np.isfinite(out)):
        raise ValueError(f"estimate.{name}: not finite ({out.tolist()}); the stack refuses to "
                         "steer on it")
    return out
