"""The simulated world's compiled tick: every UAV's numerical part of its stack and its plant
on its own row of the world's records, in one compiled call (:func:`world_tick`), or, with a
Python QP solver, in the same kernels around the solver (:func:`world_pre`,
:func:`world_post`); :class:`CompiledTick` binds them to a world's records."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from uavmpc.estimation.fleet import FleetEstimator
from uavmpc.jit import HAS_CYCLE_COUNTER, bind, cycle_count, kernel
from uavmpc.onboard import OnboardBatch, onboard_post, onboard_pre, onboard_row
from uavmpc.plant import PlantRows
from uavmpc.plant.kernels import fly_target
from uavmpc.plant.multirotor import Multirotor
from uavmpc.tracker.kernels import make_scratch


@kernel
def world_tick(trk, refs, consts, ctl, stats, plant, n_sub, dt, k, pos_out, zoff_out, dmin_out,
               pair_d, cycles, est):
    """One 10 ms tick of every UAV, the compiled solver inline: each UAV's stack
    (:func:`~uavmpc.onboard.onboard_row`) controls its plant row from its true state, then the
    plant flies the target (:func:`~uavmpc.plant.kernels.fly_target`); row ``k`` of the traces
    (positions (K, N, 3), z offsets (K, N), closest distance (K,)) and the pair distances
    ``pair_d`` (N (N − 1) / 2,) are written. Returns −1, or the index of a UAV whose attitude
    target could not be flown (the tick stops there).

    ``cycles``: (4,) int64 to profile the tick, or (0,) not to: adds the cycle counts of the
    stacks, the plants and the traces, and the number of UAV-ticks (:func:`cycle_count`).
    ``est``: (N, 6) the estimated [p, v] the stacks fly on (attitude and rates stay the
    plants' own), or (0, 6) for the true state."""
    n = plant.x.shape[0]
    sc = make_scratch(consts.horizon_s.shape[0])
    qd = np.empty(4)
    ff = np.empty(3)
    timed = cycles.shape[0] > 0
    estimated = est.shape[0] > 0
    c0 = c1 = 0
    for i in range(n):
        x = plant.x[i]
        if timed:
            c0 = cycle_count()
        if estimated:
            thrust = onboard_row(i, trk, refs, consts, ctl, stats, est[i, 0:3], est[i, 3:6],
                                 x[6:10], dt, sc, qd, ff)
        else:
            thrust = onboard_row(i, trk, refs, consts, ctl, stats, x[0:3], x[3:6], x[6:10], dt,
                                 sc, qd, ff)
        if timed:
            c1 = cycle_count()
            cycles[0] += c1 - c0
        if not fly_target(i, plant, n_sub, qd, thrust, ff):
            return i
        if timed:
            cycles[1] += cycle_count() - c1
            cycles[3] += 1
    if timed:
        c0 = cycle_count()
    _trace(trk, plant, k, pos_out, zoff_out, dmin_out, pair_d)
    if timed:
        cycles[2] += cycle_count() - c0
    return -1


@kernel
def world_pre(trk, stats, plant):
    """:func:`world_tick`'s bookkeeping before the trackers tick (Python solvers)."""
    for i in range(plant.x.shape[0]):
        onboard_pre(i, trk, stats, plant.x[i, 0:3])


@kernel
def world_post(trk, consts, ctl, stats, plant, n_sub, dt, k, pos_out, zoff_out, dmin_out,
               pair_d):
    """:func:`world_tick` after the trackers ticked (Python solvers): control and plants."""
    qd = np.empty(4)
    ff = np.empty(3)
    for i in range(plant.x.shape[0]):
        x = plant.x[i]
        thrust = onboard_post(i, trk, consts, ctl, stats, x[0:3], x[3:6], x[6:10], dt, qd, ff)
        if not fly_target(i, plant, n_sub, qd, thrust, ff):
            return i
    _trace(trk, plant, k, pos_out, zoff_out, dmin_out, pair_d)
    return -1


@kernel
def _trace(trk, plant, k, pos_out, zoff_out, dmin_out, pair_d):
    n = plant.x.shape[0]
    for i in range(n):
        for j in range(3):
            pos_out[k, i, j] = plant.x[i, j]
        zoff_out[k, i] = trk.z_offset_m[i]
    best = math.inf
    p = 0
    for a in range(n):
        for b in range(a + 1, n):
            d0 = pos_out[k, a, 0] - pos_out[k, b, 0]
            d1 = pos_out[k, a, 1] - pos_out[k, b, 1]
            d2 = pos_out[k, a, 2] - pos_out[k, b, 2]
            d = math.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
            pair_d[p] = d
            best = min(best, d)
            p += 1
    dmin_out[k] = best


class CompiledTick:
    """The numerical tick of a world's UAVs: its records (``onboard``, ``plants``), ``n_sub``
    plant substeps per ``period_s``, the controllers flying on ``estimator`` (None: the true
    state), the plants with wind (``windy``: their gusts held over the tick).

    Attributes:
        cycles: (4,) int64 the cycle counts of the compiled calls of the current run (see
            :func:`world_tick`), or (0,) without a cycle counter.
    """

    def __init__(self, onboard: OnboardBatch, plants: PlantRows, n_sub: int, period_s: float,
                 estimator: FleetEstimator | None, windy: list[Multirotor]) -> None:
        self.onboard = onboard
        self.plants = plants
        self.n_sub = n_sub
        self.period_s = period_s
        self.estimator = estimator
        self.windy = windy
        self.cycles = np.zeros(4 if HAS_CYCLE_COUNTER else 0, dtype=np.int64)
        self._kernels: tuple[Any, Any] | None = None
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
            return self.bound(table, traces)(trk.rows, table, trk.consts, ob.control,
                                             ob.stats, self.plants, self.n_sub,
                                             self.period_s, *traces, self.cycles,
                                             self.estimates())
        world_pre(trk.rows, ob.stats, self.plants)
        trk.step()
        return world_post(trk.rows, trk.consts, ob.control, ob.stats, self.plants,
                          self.n_sub, self.period_s, *traces)

    def bound(self, table: Any, traces: tuple[Any, ...]) -> Any:
        """:func:`world_tick` bound to these records (compiled on first use)."""
        if self._kernels is None or self._kernels[0] is not table:
            ob = self.onboard
            trk = ob.tracker
            self._kernels = (table, bind(world_tick, trk.rows, table, trk.consts, ob.control,
                                         ob.stats, self.plants, self.n_sub, self.period_s,
                                         *traces, self.cycles, self.estimates(peek=True)))
        return self._kernels[1]

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
