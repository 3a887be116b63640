"""The simulated world's compiled tick: every UAV's numerical part of its stack and its plant
on its own row of the world's records, in one compiled call (:func:`world_tick`), or, with a
Python QP solver, in the same kernels around the solver (:func:`world_pre`,
:func:`world_post`); :class:`CompiledTick` binds them to a world's records."""

from __future__ import annotations

import math
from typing import Any

import numba
import numpy as np

from uavmpc.control.se3 import ControlRows
from uavmpc.estimation.fleet import FleetEstimator
from uavmpc.jit import (
    HAS_CYCLE_COUNTER,
    bind,
    cycle_count,
    kernel,
    thread_count,
)
from uavmpc.onboard import OnboardBatch, StackStats, onboard_post, onboard_pre, onboard_row
from uavmpc.plant import PlantRows
from uavmpc.plant.kernels import fly_target
from uavmpc.plant.multirotor import Multirotor
from uavmpc.tracker.kernels import ReferenceTable, TrackerConsts, TrackerRows, make_scratch

#: The stages of a UAV's tick that :func:`world_tick` times: the tracker's three
#: (:func:`~uavmpc.tracker.kernels.tick_row`), the SE(3) control with the stack's bookkeeping,
#: the plant's substeps, and the traces (once per tick, for every UAV).
STAGES = ("prepare", "qp", "advance", "control", "plant", "trace")
#: A profile's entry after the stages: the cycles the threads of
#: :func:`world_tick_threads` waited at the end of their blocks for the slowest one (summed
#: over the threads; 0 on one thread).
WAIT = len(STAGES)
#: A profile's last entry: the number of UAV-ticks.
COUNT = WAIT + 1
#: The length of a profile: a cycle count per stage, the threads' wait, the UAV-ticks.
N_CYCLES = COUNT + 1
#: Counts (int64) left unused around each thread's profile in the threaded tick: 64 bytes.
_PAD = 8


@kernel(allocates=True)
def world_tick(trk: TrackerRows, refs: ReferenceTable, consts: TrackerConsts, ctl: ControlRows,
               stats: StackStats, plant: PlantRows, n_sub: int, dt: float, k: int,
               pos_out: np.ndarray, zoff_out: np.ndarray, dmin_out: np.ndarray,
               cycles: np.ndarray, est: np.ndarray) -> int:
    """One 10 ms tick of every UAV on the calling thread, the compiled solver inline: each
    UAV's stack (:func:`~uavmpc.onboard.onboard_row`) controls its plant row from its true
    state, then the plant flies the target (:func:`~uavmpc.plant.kernels.fly_target`); row
    ``k`` of the traces (positions (K, N, 3), z offsets (K, N), closest distance (K,)) is
    written (the pair distances only when asked for: :func:`pair_distances`). Returns −1, or
    the lowest index of
    a UAV whose attitude target could not be flown (that row is not flown; the caller stops
    the run).

    ``cycles``: (:data:`N_CYCLES`,) int64 to profile the tick, or (0,) not to: adds the CPU
    cycles of each of :data:`STAGES`, the threads' wait (:data:`WAIT`) and, last, the
    number of UAV-ticks (:func:`cycle_count`).
    ``est``: (N, 6) the estimated [p, v] the stacks fly on (attitude and rates stay the
    plants' own), or (0, 6) for the true state.

    :func:`world_tick_threads` is the same tick over threads. Two kernels rather than one
    with a branch: a command compiles only the one it runs (the threaded one costs about 16 s
    more to compile on a cold cache), and on one thread this one is faster (no parallel
    region to enter; docs/scale.md)."""
    n = plant.x.shape[0]
    timed = cycles.shape[0] > 0
    spent = np.zeros(N_CYCLES if timed else 0, dtype=np.int64)
    bad = _tick_rows(n - n, n, trk, refs, consts, ctl, stats,
                     plant, n_sub, dt, k, pos_out, zoff_out, est, spent)
    if bad >= 0:
        return bad
    c0 = cycle_count() if timed else 0
    dmin_out[k] = closest_distance(pos_out[k])
    if timed:
        for j in range(N_CYCLES):
            cycles[j] += spent[j]
        cycles[5] += cycle_count() - c0
    return -1


@kernel(parallel=True, nogil=True)
def world_tick_threads(trk: TrackerRows, refs: ReferenceTable, consts: TrackerConsts,
                       ctl: ControlRows, stats: StackStats, plant: PlantRows, n_sub: int,
                       dt: float, k: int, pos_out: np.ndarray, zoff_out: np.ndarray,
                       dmin_out: np.ndarray, cycles: np.ndarray, est: np.ndarray,
                       blocks: int) -> int:
    """:func:`world_tick` with its rows in ``blocks`` ≥ 1 contiguous blocks, one per thread
    (the caller passes :func:`uavmpc.jit.thread_count`, see :func:`uavmpc.jit.set_threads`: a
    compiled function that asks numba itself cannot be cached), the traces after them on
    the calling thread (the closest distance is a sweep, :func:`closest_distance`).

    The blocks are of equal rows (UAV rows cost about the same). The interpreter's lock is
    released for the call.

    A row reads and writes only its own rows of the records, with work arrays of its
    block's own, so the flight is bit-identical to :func:`world_tick`'s for any thread
    count. A row whose target could not be flown stops its thread; the lowest such row is
    returned. ``cycles`` sums the CPU cycles over the threads, and counts how long the
    threads done first waited for the last (:data:`WAIT`: the tick's jitter, since blocks of
    equal rows cost about the same, docs/scale.md)."""
    n = plant.x.shape[0]
    timed = cycles.shape[0] > 0
    nb = max(1, min(n, blocks))
    bad = np.full(nb, -1, dtype=np.int64)
    # Each thread's counts apart from the next one's by more than a cache line: counts
    # two cores add to in one line cost a transfer between them at every row.
    width = N_CYCLES if timed else 0
    spent = np.zeros((nb, width + 2 * _PAD), dtype=np.int64)
    done = np.zeros(nb, dtype=np.int64)
    for b in numba.prange(nb):
        lo, hi = b * n // nb, (b + 1) * n // nb
        bad[b] = _tick_rows(lo, hi, trk, refs, consts, ctl, stats, plant, n_sub, dt, k,
                            pos_out, zoff_out, est, spent[b, _PAD:_PAD + width])
        if timed:
            done[b] = cycle_count()
    fail = -1
    for b in range(nb):
        if bad[b] >= 0 and (fail < 0 or bad[b] < fail):
            fail = bad[b]
    if fail >= 0:
        return fail
    c0 = cycle_count() if timed else 0
    dmin_out[k] = closest_distance(pos_out[k])
    if timed:
        last = done.max()
        for b in range(nb):
            for j in range(N_CYCLES):
                cycles[j] += spent[b, _PAD + j]
            cycles[WAIT] += last - done[b]
        cycles[5] += cycle_count() - c0
    return -1


@kernel
def world_pre(trk: TrackerRows, stats: StackStats, plant: PlantRows) -> None:
    """:func:`world_tick`'s bookkeeping before the trackers tick (Python solvers)."""
    for i in range(plant.x.shape[0]):
        onboard_pre(i, trk, stats, plant.x[i, 0:3])


@kernel(allocates=True)
def world_post(trk: TrackerRows, consts: TrackerConsts, ctl: ControlRows, stats: StackStats,
               plant: PlantRows, n_sub: int, dt: float, k: int, pos_out: np.ndarray,
               zoff_out: np.ndarray, dmin_out: np.ndarray) -> int:
    """:func:`world_tick` after the trackers ticked (Python solvers): control and plants."""
    qd = np.empty(4)
    ff = np.empty(3)
    cmd = np.empty((3, 3))
    for i in range(plant.x.shape[0]):
        x = plant.x[i]
        thrust = onboard_post(i, trk, consts, ctl, stats, x[0:3], x[3:6], x[6:10], dt, qd, ff,
                              cmd)
        if not fly_target(i, plant, n_sub, qd, thrust, ff):
            return i
    _trace(trk, plant, k, pos_out, zoff_out, dmin_out)
    return -1


@kernel(allocates=True)
def _tick_rows(first: int, end: int, trk: TrackerRows, refs: ReferenceTable,
               consts: TrackerConsts, ctl: ControlRows, stats: StackStats, plant: PlantRows,
               n_sub: int, dt: float, k: int, pos_out: np.ndarray, zoff_out: np.ndarray,
               est: np.ndarray, spent: np.ndarray) -> int:
    """Rows ``first`` … ``end`` − 1 of :func:`world_tick`, with work arrays of their own
    (one thread's block), each row's position and z offset written into row ``k`` of the
    traces as soon as it is flown (its state still in this core's cache; gathered from every
    row after the tick they were most of the trace stage, docs/scale.md). Returns −1, or the
    first row this thread could not fly the target of (it takes no more rows)."""
    sc = make_scratch(consts.horizon_s.shape[0])
    qd = np.empty(4)
    ff = np.empty(3)
    cmd = np.empty((3, 3))
    timed = spent.shape[0] > 0
    estimated = est.shape[0] > 0
    for row in range(first, end):
        x = plant.x[row]
        if estimated:
            thrust = onboard_row(row, trk, refs, consts, ctl, stats, est[row, 0:3],
                                 est[row, 3:6], x[6:10], dt, sc, qd, ff, cmd, spent)
        else:
            thrust = onboard_row(row, trk, refs, consts, ctl, stats, x[0:3], x[3:6], x[6:10],
                                 dt, sc, qd, ff, cmd, spent)
        c0 = cycle_count() if timed else 0
        if not fly_target(row, plant, n_sub, qd, thrust, ff):
            return row
        c1 = cycle_count() if timed else 0
        for j in range(3):
            pos_out[k, row, j] = x[j]
        zoff_out[k, row] = trk.z_offset_m[row]
        if timed:
            spent[4] += c1 - c0
            spent[5] += cycle_count() - c1
            spent[COUNT] += 1
    return -1


@kernel
def _pair_d(pos: np.ndarray, a: int, b: int) -> float:
    """The distance between the points ``a`` and ``b`` of ``pos`` (N, 3) [m]."""
    d0 = pos[a, 0] - pos[b, 0]
    d1 = pos[a, 1] - pos[b, 1]
    d2 = pos[a, 2] - pos[b, 2]
    return math.sqrt(d0 * d0 + d1 * d1 + d2 * d2)


@kernel(allocates=True)
def closest_distance(pos: np.ndarray) -> float:
    """The smallest distance between two of the points ``pos`` (N, 3) [m] (inf for fewer
    than two): the root of the smallest of the pairs' squared distances, bit for bit the
    smallest :func:`pair_distances` (the root rounds correctly and never decreases).

    A sweep along x instead of every pair: with the points in order of x, the pairs of a
    point with those after it are tried only while their x difference alone, squared, is
    below the best so far. Exact, not approximate: a difference of x grows (rounding is
    monotone) and the sum of non-negative squares is at least its first term, so every
    pair left out is at least the best; the squares are those of :func:`_pair_d` (a
    difference's sign does not change its square). O(N log N) for UAVs spread over an
    area: about 5 µs at 300 UAVs and 50 µs at 1000 against their 45 000 and 500 000 pairs
    (``benchmarks/closest.py``). A pair whose distance is not a number is passed over, as ``min``
    passes it over."""
    n = pos.shape[0]
    order = np.argsort(pos[:, 0], kind="mergesort")
    best = math.inf
    for i in range(n):
        a = order[i]
        for j in range(i + 1, n):
            b = order[j]
            d0 = pos[a, 0] - pos[b, 0]
            if d0 * d0 >= best:
                break
            d1 = pos[a, 1] - pos[b, 1]
            d2 = pos[a, 2] - pos[b, 2]
            best = min(best, d0 * d0 + d1 * d1 + d2 * d2)
    return math.sqrt(best)


@kernel
def pair_distances(pos: np.ndarray, out: np.ndarray) -> None:
    """The distance of every pair (a, b > a) of the points ``pos`` (N, 3) [m] into ``out``
    (N (N − 1) / 2,), row by row (``np.triu_indices(N, 1)``'s order)."""
    n = pos.shape[0]
    p = 0
    for a in range(n):
        for b in range(a + 1, n):
            out[p] = _pair_d(pos, a, b)
            p += 1


@kernel
def _positions(trk: TrackerRows, plant: PlantRows, k: int, pos_out: np.ndarray,
               zoff_out: np.ndarray) -> None:
    """Row ``k`` of the position and z-offset traces."""
    for i in range(plant.x.shape[0]):
        for j in range(3):
            pos_out[k, i, j] = plant.x[i, j]
        zoff_out[k, i] = trk.z_offset_m[i]


@kernel(allocates=True)
def _trace(trk: TrackerRows, plant: PlantRows, k: int, pos_out: np.ndarray,
           zoff_out: np.ndarray, dmin_out: np.ndarray) -> None:
    """Row ``k`` of the traces (see :func:`world_tick`)."""
    _positions(trk, plant, k, pos_out, zoff_out)
    dmin_out[k] = closest_distance(pos_out[k])


class CompiledTick:
    """The numerical tick of a world's UAVs: its records (``onboard``, ``plants``), ``n_sub``
    plant substeps per ``period_s``, the controllers flying on ``estimator`` (None: the true
    state), the plants with wind (``windy``: their gusts held over the tick).

    Attributes:
        cycles: (:data:`N_CYCLES`,) int64 the cycle counts of the compiled calls of the
            current run (see :func:`world_tick`), or (0,) without a cycle counter.
    """

    def __init__(self, onboard: OnboardBatch, plants: PlantRows, n_sub: int, period_s: float,
                 estimator: FleetEstimator | None, windy: list[Multirotor]) -> None:
        self.onboard = onboard
        self.plants = plants
        self.n_sub = n_sub
        self.period_s = period_s
        self.estimator = estimator
        self.windy = windy
        self.cycles = np.zeros(N_CYCLES if HAS_CYCLE_COUNTER else 0, dtype=np.int64)
        self._kernels: tuple[Any, dict[bool, Any]] | None = None
        #: The reference table, row blocks and bound tick of the current run (:meth:`start`).
        self._run: tuple[Any, int, Any] | None = None
        self._no_estimate = np.zeros((0, 6))

    def __call__(self, traces: tuple[Any, ...]) -> int:
        """One tick of every UAV, writing ``traces`` (:func:`world_tick`'s ``k`` and
        arrays). Returns −1, or the row whose attitude target could not be flown."""
        for plant in self.windy:
            plant.hold_wind(self.period_s)
        ob = self.onboard
        trk = ob.tracker
        table = trk.table()
        if ob.inline:
            run = self._run
            if run is None or run[0] is not table:  # a new table (a new mission): bind again
                run = self.start(traces)
            _, blocks, tick = run
            args = (trk.rows, table, trk.consts, ob.control, ob.stats, self.plants, self.n_sub,
                    self.period_s, *traces, self.cycles, self.estimates())
            if not blocks:
                return tick(*args)  # type: ignore[no-any-return]
            return tick(*args, blocks)  # type: ignore[no-any-return]
        world_pre(trk.rows, ob.stats, self.plants)
        trk.step()
        return world_post(trk.rows, trk.consts, ob.control, ob.stats, self.plants,
                          self.n_sub, self.period_s, *traces)

    def start(self, traces: tuple[Any, ...]) -> tuple[Any, int, Any]:
        """Before a run (``traces``: its first tick's): the tick this thread count flies,
        bound to the records (compiled or loaded now, so that a run's clock measures flying),
        kept for the run's ticks with its row blocks; returns (table, blocks, tick). The
        thread count is read here, not at every tick: a run flies on the threads it started
        with."""
        table = self.onboard.tracker.table()
        blocks = self.blocks()
        self._run = (table, blocks, self.bound(table, traces, blocks))
        return self._run

    def blocks(self) -> int:
        """The row blocks the tick runs in: 0 for :func:`world_tick` (one thread, or one
        UAV), else the blocks of :func:`world_tick_threads` (the current thread count)."""
        blocks = min(thread_count(), self.plants.x.shape[0])
        return blocks if blocks > 1 else 0

    def bound(self, table: Any, traces: tuple[Any, ...], blocks: int) -> Any:
        """The tick for ``blocks`` (:meth:`blocks`' answer) bound to these records, compiled
        on first use."""
        threaded = blocks > 0
        if self._kernels is None or self._kernels[0] is not table:
            self._kernels = (table, {})
        bound = self._kernels[1]
        if threaded not in bound:
            ob = self.onboard
            trk = ob.tracker
            args = (trk.rows, table, trk.consts, ob.control, ob.stats, self.plants, self.n_sub,
                    self.period_s, *traces, self.cycles, self.estimates(peek=True))
            bound[threaded] = (bind(world_tick_threads, *args, 1) if threaded
                               else bind(world_tick, *args))
        return bound[threaded]

    def estimates(self, peek: bool = False) -> np.ndarray:
        """What the controllers fly on this tick: (N, 6) estimated [p, v], or (0, 6) (the
        truth). ``peek``: the array only, the sensors not advanced (to compile the tick)."""
        if self.estimator is None:
            return self._no_estimate
        if peek:
            return self.estimator.estimate
        x = self.plants.x
        return self.estimator.step(x[:, 0:3], x[:, 3:6])

    def trace(self, traces: tuple[Any, ...]) -> None:
        """Write ``traces`` of the plants' state (the per-object path's tick)."""
        _trace(self.onboard.tracker.rows, self.plants, *traces)
