"""The landing campaign: many seeded landings on the moving deck (``uavmpc campaign landing``).

Each trial flies a landing scenario (default: the built-in ``moving_target_landing``) with the
car starting at a random point of its track and its own seeded fix noise and dropouts; a trial
is one :class:`~uavmpc.drivers.world.World` run. The report gives the success rate, the
time-to-land percentiles (from the start of the approach), touchdowns off the deck and hard
ones, and where the time went (mean time per phase).
"""

from __future__ import annotations

import concurrent.futures as cf
import dataclasses
import json
import os
from pathlib import Path
from typing import Any

import numpy as np

from uavmpc import scenarios
from uavmpc.config import ConfigError
from uavmpc.plant.ground_vehicle import KMH, GroundVehicle


def landing_trial(scenario: str, index: int, seed: int, speed_kmh: float | None,
                  duration_s: float | None) -> dict[str, Any]:
    """One trial: the scenario with the car at a random start point of its track."""
    from uavmpc.drivers.world import World

    sc = scenarios.load(scenario)
    car = sc.ground_vehicle
    if car is None or sc.landing is None:
        raise ConfigError(f"{scenario}: not a landing scenario (needs [ground_vehicle] and "
                          "[landing])")
    rng = np.random.default_rng([seed, index])
    moved = GroundVehicle(car.track, speed_mps=car.speed_mps if speed_kmh is None
                          else speed_kmh * KMH,
                          start_arc_m=float(rng.uniform(0.0, car.track.length_of_lap_m)),
                          deck_size_m=car.deck_size_m, deck_height_m=car.deck_height_m)
    sc = dataclasses.replace(sc, ground_vehicle=moved)
    trial_seed = int(rng.integers(0, 2**31))
    s = World(sc, seed=trial_seed).run(duration_s).summary()
    assert s.landing is not None  # the scenario was checked for a lander above
    landing = dataclasses.asdict(s.landing)
    keep = ("landed", "time_to_land_s", "touchdown", "landed_elsewhere", "edge_strikes",
            "touchdowns",
            "on_deck_at_end", "phases_s", "aborts", "max_touchdown_speed_mps")
    return {"index": index, "seed": trial_seed, "start_arc_m": moved.start_arc_m,
            "speed_kmh": moved.speed_mps / KMH, "wall_s": s.wall_s,
            **{k: landing[k] for k in keep}}


def _pct(values: list[float], q: float) -> float | None:
    return float(np.percentile(values, q)) if values else None


def landing_report(trials: list[dict[str, Any]]) -> dict[str, Any]:
    """The campaign's figures from its trials."""
    n = len(trials)
    landed = [t for t in trials if t["landed"]]
    times = [t["time_to_land_s"] for t in landed]
    touched = [t for t in trials if t["touchdown"] is not None]
    # Off the deck: a rotor struck its edge, or the motors were cut resting elsewhere.
    off_deck = [t for t in trials if t["edge_strikes"] or t["landed_elsewhere"]]
    hard = [t for t in touched if t["touchdown"]["hard"]]
    late = [t for t in trials if not t["landed"] and t not in off_deck and t not in hard]
    phases: dict[str, float] = {}
    for t in landed:
        for k, v in t["phases_s"].items():
            phases[k] = phases.get(k, 0.0) + v / max(len(landed), 1)
    aborts: dict[str, int] = {}
    for t in trials:
        for k, v in t["aborts"].items():
            aborts[k] = aborts.get(k, 0) + v
    vz = [t["touchdown"]["vertical_speed_mps"] for t in touched]
    off = [t["touchdown"]["offset_from_centre_m"] for t in touched]
    return {
        "trials": n, "speed_kmh": trials[0]["speed_kmh"] if trials else None,
        "landed": len(landed), "success_rate": len(landed) / n if n else None,
        "time_to_land_s": {f"p{q}": _pct(times, q) for q in (5, 50, 95, 100)},
        "touchdowns_off_the_deck": len(off_deck), "hard_touchdowns": len(hard),
        "edge_strikes": sum(t["edge_strikes"] for t in trials),
        "no_touchdown": n - len(touched),
        "not_landed_in_time": len(late),
        "touchdown_vertical_speed_mps": {"p50": _pct(vz, 50), "max": max(vz, default=None)},
        "touchdown_offset_m": {"p50": _pct(off, 50), "max": max(off, default=None)},
        "mean_phase_s_of_landed": {k: round(v, 2) for k, v in phases.items()},
        "aborts": aborts,
    }


def run_landing_campaign(out: str | Path, *, trials: int, seed: int = 0,
                         scenario: str = "moving_target_landing",
                         speed_kmh: float | None = None, duration_s: float | None = None,
                         workers: int | None = None) -> dict[str, Any]:
    """Fly ``trials`` landings (``workers`` processes) and write trials.jsonl, report.json."""
    if trials < 1:
        raise ConfigError(f"--trials: must be ≥ 1, got {trials}")
    if speed_kmh is not None and not 0.0 <= speed_kmh <= 200.0:
        raise ConfigError(f"--speed-kmh: must be in [0, 200], got {speed_kmh}")
    landing_trial(scenario, 0, seed, speed_kmh, 0.1)  # a bad scenario fails here, at once
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    workers = workers or os.cpu_count() or 1
    args = [(scenario, i, seed, speed_kmh, duration_s) for i in range(trials)]
    if workers == 1:
        results = [landing_trial(*a) for a in args]
    else:
        with cf.ProcessPoolExecutor(max_workers=workers) as ex:
            results = list(ex.map(landing_trial, *zip(*args, strict=True)))
    with (out / "trials.jsonl").open("w") as f:
        for r in results:
            f.write(json.dumps(r) + "\n")
    report = {"scenario": scenario, "seed": seed, **landing_report(results)}
    (out / "report.json").write_text(json.dumps(report, indent=2) + "\n")
    return report
