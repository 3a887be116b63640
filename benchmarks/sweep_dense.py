"""The dense and adversarial built-in scenarios over many seeds, with and without loss.

``python benchmarks/sweep_dense.py [--seeds 10] [--links 0,0.3:0.2] [--scenarios a,b]
[--ceiling 30] [--workers 2]`` flies each scenario (default: antipodal_8, antipodal_12,
noncooperative_crossing; ``antipodal_<N>``: any N, from
:func:`uavmpc.scenarios.dense.antipodal`, ``antipodal_<N>_reversed`` with its priorities
reversed, under a geofence whose ceiling is ``--ceiling`` m
when given) for seeds 0..N−1 on each link (``LOSS[:LATENCY_S]``: the scenario's link with that
loss probability and, when given, that latency), with avoidance, and prints one row per
scenario × link, then every collision and every missed goal precisely, and, last, one JSON
object.

The vertical stack swaps of docs/safety.md (2 × 3 and 2 × 5, 3 seeds, clean and lossy):

    python benchmarks/sweep_dense.py --seeds 3 --links 0,0.3:0.2 --workers 2 \
        --scenarios vertical_3,vertical_5

A grid of 16 shuffled (``grid_<N>``: each UAV flies to another grid point, 10 m apart,
the assignment drawn from the run's seed; a 25 m ceiling unless ``--ceiling``):

    python benchmarks/sweep_dense.py --seeds 3 --links 0,0.3:0.2 --workers 2 \
        --scenarios grid_16

The antipodal swaps of docs/safety.md (N = 8 … 32 under a 30 m ceiling):


    python benchmarks/sweep_dense.py --ceiling 30 --links 0,0.3:0.2 --workers 2 \
        --scenarios antipodal_8,antipodal_12,antipodal_16,antipodal_24,antipodal_32

24 through one point with the priorities reversed, under a 40 m ceiling:

    python benchmarks/sweep_dense.py --seeds 3 --ceiling 40 --links 0,0.3:0.2 --workers 2 \
        --scenarios antipodal_24_reversed

Columns: runs with a collision; closest approach between any two UAVs (3-D, m) over the runs,
min and median; UAV goals reached at the end (within 1 m); time to all goals (s: per run the
latest UAV's time from which it stayed within 1 m of its goal, :func:`time_to_goals`) max and
median over the runs whose goals were all reached; the largest z offset of any UAV (m; the
ceiling is ``max_offset_m``, 30 m by default); the makespan: time to all goals over the
direct flight's (the latest mission's end, flown without anyone in the way), max over the runs.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import re
import statistics
import time
from concurrent.futures import ProcessPoolExecutor
from typing import Any

import numpy as np

from uavmpc import ConfigError, scenarios
from uavmpc.drivers.world import World, WorldResult
from uavmpc.scenarios import Scenario
from uavmpc.scenarios.dense import antipodal, grid_shuffle, time_to_goals, vertical_swap
from uavmpc.scenarios.run import RunSpec

DENSE = ("antipodal_8", "antipodal_12", "noncooperative_crossing")
_ANTIPODAL = re.compile(r"^antipodal_(\d+)(_reversed)?$")
_VERTICAL = re.compile(r"^vertical_(\d+)$")
_GRID = re.compile(r"^grid_(\d+)$")


def load(name: str, ceiling_m: float | None = None, seed: int = 0) -> Scenario:
    """A built-in scenario, ``antipodal_<N>`` for any N, ``vertical_<K>``: two stacks of K
    swapping places and heights, or ``grid_<N>``: N UAVs on a grid each flying to another
    grid point, the assignment drawn from ``seed`` (uavmpc.scenarios.dense), under a
    ``ceiling_m`` geofence when given (generated ones only; a vertical swap's default: 12 m
    above its top; a grid's: 25 m)."""
    m = _ANTIPODAL.match(name)
    v = _VERTICAL.match(name)
    g = _GRID.match(name)
    if g is not None:
        return grid_shuffle(int(g.group(1)), seed=seed,
                            ceiling_m=25.0 if ceiling_m is None else ceiling_m)
    if name in scenarios.BUILTIN and (ceiling_m is None or (m is None and v is None)):
        return scenarios.load(name)
    if v is not None:
        return vertical_swap(int(v.group(1)), duration_s=90.0, ceiling_m=ceiling_m)
    if m is None:
        raise ValueError(f"{name}: neither a built-in scenario, antipodal_<N>, vertical_<K> "
                         "nor grid_<N>")
    return antipodal(int(m.group(1)), duration_s=120.0, ceiling_m=ceiling_m,
                     reversed_priorities=m.group(2) is not None)


def direct_s(sc: Scenario) -> float:
    """When the latest mission ends: the time to all goals with nobody in the way."""
    return max(float(u.mission.times_s[-1]) for u in sc.uavs)


def fly(job: tuple[str, int, float, float | None, float | None]) -> dict[str, Any]:
    """One run's numbers (JSON-serialisable): (name, seed, loss, latency or None, ceiling or
    None)."""
    name, seed, loss, latency, ceiling = job
    sc = load(name, ceiling, seed)  # a grid's assignment is the seed's too
    link = dataclasses.replace(sc.link, loss=loss)
    if latency is not None:
        link = dataclasses.replace(link, latency_s=latency)
    result = World(RunSpec(sc, seed=seed, link=link)).run()
    s = result.summary()
    goals = time_to_goals(result, sc)
    reached = {uid: bool(u.reached_goal) for uid, u in s.uavs.items()}
    missed = {uid: {"final_position_m": [round(v, 2) for v in s.uavs[uid].final_position_m or ()],
                    "z_offset_at_end_m": round(float(result.z_offset_m[-1, k]), 2)}
              for k, uid in enumerate(result.uav_ids) if not reached[uid]}
    return {
        "seed": seed, "loss": loss,
        "collisions": [{"t_s": round(c.t_s, 2), "a": c.a, "b": c.b,
                        "closest_m": round(c.distance_m, 3)} for c in s.collisions],
        "min_distance_m": s.min_distance_m,
        "closest": _closest(result),
        "goals_reached": sum(reached.values()), "uavs": len(reached), "missed": missed,
        "time_to_goal_s": goals,
        "time_to_all_goals_s": (max(goals.values()) if all(v is not None for v in goals.values())
                                else None),
        "direct_s": direct_s(sc),
        "max_z_offset_m": max(u.max_z_offset_m for u in s.uavs.values()),
        "limit_violations": sum(u.details["limit_violations"] for u in s.uavs.values()),
        "tracker_fallbacks": sum(u.details["tracker_fallbacks"] for u in s.uavs.values()),
        "dropped_share": s.messages.dropped / max(1, s.messages.sent),
        "wall_s": s.wall_s,
    }


def _closest(result: WorldResult) -> dict[str, Any]:
    """When and between whom the run's closest approach was."""
    k = int(result.min_distance_m.argmin())
    p = result.positions_m[k]
    d = np.linalg.norm(p[:, None] - p[None], axis=2)
    d[np.diag_indices_from(d)] = np.inf
    a, b = np.unravel_index(int(d.argmin()), d.shape)
    return {"t_s": round(float(result.t_s[k]), 2), "a": result.uav_ids[min(a, b)],
            "b": result.uav_ids[max(a, b)], "distance_m": round(float(d[a, b]), 3)}


def row(name: str, loss: float, latency: float | None, ceiling: float | None,
        runs: list[dict[str, Any]]) -> dict[str, Any]:
    """One scenario × link: the runs summed up."""
    closest = [r["min_distance_m"] for r in runs]
    done = [r["time_to_all_goals_s"] for r in runs if r["time_to_all_goals_s"] is not None]
    spans = [r["time_to_all_goals_s"] / r["direct_s"] for r in runs
             if r["time_to_all_goals_s"] is not None]
    return {
        "scenario": name, "loss": loss, "latency_s": latency, "ceiling_m": ceiling,
        "runs": len(runs), "duration_s": load(name, ceiling).duration_s,
        "makespan_over_direct_max": max(spans) if spans else None,
        "runs_with_collision": sum(bool(r["collisions"]) for r in runs),
        "closest_m_min": min(closest), "closest_m_median": statistics.median(closest),
        "goals_reached": sum(r["goals_reached"] for r in runs),
        "goals": sum(r["uavs"] for r in runs),
        "time_to_all_goals_s_max": max(done) if done else None,
        "time_to_all_goals_s_median": statistics.median(done) if done else None,
        "max_z_offset_m": max(r["max_z_offset_m"] for r in runs),
        "limit_violations": sum(r["limit_violations"] for r in runs),
        "tracker_fallbacks": sum(r["tracker_fallbacks"] for r in runs),
    }


def _fmt(v: float | None, spec: str = ".1f") -> str:
    return "—" if v is None else format(v, spec)


def _links(text: str) -> list[tuple[float, float | None]]:
    """``LOSS[:LATENCY_S],...`` → [(loss, latency or None)]; ValueError naming a bad item."""
    out = []
    for item in text.split(","):
        loss_text, _, latency_text = item.partition(":")
        loss = float(loss_text)
        latency = float(latency_text) if latency_text else None
        if not 0.0 <= loss < 1.0 or (latency is not None and not 0.0 <= latency <= 5.0):
            raise ValueError(item)
        out.append((loss, latency))
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=10)
    parser.add_argument("--links", default="0,0.3",
                        help="comma-separated LOSS[:LATENCY_S] (loss in [0, 1), latency in "
                             "[0, 5] s; without it, the scenario's)")
    parser.add_argument("--scenarios", default=",".join(DENSE))
    parser.add_argument("--ceiling", type=float, default=None,
                        help="a geofence's ceiling [m] over each antipodal circle")
    parser.add_argument("--workers", type=int, default=1, help="runs flown at once")
    args = parser.parse_args()
    if args.seeds < 1:
        parser.error("--seeds: need at least 1")
    if args.workers < 1:
        parser.error("--workers: need at least 1")
    try:
        links = _links(args.links)
    except ValueError as exc:
        parser.error(f"--links: LOSS[:LATENCY_S] with loss in [0, 1) and latency in [0, 5] s, "
                     f"got {exc}")
    names = [v for v in args.scenarios.split(",") if v]
    unknown = [v for v in names if v not in scenarios.BUILTIN and not _ANTIPODAL.match(v)
               and not _VERTICAL.match(v) and not _GRID.match(v)]
    if unknown:
        parser.error("--scenarios: neither built-in, antipodal_<N>, vertical_<K> nor "
                     f"grid_<N>: {', '.join(unknown)}")
    try:
        for name in names:
            load(name, args.ceiling)
    except (ValueError, ConfigError) as exc:
        parser.error(f"--ceiling: {exc}")

    wall0 = time.perf_counter()
    rows, findings = [], []
    print(f"{'scenario':24s} {'link':>10s} {'coll':>5s} {'closest min/med [m]':>20s} "
          f"{'goals':>9s} {'all goals max/med [s]':>22s} {'span/direct':>11s} "
          f"{'max dz [m]':>10s}", flush=True)
    with ProcessPoolExecutor(args.workers) as pool:
        for name in names:
            for loss, latency in links:
                jobs = [(name, seed, loss, latency, args.ceiling) for seed in range(args.seeds)]
                runs = list(pool.map(fly, jobs))
                r = row(name, loss, latency, args.ceiling, runs)
                rows.append({**r, "per_run": runs})
                link = f"{loss:g}" + ("" if latency is None else f"+{latency:g}s")
                print(f"{name:24s} {link:>10s} {r['runs_with_collision']:>2d}/{r['runs']:<2d} "
                      f"{r['closest_m_min']:>9.2f} / {r['closest_m_median']:<8.2f} "
                      f"{r['goals_reached']:>4d}/{r['goals']:<4d} "
                      f"{_fmt(r['time_to_all_goals_s_max']):>10s} / "
                      f"{_fmt(r['time_to_all_goals_s_median']):<9s} "
                      f"{_fmt(r['makespan_over_direct_max'], '.2f'):>11s} "
                      f"{r['max_z_offset_m']:>10.1f}", flush=True)
                for run in runs:
                    for c in run["collisions"]:
                        findings.append(f"COLLISION {name} link={link} seed={run['seed']}: "
                                        f"{c['a']}–{c['b']} at t={c['t_s']} s, closest "
                                        f"{c['closest_m']} m")
                    for uid, m in run["missed"].items():
                        findings.append(f"GOAL MISSED {name} link={link} seed={run['seed']}: "
                                        f"{uid} ended at {m['final_position_m']}, z offset "
                                        f"{m['z_offset_at_end_m']} m")
    for f in findings:
        print(f, flush=True)
    print(f"({len(findings)} findings, {time.perf_counter() - wall0:.0f} s)", flush=True)
    print(json.dumps({"seeds": args.seeds, "links": links, "ceiling_m": args.ceiling,
                      "rows": rows, "findings": findings}))


if __name__ == "__main__":
    main()
