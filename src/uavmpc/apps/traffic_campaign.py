"""The traffic campaign: seeded dense traffics, each flown with and without avoidance
(``uavmpc campaign traffic``).

A trial is one seeded :func:`~uavmpc.scenarios.traffic.traffic` scenario flown twice by
:class:`~uavmpc.drivers.world.World` with the same world seed (link randomness), once with
avoidance and once without, so that the two flights differ only by avoidance. The report
gives, per side, the collisions, the closest approach, the goals reached and the trip-time
percentiles, and the trip-time penalty of avoidance: for each UAV that arrived in both
flights, its trip with avoidance minus its trip without (pooled over the trials).

Each of the 2 × trials flights is a job of its own on the worker processes (a flight is
single-threaded), so two workers already fly both sides of a trial at once.
"""

from __future__ import annotations

import concurrent.futures as cf
import json
import os
import time
from pathlib import Path
from typing import Any

import numpy as np

from uavmpc.config import ConfigError
from uavmpc.scenarios.traffic import MAX_UAVS, traffic, traffic_outcome

SIDES = ("with_avoidance", "without_avoidance")


def trial_seeds(seed: int, index: int) -> tuple[int, int]:
    """(scenario seed, world seed) of trial ``index``: independent streams per trial, the
    same for both sides of it."""
    a, b = np.random.SeedSequence([int(seed), int(index)]).generate_state(2)
    return int(a) & 0x7FFFFFFF, int(b) & 0x7FFFFFFF


def traffic_flight(index: int, seed: int, uavs: int, duration_s: float | None,
                   avoidance: bool, options: dict[str, Any] | None = None) -> dict[str, Any]:
    """One side of one trial: its traffic outcome, seeds and wall time. ``options``: more
    keyword arguments of :func:`~uavmpc.scenarios.traffic.traffic` (density, heights, ...)."""
    from uavmpc.drivers.world import World

    scenario_seed, world_seed = trial_seeds(seed, index)
    sc = traffic(uavs, scenario_seed, duration_s=duration_s, **(options or {}))
    result = World(sc, avoidance=avoidance, seed=world_seed).run(duration_s)
    return {"index": index, "avoidance": avoidance, "scenario_seed": scenario_seed,
            "world_seed": world_seed, "duration_s": result.duration_s,
            "wall_s": result.wall_s, **traffic_outcome(result, sc)}


def _pct(values: list[float], q: float) -> float | None:
    return float(np.percentile(values, q)) if values else None


def _side(flights: list[dict[str, Any]]) -> dict[str, Any]:
    trips = [t for f in flights for t in f["per_uav_trip_s"].values() if t is not None]
    closest = [f["closest_approach_m"] for f in flights if f["closest_approach_m"] is not None]
    uavs = sum(f["uavs"] for f in flights)
    reached = sum(f["goals_reached"] for f in flights)
    return {
        "collisions": sum(f["collisions"] for f in flights),
        "trials_with_collision": sum(1 for f in flights if f["collisions"]),
        "colliding_uavs": sum(f["colliding_uavs"] for f in flights),
        "closest_approach_m": min(closest, default=None),
        "closest_approach_p50_m": _pct(closest, 50),
        "goals_reached": reached,
        "goals_reached_share": reached / uavs if uavs else None,
        "arrived": len(trips),
        "trip_s": {"p50": _pct(trips, 50), "p95": _pct(trips, 95),
                   "max": max(trips, default=None)},
        "airborne_peak": max((f["airborne"]["peak"] for f in flights), default=0),
        "wall_s": sum(f["wall_s"] for f in flights),
    }


def traffic_report(trials: list[dict[str, Any]]) -> dict[str, Any]:
    """The campaign's figures from its trial records (each with both sides)."""
    penalty: list[float] = []
    for t in trials:
        w, wo = t["with_avoidance"]["per_uav_trip_s"], t["without_avoidance"]["per_uav_trip_s"]
        penalty += [w[k] - wo[k] for k in w if w[k] is not None and wo.get(k) is not None]
    first = trials[0]["with_avoidance"] if trials else {}
    return {
        "trials": len(trials),
        "uavs": first.get("uavs"),
        "density_per_km2": first.get("density_per_km2"),
        "area_km2": first.get("area_km2"),
        "duration_s": {"min": min((t["with_avoidance"]["duration_s"] for t in trials),
                                  default=None),
                       "max": max((t["with_avoidance"]["duration_s"] for t in trials),
                                  default=None)},
        **{side: _side([t[side] for t in trials]) for side in SIDES},
        # Per UAV that arrived in both flights of its trial: trip with − trip without.
        "avoidance_trip_penalty_s": {
            "uavs": len(penalty),
            "mean": float(np.mean(penalty)) if penalty else None,
            "p50": _pct(penalty, 50), "p95": _pct(penalty, 95),
            "max": max(penalty, default=None)},
    }


def run_traffic_campaign(out: str | Path, *, trials: int, uavs: int = 300, seed: int = 0,
                         duration_s: float | None = None, workers: int | None = None,
                         scenario_options: dict[str, Any] | None = None) -> dict[str, Any]:
    """Fly ``trials`` traffics with and without avoidance (``workers`` processes); write
    trials.jsonl (one line per trial, both sides) and report.json; return the report.

    ``duration_s``: simulated seconds per flight (default: each scenario's, long enough for
    every trip); ``scenario_options``: more keyword arguments of
    :func:`~uavmpc.scenarios.traffic.traffic`."""
    if isinstance(trials, bool) or not isinstance(trials, int) or trials < 1:
        raise ConfigError(f"--trials: must be an integer ≥ 1, got {trials!r}")
    if isinstance(uavs, bool) or not isinstance(uavs, int) or not 1 <= uavs <= MAX_UAVS:
        raise ConfigError(f"--uavs: must be an integer in [1, {MAX_UAVS}], got {uavs!r}")
    if duration_s is not None and not duration_s > 0:
        raise ConfigError(f"--duration: must be > 0, got {duration_s}")
    if workers is not None and workers < 1:
        raise ConfigError(f"--workers: must be ≥ 1, got {workers}")
    for i in range(trials):  # a layout that cannot be drawn fails here, before any flight
        traffic(uavs, trial_seeds(seed, i)[0], duration_s=duration_s,
                **(scenario_options or {}))
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    workers = workers or os.cpu_count() or 1
    jobs = [(i, seed, uavs, duration_s, avoidance, scenario_options) for i in range(trials)
            for avoidance in (True, False)]
    wall0 = time.perf_counter()
    if workers == 1:
        flights = [traffic_flight(*j) for j in jobs]
    else:
        with cf.ProcessPoolExecutor(max_workers=min(workers, len(jobs))) as ex:
            flights = list(ex.map(traffic_flight, *zip(*jobs, strict=True)))
    wall = time.perf_counter() - wall0
    records = []
    for i in range(trials):
        both = {("with_avoidance" if f["avoidance"] else "without_avoidance"): f
                for f in flights if f["index"] == i}
        f = both["with_avoidance"]
        records.append({"index": i, "scenario_seed": f["scenario_seed"],
                        "world_seed": f["world_seed"], **both})
    with (out / "trials.jsonl").open("w") as fh:
        for r in records:
            fh.write(json.dumps(r) + "\n")
    report = {"scenario": "traffic", "seed": seed, "options": scenario_options or {},
              **traffic_report(records),
              "workers": workers, "wall_s": wall}
    (out / "report.json").write_text(json.dumps(report, indent=2) + "\n")
    return report


def report_lines(r: dict[str, Any]) -> list[str]:
    """The report in a few human lines (``uavmpc campaign traffic``)."""
    def s(v: float | None) -> str:
        return "–" if v is None else f"{v:.1f} s"

    lines = [f"traffic: {r['trials']} trial(s) of {r['uavs']} UAVs "
             f"({r['density_per_km2']:g}/km² over {r['area_km2']:.3g} km²), each flown with "
             f"and without avoidance, {r['wall_s']:.0f} s wall"]
    for side in SIDES:
        x = r[side]
        closest = x["closest_approach_m"]
        lines.append(
            f"  {side.replace('_', ' ')}: {x['collisions']} collision(s) in "
            f"{x['trials_with_collision']} trial(s), closest approach "
            f"{'–' if closest is None else f'{closest:.2f} m'}; goals reached "
            f"{x['goals_reached']} ({100 * (x['goals_reached_share'] or 0.0):.0f} %); trip time "
            f"p50 {s(x['trip_s']['p50'])}, p95 {s(x['trip_s']['p95'])}")
    p = r["avoidance_trip_penalty_s"]
    lines.append(f"  trip-time penalty of avoidance ({p['uavs']} UAVs arrived in both): mean "
                 f"{s(p['mean'])}, p50 {s(p['p50'])}, p95 {s(p['p95'])}")
    return lines
