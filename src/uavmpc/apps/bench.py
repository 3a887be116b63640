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
from uavmpc.solvers import AxisQpSolver, BatchAxisSolver
from uavmpc.tracker import ClarabelSolver, MpcTracker, QpResult, TrackerConfig

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
        events.append(Event(tick, kind, (*map(float, target), float(rng.uniform(-np.pi, np.pi)))))
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
) -> Iterator[tuple[float, Any, np.ndarray]]:
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


def bench_world(sizes: tuple[int, ...] = (5, 20, 100), duration_s: float = 20.0,
                avoidance: bool = True, progress: Callable[[str], None] = print
                ) -> dict[str, Any]:
    """The per-core real-time factor of one random_walk world of N UAVs (full pipeline at
    100 Hz, plants at 500 Hz, avoidance on), for each N in ``sizes``, every tick one compiled
    call for all UAVs; the first size is flown again UAV by UAV through the per-object API
    (``World(batched=False)``: the same kernels) as the in-run reference, and the two flights
    are compared. The area grows with N so the density stays that of the protocol (5 UAVs in
    100 m × 100 m)."""
    from uavmpc.drivers.world import World
    from uavmpc.scenarios.random_walk import random_walk

    def fly(n: int, batched: bool) -> Any:
        area = 100.0 * math.sqrt(n / 5.0)
        world = World(random_walk(n, area_m=area, duration_s=duration_s, seed=1),
                      avoidance=avoidance, seed=1, batched=batched)
        return world.run(duration_s), area

    rows = []
    for batched in (True, False):  # compile and load the kernels first
        World(random_walk(2, duration_s=1.0), avoidance=avoidance, batched=batched).run(0.5)
    first = None
    for n in sizes:
        result, area = fly(n, True)
        first = first or result
        factor = result.duration_s / result.wall_s
        rows.append({"uavs": n, "path": "batched", "area_m": round(area, 1),
                     "realtime_factor": round(factor, 2),
                     "uav_seconds_per_wall_second": round(factor * n, 1),
                     "collisions": len(result.collisions)})
        progress(f"{n} UAVs, batched: {factor:.1f}× real time "
                 f"({factor * n:.0f} UAV-seconds per second)")
    objects, area = fly(sizes[0], False)
    factor = objects.duration_s / objects.wall_s
    identical = bool(np.array_equal(objects.positions_m, first.positions_m))
    rows.append({"uavs": sizes[0], "path": "per-object", "area_m": round(area, 1),
                 "realtime_factor": round(factor, 2),
                 "uav_seconds_per_wall_second": round(factor * sizes[0], 1),
                 "collisions": len(objects.collisions)})
    speedup = rows[0]["realtime_factor"] / factor
    progress(f"{sizes[0]} UAVs, per object (reference): {factor:.1f}× real time; batched is "
             f"{speedup:.1f}× faster, flights bit-identical: {identical}")
    return {"duration_s": duration_s, "avoidance": avoidance, "worlds": rows,
            "batched_speedup": round(speedup, 2), "identical_to_per_object": identical,
            "python": platform.python_version(), "machine": platform.machine()}


def bench_px4(duration_s: float = 20.0) -> dict[str, Any]:
    """``swap_through_static`` as three node processes, each flying its own stand-in PX4 over
    MAVLink/UDP on loopback, and (the reference, in the same run) the same three nodes flying
    their built-in plants: setpoint rate and jitter, estimate-to-setpoint latency (the age of
    the estimate a setpoint was computed from, when it is sent), CPU per node and per stand-in.
    Six processes share this machine's cores, as on a busy companion computer."""
    import tempfile

    from uavmpc import scenarios
    from uavmpc.drivers.swarm import run_swarm

    sc = scenarios.load("swap_through_static")
    result: dict[str, Any] = {"duration_s": duration_s, "cores": os.cpu_count()}
    with tempfile.TemporaryDirectory(prefix="uavmpc-bench-px4-") as tmp:
        for label, mavlink in (("built_in_plant", False), ("px4_stand_in", True)):
            s = run_swarm(sc, Path(tmp) / label, duration_s=duration_s, mavlink=mavlink)
            rows = {}
            for uav, u in s["uavs"].items():
                node = u["node"]
                row = {"node_cpu_percent": 100.0 * node["cpu_s"] / node["wall_s"],
                       "tick_period_p99_ms": node["period_p99_ms"],
                       "tracking_rmse_m": node["tracking_rmse_m"]}
                veh = node.get("vehicle") or {}
                if veh:
                    sitl = u.get("sitl", {})
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
            result[label] = {"collisions": len(s["collisions"]),
                             "min_distance_m": s["min_distance_m"], "uavs": rows}
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
    import zenoh

    from uavmpc import scenarios
    from uavmpc.comms.ros2 import Ros2Codec
    from uavmpc.drivers.swarm import free_ports, run_swarm

    (port,) = free_ports(1)
    cfg = zenoh.Config()
    cfg.insert_json5("mode", '"router"')
    cfg.insert_json5("listen/endpoints", f'["tcp/127.0.0.1:{port}"]')
    cfg.insert_json5("scouting/multicast/enabled", "false")
    router = zenoh.open(cfg)
    sc = scenarios.load("swap_through_static")
    result: dict[str, Any] = {"duration_s": duration_s, "cores": os.cpu_count()}
    try:
        with tempfile.TemporaryDirectory(prefix="uavmpc-bench-ros2-") as tmp:
            for label, endpoint in (("without_ros2", None), ("with_ros2", f"tcp/127.0.0.1:{port}")):
                s = run_swarm(sc, Path(tmp) / label, duration_s=duration_s, ros2=endpoint)
                result[label] = {uav: 100.0 * u["node"]["cpu_s"] / u["node"]["wall_s"]
                                 for uav, u in s["uavs"].items()}
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


def main_world(duration_s: float) -> int:
    print(json.dumps(bench_world(duration_s=duration_s)))
    return 0


def main_loop(duration_s: float, repeats: int, airframe: str) -> int:
    print(json.dumps(bench_loop(duration_s, repeats, airframe)))
    return 0
