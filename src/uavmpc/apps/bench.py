"""Benchmarks that print numbers and compare against a reference measured in the same run.

``uavmpc bench loop`` times the full single-UAV loop (see :func:`bench_loop`).

``uavmpc bench tracker`` flies the standalone :class:`~uavmpc.tracker.MpcTracker` over a
demanding reference (random far waypoints, 50 m steps, limits halved and restored) four times
on the same scenario:

1. with the configured solver (the compiled dual active-set solver, inside the compiled tick),
   timing every whole ``step()`` (all 4 axes: build, solve, simulate), after a warm-up flight
   of 500 ticks;
2. with DAQP through the solver contract, timed the same way (the solver it replaced);
3. with Clarabel, an independent interior-point solver at tight tolerance, timed the same way;
4. with our solver again (its one-problem adapter), re-solving every QP that reached the solver
   with Clarabel to compare the first inputs (``max_solution_diff``) and the objective values
   (``max_relative_objective_excess`` > 0 would mean our plan costs more than Clarabel's).

``uavmpc bench world`` flies random_walk worlds of 5 to 1000 UAVs, each in a fresh process, and
fits how the cost grows with N (see :func:`bench_world`).

The last line of output is one JSON object.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import platform
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np

from uavmpc.reference import Reference
from uavmpc.scenarios.run import RunSpec
from uavmpc.solvers import AxisQpSolver, BatchAxisSolver
from uavmpc.tracker import ClarabelSolver, MpcTracker, QpResult, TrackerConfig, TrackerOutput

#: A tick whose state lies outside the limits in force by more than this is a violation.
VIOLATION_TOL = 1e-6


@dataclasses.dataclass(frozen=True)
class Event:
    """Something the benchmark does to the tracker at a given tick."""

    tick: int
    kind: str  # "goto", "step", "halve", "restore"
    point: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0)


def demanding_events(ticks: int, seed: int) -> list[Event]:
    """Random far waypoints and 50 m steps every 1.5–6 s, limits halved then restored."""
    rng = np.random.default_rng(seed)
    events: list[Event] = []
    tick, here = 0, np.zeros(3)
    while tick < ticks:
        if rng.random() < 0.5:
            target = rng.uniform([-200, -200, 2], [200, 200, 60])
            kind = "goto"
        else:
            direction = np.zeros(3)
            direction[rng.integers(0, 2)] = rng.choice([-1.0, 1.0])
            target = here + 50.0 * direction
            kind = "step"
        events.append(Event(tick, kind, (float(target[0]), float(target[1]), float(target[2]),
                                         float(rng.uniform(-np.pi, np.pi)))))
        here = target
        tick += int(rng.integers(150, 600))
    limit_tick = 0
    while limit_tick < ticks:
        limit_tick += int(rng.integers(200, 700))
        events.append(Event(limit_tick, "halve"))
        limit_tick += int(rng.integers(100, 400))
        events.append(Event(limit_tick, "restore"))
    return sorted(events, key=lambda e: e.tick)


class _Recording:
    """Wraps an axis solver and re-solves every QP it sees with a reference solver."""

    def __init__(self, inner: AxisQpSolver, reference: ClarabelSolver, hessian: np.ndarray
                 ) -> None:
        self.name = inner.name
        self._inner, self._reference, self._hessian = inner, reference, hessian
        self.max_diff = 0.0
        self.max_objective_excess = -np.inf
        self.compared = 0
        self.reference_failures = 0
        self.worst: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None

    @property
    def polished(self) -> int:
        return self._reference.polished

    def solve(self, f: np.ndarray, lower: np.ndarray, upper: np.ndarray) -> QpResult:
        result = self._inner.solve(f, lower, upper)
        ref = self._reference.solve(f, lower, upper)
        if result.inputs is not None and ref.inputs is not None:
            diff = abs(float(result.inputs[0] - ref.inputs[0]))
            if diff > self.max_diff:
                self.max_diff, self.worst = diff, (f.copy(), lower.copy(), upper.copy())
            # Where the two differ, whose plan is better? (> 0: ours costs more than the reference)
            h = self._hessian
            ours = 0.5 * result.inputs @ h @ result.inputs + f @ result.inputs
            theirs = 0.5 * ref.inputs @ h @ ref.inputs + f @ ref.inputs
            excess = (ours - theirs) / max(1.0, abs(theirs))
            self.max_objective_excess = max(self.max_objective_excess, float(excess))
            self.compared += 1
        elif ref.inputs is None:
            self.reference_failures += 1
        return result


def _fly(
    tracker: MpcTracker, events: list[Event], ticks: int, timed: bool = True
) -> Iterator[tuple[float, TrackerOutput, np.ndarray]]:
    nominal = tracker.config.limits
    pending = iter(events)
    nxt = next(pending, None)
    for tick in range(ticks):
        while nxt is not None and nxt.tick <= tick:
            if nxt.kind in ("goto", "step"):
                tracker.set_reference(Reference.goto(*nxt.point, start_s=tracker.time_s))
            elif nxt.kind == "halve":
                tracker.set_limits(nominal.scaled(0.5, 0.5))
            else:
                tracker.set_limits(nominal)
            nxt = next(pending, None)
        before = tracker.state
        t0 = time.perf_counter()
        out = tracker.step()
        yield (time.perf_counter() - t0 if timed else 0.0), out, before


def _excess(tracker: MpcTracker, s: np.ndarray) -> tuple[float, float]:
    """(how far state s lies outside the limits in force, the same for w = v + τa)."""
    lim = tracker.limits
    v_lo, v_hi = lim.velocity_bounds()
    a_lo, a_hi = lim.acceleration_bounds()
    w = s[:, 1] + tracker.config.tau_s * s[:, 2]
    va = max(float(np.max(s[:, 1] - v_hi)), float(np.max(v_lo - s[:, 1])),
             float(np.max(s[:, 2] - a_hi)), float(np.max(a_lo - s[:, 2])), 0.0)
    we = max(float(np.max(w - v_hi)), float(np.max(v_lo - w)), 0.0)
    return va, we


def bench_tracker(
    ticks: int = 3000, seed: int = 1, progress: Callable[[str], None] = print
) -> dict[str, Any]:
    """Run the tracker benchmark; returns the result dictionary (see module docstring)."""
    if ticks < 1:
        raise ValueError(f"ticks must be ≥ 1, got {ticks}")
    config = TrackerConfig.from_toml()
    events = demanding_events(ticks, seed)

    progress(f"tracker benchmark: {ticks} ticks, {len(events)} events, seed {seed}")
    # Warm up (kernels loaded, caches and predictors warm) on a throw-away flight of the same
    # events, so that every timed run below starts in the same state.
    for warm_config in (config, dataclasses.replace(config, solver="daqp")):
        warm = MpcTracker(warm_config, position_m=(0.0, 0.0, 10.0))
        for _ in _fly(warm, events, min(ticks, 500), timed=False):
            pass
    tracker = MpcTracker(config, position_m=(0.0, 0.0, 10.0))
    step_times, qp_ticks = [], 0
    violations, max_violation = 0, 0.0
    for dt, out, before in _fly(tracker, events, ticks):
        step_times.append(dt)
        qp_ticks += out.qp_solves > 0
        va, we = _excess(tracker, tracker.state)
        # Outside the box is allowed only while braking back into it after a tightening, and
        # then w = v + τa (which integrates the input) must move towards the box every tick.
        bad = va if not out.braking else max(0.0, we - _excess(tracker, before)[1])
        if bad > VIOLATION_TOL:
            violations += 1
        max_violation = max(max_violation, bad)
    fallbacks = tracker.fallback_count

    progress("reference runs: the same flight with DAQP, then Clarabel, as the QP solver")
    daqp_tracker = MpcTracker(dataclasses.replace(config, solver="daqp"),
                              position_m=(0.0, 0.0, 10.0))
    daqp_times = [dt for dt, _, _ in _fly(daqp_tracker, events, ticks)]
    ref_config = dataclasses.replace(config, solver="clarabel")
    ref_tracker = MpcTracker(ref_config, position_m=(0.0, 0.0, 10.0))
    ref_times = [dt for dt, _, _ in _fly(ref_tracker, events, ticks)]

    progress("comparison run: every QP solved by both solvers")
    model_tracker = MpcTracker(config, position_m=(0.0, 0.0, 10.0))
    model = model_tracker.model
    recorders = [_Recording(BatchAxisSolver(model, config.iter_limit), ClarabelSolver(model),
                            model.hessian) for _ in range(4)]
    cmp_tracker = MpcTracker(config, position_m=(0.0, 0.0, 10.0), solvers=list(recorders))
    for _ in _fly(cmp_tracker, events, ticks, timed=False):
        pass

    us = np.array(step_times) * 1e6
    return {
        "ticks": ticks,
        "seed": seed,
        "solver": config.solver,
        "step_median_us": round(float(np.median(us)), 2),
        "step_p99_us": round(float(np.percentile(us, 99)), 2),
        "ticks_with_qp": int(qp_ticks),
        "limit_violations": int(violations),
        "max_violation": float(max_violation),
        "fallbacks": int(fallbacks),
        "daqp_step_median_us": round(float(np.median(daqp_times) * 1e6), 2),
        "reference_solver": "clarabel",
        "reference_step_median_us": round(float(np.median(ref_times) * 1e6), 2),
        "max_solution_diff": float(max(r.max_diff for r in recorders)),
        "max_relative_objective_excess": float(max(r.max_objective_excess for r in recorders)),
        "qps_compared": int(sum(r.compared for r in recorders)),
        "reference_failures": int(sum(r.reference_failures for r in recorders)),
        "reference_polished": int(sum(r.polished for r in recorders)),
        "python": platform.python_version(),
        "machine": platform.machine(),
    }


def bench_loop(duration_s: float = 60.0, repeats: int = 3, airframe: str = "f550",
               progress: Callable[[str], None] = print) -> dict[str, Any]:
    """The full single-UAV loop (tracker + SE(3) + attitude + plant) on the demanding reference.

    ``realtime_factor`` is simulated time over wall time of the whole loop (median of
    ``repeats`` runs, one core); ``stage_us`` splits one tick by stage in a separate, timed run.
    """
    from uavmpc.drivers.flight import demanding_reference, fly, summarize
    from uavmpc.onboard import OnboardStack
    from uavmpc.plant import Airframe
    from uavmpc.plant.multirotor import Multirotor

    af = Airframe.named(airframe)
    ref = demanding_reference()
    fly(af, ref, 1.0)  # load the compiled kernels (numba cache) before timing
    warm = OnboardStack(af, position_m=tuple(ref.points[0, :3]))  # and the split's own path
    warm.set_mission(ref)
    warm.controller.update(warm.tracker.step().command, Multirotor(af).state())
    factors, rmse = [], []
    for i in range(repeats):
        s = summarize(fly(af, ref, duration_s), af)
        factors.append(s["realtime_factor"])
        rmse.append(s["tracking_rmse_m"])
        progress(f"run {i + 1}/{repeats}: {s['realtime_factor']:.1f}× real time")
    start = tuple(ref.points[0, :3])
    plant = Multirotor(af, position_m=start, rotors_at_hover=True)
    stack = OnboardStack(af, position_m=start)
    stack.set_mission(ref)
    ticks = round(duration_s / stack.period_s)
    spent = np.zeros(3)
    state = plant.state()
    for _ in range(ticks):
        t0 = time.perf_counter()
        out = stack.tracker.step()
        t1 = time.perf_counter()
        target = stack.controller.update(out.command, state, stack.period_s)
        t2 = time.perf_counter()
        state = plant.step(target, stack.period_s)
        t3 = time.perf_counter()
        spent += (t1 - t0, t2 - t1, t3 - t2)
    per_tick = spent / ticks * 1e6
    return {
        "airframe": airframe,
        "duration_s": duration_s,
        "repeats": repeats,
        "realtime_factor": round(float(np.median(factors)), 1),
        "realtime_factors": [round(f, 1) for f in factors],
        "tracking_rmse_m": round(float(np.median(rmse)), 4),
        "stage_us": {"tracker": round(float(per_tick[0]), 1),
                     "se3": round(float(per_tick[1]), 1),
                     "attitude_and_plant": round(float(per_tick[2]), 1)},
        "python": platform.python_version(),
        "machine": platform.machine(),
    }


#: ``bench world``'s default sizes (UAVs per world).
WORLD_SIZES: tuple[int, ...] = (5, 20, 100, 300, 1000)
#: Worlds of at least this many UAVs fly ``duration_large_s`` (they are the slow ones).
WORLD_LARGE_UAVS = 300
#: The growth exponent is fitted over the sizes from this one up: below it the fixed cost per
#: tick (Python overhead of one compiled call) dominates and would flatten the slope.
WORLD_FIT_FROM_UAVS = 20


def _maxrss_mib() -> float:
    import resource
    import sys

    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return peak / 2**20 if sys.platform == "darwin" else peak / 2**10  # bytes there, KiB here


def _world_child(n: int, duration_s: float, avoidance: bool, batched: bool,
                 threads: int = 1) -> dict[str, Any]:
    """Fly one random_walk world of ``n`` UAVs in this (fresh) process on ``threads`` threads;
    see :func:`bench_world`.

    Only the public ``World(RunSpec(...))`` and ``run()`` are used, so the numbers stay
    comparable while the world's internals change."""
    import hashlib
    import resource

    from uavmpc.drivers.world import World
    from uavmpc.jit import set_threads
    from uavmpc.scenarios.random_walk import random_walk

    set_threads(threads)
    # Load the on-disk kernels (seconds) on a throw-away flight, so the baseline holds them.
    World(RunSpec(random_walk(2, duration_s=1.0), avoidance=avoidance), batched=batched).run(0.5)
    baseline = _maxrss_mib()
    area = 100.0 * math.sqrt(n / 5.0)  # the protocol's density: 5 UAVs per 100 m × 100 m
    world = World(RunSpec(random_walk(n, area_m=area, duration_s=duration_s, seed=1),
                          avoidance=avoidance, seed=1), batched=batched)
    # run() also loads its tick before its own clock starts: CPU is set against this clock.
    cpu0, t0 = resource.getrusage(resource.RUSAGE_SELF), time.perf_counter()
    result = world.run(duration_s)
    cpu1, t1 = resource.getrusage(resource.RUSAGE_SELF), time.perf_counter()
    peak = _maxrss_mib()
    digest = hashlib.sha256(np.ascontiguousarray(result.positions_m).tobytes())
    digest.update(np.ascontiguousarray(result.z_offset_m).tobytes())
    timing = result.timing
    return {
        "uavs": n, "path": "batched" if batched else "per-object", "area_m": area,
        "threads": threads,
        "duration_s": float(result.duration_s), "wall_s": float(result.wall_s),
        "cpu_s": (cpu1.ru_utime + cpu1.ru_stime) - (cpu0.ru_utime + cpu0.ru_stime),
        "run_wall_s": t1 - t0,
        "collisions": len(result.collisions),
        "min_distance_m": float(np.min(result.min_distance_m)) if n > 1 else None,
        "baseline_rss_mib": baseline, "peak_rss_mib": peak, "flight_digest": digest.hexdigest(),
        "wall_s_by_phase": timing.wall_s_by_phase if timing else None,
        "compiled_us_per_uav_tick": timing.compiled_us_per_uav_tick if timing else None,
        "threads_wait_us_per_uav_tick": (timing.threads_wait_us_per_uav_tick if timing
                                         else None),
        "ticks_per_s": 1.0 / world.period_s,
    }


def _spawn_world(n: int, duration_s: float, avoidance: bool, batched: bool,
                 threads: int = 1) -> dict[str, Any]:
    """:func:`_world_child` in a fresh interpreter: ru_maxrss is a high-water mark of the whole
    process, so each size needs its own process to measure its own peak."""
    import subprocess
    import sys

    code = ("import json, sys; from uavmpc.apps.bench import _world_child; "
            "print(json.dumps(_world_child(*json.loads(sys.argv[1]))))")
    # Exactly ``threads`` threads for the world's tick, one for every other pool the child
    # might start (BLAS): the factor is that of the threads asked for.
    env = {**os.environ, **{k: "1" for k in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS",
                                              "MKL_NUM_THREADS")},
           "NUMBA_NUM_THREADS": str(threads)}
    proc = subprocess.run([sys.executable, "-c", code,
                           json.dumps([n, duration_s, avoidance, batched, threads])],
                          capture_output=True, text=True, env=env, check=False)
    if proc.returncode != 0:
        raise RuntimeError(f"bench world: the {n}-UAV child failed ({proc.returncode}):\n"
                           f"{proc.stderr[-2000:]}")
    row: dict[str, Any] = json.loads(proc.stdout.strip().splitlines()[-1])
    return row


def _sig(x: float, digits: int = 4) -> float:
    # Significant digits, not decimals: the factors span 0.01× to 100× over the sizes.
    return float(f"{x:.{digits}g}")


def _world_row(child: dict[str, Any]) -> dict[str, Any]:
    n, sim, wall = child["uavs"], child["duration_s"], child["wall_s"]
    factor = sim / wall
    return {
        "uavs": n, "path": child["path"], "threads": child["threads"],
        "area_m": round(child["area_m"], 1), "duration_s": sim, "wall_s": _sig(wall),
        "realtime_factor": _sig(factor),
        "uav_seconds_per_wall_second": round(factor * n, 1),
        "us_per_uav_second": _sig(wall * 1e6 / (sim * n)),
        "wall_s_per_simulated_s": _sig(wall / sim),
        "cpu_per_wall": round(child["cpu_s"] / child["run_wall_s"], 3),
        "baseline_rss_mib": round(child["baseline_rss_mib"], 1),
        "peak_rss_mib": round(child["peak_rss_mib"], 1),
        "flight_rss_mib": round(child["peak_rss_mib"] - child["baseline_rss_mib"], 1),
        "collisions": child["collisions"],
        "min_distance_m": (None if child["min_distance_m"] is None
                           else round(child["min_distance_m"], 3)),
        # The share of the flight's wall time in the compiled tick (the rest: Python around
        # it, receiving, planning and broadcasting at 10 and 2 Hz).
        "compiled_share": (None if not child.get("wall_s_by_phase")
                           else round(child["wall_s_by_phase"]["compiled_tick"] / wall, 3)),
        # The wall time of each phase of a tick (the compiled call, and the Python around it:
        # receiving and planning, broadcasting), per tick [µs].
        "us_per_tick_by_phase": (None if not child.get("wall_s_by_phase") else {
            k: _sig(v * 1e6 / (child["ticks_per_s"] * sim))
            for k, v in child["wall_s_by_phase"].items()}),
        # Inside the compiled tick, per UAV and tick (CPU time, summed over the threads): the
        # tracker's stages, the control, the plant, the traces; and the real-time factor the
        # world would have if nothing but the compiled tick ran on one thread.
        **_floor(child),
        # The threads idle at the end of the compiled tick, waiting for its slowest block
        # (CPU µs per UAV-tick, summed over the threads; 0 on one thread).
        "threads_wait_us_per_uav_tick": child.get("threads_wait_us_per_uav_tick"),
    }


def _floor(child: dict[str, Any]) -> dict[str, Any]:
    stages = child.get("compiled_us_per_uav_tick")
    if not stages:  # no cycle counter on this machine, or a per-object run
        return {"compiled_us_per_uav_tick": None, "compiled_only_realtime_factor": None}
    per_tick_s = sum(stages.values()) * 1e-6 * child["uavs"]
    return {"compiled_us_per_uav_tick": stages,
            "compiled_only_realtime_factor": _sig(1.0 / (per_tick_s * child["ticks_per_s"]))}


def _growth(rows: list[dict[str, Any]]) -> dict[str, Any]:
    """α of cost ∝ N^α by least squares on log–log, and the cost per UAV-second at the largest
    size over that at the first fitted one (20 UAVs by default; 1.0 means linear scaling)."""
    by_n = {r["uavs"]: r for r in rows}
    fit = sorted(n for n in by_n if n >= WORLD_FIT_FROM_UAVS)
    if len(fit) < 2:  # e.g. a quick run of small sizes only: fit what there is
        fit = sorted(by_n)
    if len(fit) < 2:
        return {"fit_uavs": fit, "growth_exponent": None, "ratio_reference_uavs": None,
                "us_per_uav_second_ratio": None}
    x = np.log(np.array(fit, float))
    y = np.log([by_n[n]["wall_s_per_simulated_s"] for n in fit])
    alpha = float(np.polyfit(x, y, 1)[0])
    ref, top = fit[0], fit[-1]
    ratio = by_n[top]["us_per_uav_second"] / by_n[ref]["us_per_uav_second"]
    return {"fit_uavs": fit, "growth_exponent": round(alpha, 3), "ratio_reference_uavs": ref,
            "ratio_largest_uavs": top, "us_per_uav_second_ratio": _sig(ratio)}


def _check_world_args(sizes: tuple[int, ...], threads: tuple[int, ...], duration_s: float,
                      duration_large_s: float, repeats: int = 1) -> None:
    from uavmpc.config import ConfigError  # a ValueError the CLI reports as a message
    from uavmpc.jit import available_threads

    if not sizes or any(isinstance(n, bool) or not isinstance(n, int) or not 1 <= n <= 1000
                        for n in sizes):
        raise ConfigError(f"bench world: sizes must be integers in [1, 1000], got {sizes!r}")
    if len(set(sizes)) != len(sizes):
        raise ConfigError(f"bench world: each size once, got {sizes!r}")
    top = available_threads()
    if not threads or len(set(threads)) != len(threads) or any(
            isinstance(t, bool) or not isinstance(t, int) or not 1 <= t <= top for t in threads):
        raise ConfigError(f"bench world: threads must be distinct integers from 1 to {top} "
                          f"(this machine's cores), got {threads!r}")
    for name, v in (("duration_s", duration_s), ("duration_large_s", duration_large_s)):
        if not (math.isfinite(v) and v > 0):
            raise ConfigError(f"bench world: {name} must be > 0, got {v}")
    if isinstance(repeats, bool) or not isinstance(repeats, int) or not 1 <= repeats <= 20:
        raise ConfigError(f"bench world: repeats must be an integer from 1 to 20, got "
                          f"{repeats!r}")


def _print_world_row(row: dict[str, Any], progress: Callable[[str], None],
                     profile: bool) -> None:
    closest = "-" if row["min_distance_m"] is None else f"{row['min_distance_m']:.2f} m"
    spread = (f" (fastest of {row['repeats']}, slowest {row['slowest_over_fastest']:.2f}× "
              "its time)" if row.get("repeats", 1) > 1 else "")
    progress(f"{row['uavs']:5d} UAVs, {row['threads']} thread(s): "
             f"{row['realtime_factor']:8.2f}× real time{spread}, "
             f"{row['us_per_uav_second']:8.1f} µs per UAV-second, "
             f"RSS {row['peak_rss_mib']:.0f} MiB (+{row['flight_rss_mib']:.0f} over "
             f"{row['baseline_rss_mib']:.0f}), {100 * row['compiled_share']:.0f} % in the "
             f"compiled tick, {row['collisions']} collision(s), closest {closest}")
    st = row["compiled_us_per_uav_tick"]
    if profile and st:
        stages = " + ".join(f"{k} {v:.2f}" for k, v in st.items())
        wait = row.get("threads_wait_us_per_uav_tick")
        idle = (f"; threads waiting for the slowest block {wait:.2f}"
                if wait and row["threads"] > 1 else "")
        progress(f"{'':5s}       compiled tick, CPU µs per UAV-tick: {stages} = "
                 f"{sum(st.values()):.2f} ({row['compiled_only_realtime_factor']:.1f}× real "
                 f"time at most on one thread){idle}")
    if profile and row["us_per_tick_by_phase"]:
        ph = row["us_per_tick_by_phase"]
        progress(f"{'':5s}       wall µs per tick: " + ", ".join(
            f"{k} {v:.0f}" for k, v in ph.items()))


def _fastest(n: int, threads: int, flights: list[dict[str, Any]]
             ) -> tuple[dict[str, Any], dict[str, Any]]:
    """The row of the fastest of the repeated ``flights`` of ``n`` UAVs on ``threads``
    thread(s) (each must have flown the same flight), and its child's report."""
    child = min(flights, key=lambda c: c["wall_s"])
    row = _world_row(child)
    walls = [c["wall_s"] for c in flights]
    row["repeats"] = len(flights)
    row["slowest_over_fastest"] = _sig(max(walls) / min(walls))
    if len({c["flight_digest"] for c in flights}) != 1:
        raise RuntimeError(f"bench world: {n} UAVs on {threads} thread(s) flew different "
                           "flights in its repeats")
    return row, child


def _per_object_reference(fast: dict[str, Any], duration_s: float, avoidance: bool,
                          digest: str, progress: Callable[[str], None]
                          ) -> tuple[dict[str, Any], float, bool]:
    """The in-run reference: the world of ``fast``'s size flown UAV by UAV on one thread;
    its row, how many times faster ``fast`` (batched) flew, and whether its flight is bit for
    bit ``digest``."""
    n = fast["uavs"]
    child = _spawn_world(n, duration_s, avoidance, False, 1)
    ref = _world_row(child)
    identical = child["flight_digest"] == digest
    speedup = fast["realtime_factor"] / ref["realtime_factor"]
    progress(f"{n:5d} UAVs, per object (reference): {ref['realtime_factor']:.2f}× real "
             f"time; batched on {fast['threads']} thread(s) is {speedup:.1f}× faster, flights "
             f"bit-identical: {identical}")
    return ref, speedup, identical


def bench_world(sizes: tuple[int, ...] = WORLD_SIZES, duration_s: float = 20.0,
                duration_large_s: float = 10.0, avoidance: bool = True,
                threads: tuple[int, ...] | None = None, profile: bool = False,
                progress: Callable[[str], None] = print, repeats: int = 1) -> dict[str, Any]:
    """How the world scales with N and with threads: one random_walk world of N UAVs (full
    pipeline at 100 Hz, plants at 500 Hz, avoidance on) for each N in ``sizes`` and each
    thread count in ``threads`` (default: 1 and every core), every tick one compiled call
    for all UAVs, each in a fresh process (warmed up, only ``World.run`` timed).

    Per size and thread count: the real-time factor, the cost per UAV-second (wall µs per
    simulated UAV-second), the peak RSS of the child after the flight and its baseline after
    imports and warm-up, collisions and the closest approach, the compiled tick's stages per
    UAV-tick and the wall time of each phase per tick (printed with ``profile``). Per size:
    each thread count's speedup over the first and whether its flight is bit-identical to the
    first's. Over the sizes ≥ 20 at the first thread count: the exponent α of the cost per
    simulated second ∝ N^α and the cost per UAV-second at the largest size over that at 20
    UAVs. The smallest size is flown again UAV by UAV (``World(batched=False)``: the same
    kernels, one thread) as the in-run reference, and the flights are compared bit for bit.

    With ``repeats`` > 1 each size's flights are flown that many times, the thread counts
    taking turns (1, 2, 1, 2, …: a slow spell of a shared machine falls on both), and each
    thread count's fastest flight is the one reported (every repeat must fly the same flight);
    ``slowest_over_fastest`` says how far apart its flights were.

    Worlds of ≥ :data:`WORLD_LARGE_UAVS` UAVs fly ``min(duration_s, duration_large_s)``; the
    area grows with N so the density stays that of the protocol (5 UAVs in 100 m × 100 m)."""
    from uavmpc.jit import available_threads

    sizes = tuple(sizes)
    threads = tuple(sorted({1, available_threads()})) if threads is None else tuple(threads)
    _check_world_args(sizes, threads, duration_s, duration_large_s, repeats)

    def duration(n: int) -> float:
        return duration_s if n < WORLD_LARGE_UAVS else min(duration_s, duration_large_s)

    progress(f"world benchmark: {', '.join(map(str, sizes))} UAVs on "
             f"{', '.join(map(str, threads))} thread(s), {duration_s:g} s "
             f"({min(duration_s, duration_large_s):g} s from {WORLD_LARGE_UAVS} UAVs), "
             f"avoidance {'on' if avoidance else 'off'}, one fresh process per flight"
             + (f", the fastest of {repeats} flights each" if repeats > 1 else ""))
    rows, digests, scaling = [], {}, []
    for n in sizes:
        flights: dict[int, list[dict[str, Any]]] = {t: [] for t in threads}
        for _ in range(repeats):
            for t in threads:
                flights[t].append(_spawn_world(n, duration(n), avoidance, True, t))
        first: dict[str, Any] | None = None
        for t in threads:
            row, child = _fastest(n, t, flights[t])
            rows.append(row)
            _print_world_row(row, progress, profile)
            if first is None:
                first, digests[n] = row, child["flight_digest"]
                continue
            speedup = row["realtime_factor"] / first["realtime_factor"]
            same = child["flight_digest"] == digests[n]
            scaling.append({"uavs": n, "threads": t, "reference_threads": first["threads"],
                            "speedup": _sig(speedup), "identical": same})
            progress(f"{'':5s}       {t} threads over {first['threads']}: {speedup:.2f}× "
                     f"faster, flights bit-identical: {same}")
    growth = _growth([r for r in rows if r["threads"] == threads[0]])
    smallest = min(sizes)
    fast = next(r for r in rows if r["uavs"] == smallest and r["threads"] == threads[0])
    ref, speedup, identical = _per_object_reference(fast, duration(smallest), avoidance,
                                                    digests[smallest], progress)
    if growth["growth_exponent"] is not None:
        progress(f"cost per simulated second ∝ N^{growth['growth_exponent']:.2f} over "
                 f"{growth['fit_uavs']} UAVs; per UAV-second, {growth['ratio_largest_uavs']} "
                 f"UAVs cost {growth['us_per_uav_second_ratio']:.2f}× what "
                 f"{growth['ratio_reference_uavs']} do")
    return {"duration_s": duration_s, "duration_large_s": duration_large_s,
            "large_from_uavs": WORLD_LARGE_UAVS, "avoidance": avoidance, "threads": threads,
            "repeats": repeats,
            "worlds": rows, "thread_scaling": scaling, "reference": ref, **growth,
            "batched_speedup": round(speedup, 2), "identical_to_per_object": identical,
            "identical_across_threads": all(r["identical"] for r in scaling),
            "python": platform.python_version(), "machine": platform.machine(),
            "cores": os.cpu_count()}


def bench_px4(duration_s: float = 20.0) -> dict[str, Any]:
    """``swap_through_static`` as three node processes, each flying its own stand-in PX4 over
    MAVLink/UDP on loopback, and (the reference, in the same run) the same three nodes flying
    their built-in plants: setpoint rate and jitter, estimate-to-setpoint latency (the age of
    the estimate a setpoint was computed from, when it is sent), CPU per node and per stand-in.
    Six processes share this machine's cores, as on a busy companion computer."""
    import tempfile

    from uavmpc import scenarios
    from uavmpc.drivers.swarm import run_swarm
    from uavmpc.scenarios.run import RunSpec

    sc = scenarios.load("swap_through_static")
    result: dict[str, Any] = {"duration_s": duration_s, "cores": os.cpu_count()}
    with tempfile.TemporaryDirectory(prefix="uavmpc-bench-px4-") as tmp:
        for label, mavlink in (("built_in_plant", False), ("px4_stand_in", True)):
            s = run_swarm(RunSpec(sc, duration_s=duration_s), Path(tmp) / label,
                          mavlink=mavlink)
            rows = {}
            for uav, u in s.uavs.items():
                node = u.details["node"]
                row = {"node_cpu_percent": 100.0 * node["cpu_s"] / node["wall_s"],
                       "tick_period_p99_ms": node["period_p99_ms"],
                       "tracking_rmse_m": node["tracking_rmse_m"]}
                veh = node.get("vehicle") or {}
                if veh:
                    sitl = u.details.get("sitl", {})
                    row.update({
                        "phase": veh["phase"],
                        "setpoint_rate_hz": 1e3 / veh["setpoint_period_p50_ms"],
                        "setpoint_period_p50_ms": veh["setpoint_period_p50_ms"],
                        "setpoint_period_p99_ms": veh["setpoint_period_p99_ms"],
                        "setpoint_period_max_ms": veh["setpoint_period_max_ms"],
                        "estimate_age_p50_ms": veh["estimate_age_p50_ms"],
                        "estimate_age_p99_ms": veh["estimate_age_p99_ms"],
                        "stand_in_cpu_percent": 100.0 * sitl.get("cpu_s", float("nan"))
                        / max(sitl.get("wall_s", float("nan")), 1e-9)})
                rows[uav] = row
            result[label] = {"collisions": len(s.collisions),
                             "min_distance_m": s.min_distance_m, "uavs": rows}
    for label in ("built_in_plant", "px4_stand_in"):
        r = result[label]
        print(f"{label}: {r['collisions']} collision(s), closest {r['min_distance_m']:.2f} m")
        for uav, row in r["uavs"].items():
            text = ", ".join(f"{k} {v:.2f}" if isinstance(v, float) else f"{k} {v}"
                             for k, v in row.items())
            print(f"  {uav}: {text}")
    return result


def bench_ros2(duration_s: float = 20.0) -> dict[str, Any]:
    """``swap_through_static`` as three node processes, each also on a ROS 2 graph through a
    Zenoh router (in this process, as ``rmw_zenohd`` would be), against the same nodes without
    ROS 2 (the reference, same run): CPU per node, messages and bytes put, and the size of each
    message (CDR payload; rmw_zenoh adds a 33-byte attachment)."""
    import tempfile

    import numpy as np

    from uavmpc import scenarios
    from uavmpc.comms.ros2 import Ros2Codec
    from uavmpc.comms.zenoh_link import loopback_router
    from uavmpc.drivers.swarm import free_ports, run_swarm
    from uavmpc.scenarios.run import RunSpec

    (port,) = free_ports(1)
    router = loopback_router(port)
    sc = scenarios.load("swap_through_static")
    result: dict[str, Any] = {"duration_s": duration_s, "cores": os.cpu_count()}
    try:
        with tempfile.TemporaryDirectory(prefix="uavmpc-bench-ros2-") as tmp:
            for label, endpoint in (("without_ros2", None), ("with_ros2", f"tcp/127.0.0.1:{port}")):
                s = run_swarm(RunSpec(sc, duration_s=duration_s), Path(tmp) / label,
                              ros2=endpoint)
                result[label] = {uav: 100.0 * u.details["node"]["cpu_s"]
                                 / u.details["node"]["wall_s"] for uav, u in s.uavs.items()}
    finally:
        router.close()
    codec = Ros2Codec()
    p, q = np.array([1.0, 2.0, 3.0]), np.array([1.0, 0.0, 0.0, 0.0])
    times = 100.0 + 0.2 * np.arange(40)
    result["message_bytes"] = {
        "pose (PoseStamped)": len(codec.pose_stamped(0.0, p, q)),
        "odom (Odometry)": len(codec.odometry(0.0, "uav1/base_link", p, p, q, p)),
        "prediction (Path, 40 poses)": len(codec.path(0.0, times, np.tile(p, (40, 1)),
                                                      np.zeros(40))),
        "avoidance (AvoidanceStatus, yielding to one)": len(
            codec.avoidance_status(0.0, True, 3.0, ["uav1"])),
        "attachment": 33}
    for label in ("without_ros2", "with_ros2"):
        cpu = result[label]
        print(f"{label}: node CPU " + ", ".join(f"{u} {v:.1f} %" for u, v in cpu.items()))
    for name, size in result["message_bytes"].items():
        print(f"  {name}: {size} B")
    return result


def main_ros2(duration_s: float) -> int:
    print(json.dumps(bench_ros2(duration_s)))
    return 0


def main_px4(duration_s: float) -> int:
    print(json.dumps(bench_px4(duration_s)))
    return 0


def main_tracker(ticks: int, seed: int) -> int:
    result = bench_tracker(ticks, seed)
    print(json.dumps(result))
    return 0


def main_world(duration_s: float, sizes: str | None = None,
               duration_large_s: float | None = None, threads: str | None = None,
               profile: bool = False, repeats: int = 1) -> int:
    from uavmpc.config import ConfigError

    def ints(text: str | None, name: str) -> tuple[int, ...] | None:
        try:
            return None if text is None else tuple(int(v) for v in text.split(","))
        except ValueError:
            raise ConfigError(f"bench world: --{name} must be integers like 1,2, got "
                              f"{text!r}") from None

    print(json.dumps(bench_world(ints(sizes, "sizes") or WORLD_SIZES, duration_s,
                                 10.0 if duration_large_s is None else duration_large_s,
                                 threads=ints(threads, "threads"), profile=profile,
                                 repeats=repeats)))
    return 0


def main_loop(duration_s: float, repeats: int, airframe: str) -> int:
    print(json.dumps(bench_loop(duration_s, repeats, airframe)))
    return 0
