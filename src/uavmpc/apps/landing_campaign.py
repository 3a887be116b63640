"""The landing campaign: many seeded landings on the moving deck (``uavmpc campaign landing``).

Each trial flies a landing scenario (default: the built-in ``moving_target_landing``) with the
car starting at a random point of its track and its own seeded fix noise and dropouts; a trial
is one :class:`~uavmpc.drivers.world.World` run. The report gives the success rate, the
time-to-land percentiles (from the start of the approach), touchdowns off the deck and hard
ones, and where the time went (mean time per phase).

A campaign is a :class:`LandingSpec` in a folder kept by the one campaign engine
(:mod:`uavmpc.apps.campaign_engine`): ``campaign.json`` (the spec), ``trials.jsonl`` (one line
per landing, appended as it ends: re-running the same command continues the campaign),
``runs.jsonl``, ``report.json``.
"""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from uavmpc import scenarios
from uavmpc.apps.campaign_engine import QUIET, Execution, Task, run_trials
from uavmpc.config import ConfigError
from uavmpc.plant.ground_vehicle import KMH, GroundVehicle
from uavmpc.scenarios.run import RunSpec
from uavmpc.scenarios.stats import percentile


@dataclass(frozen=True)
class LandingSpec:
    """What every landing of a campaign flies: the scenario (built-in name or file), the
    campaign seed, the car's speed (None: the scenario's) and the flight's length (None: the
    scenario's)."""

    kind: ClassVar[str] = "landing"

    scenario: str = "moving_target_landing"
    seed: int = 0
    speed_kmh: float | None = None
    duration_s: float | None = None

    def __post_init__(self) -> None:
        if isinstance(self.seed, bool) or not isinstance(self.seed, int) or self.seed < 0:
            raise ConfigError(f"--seed: must be a non-negative integer, got {self.seed!r}")
        if self.speed_kmh is not None and not 0.0 <= self.speed_kmh <= 200.0:
            raise ConfigError(f"--speed-kmh: must be in [0, 200], got {self.speed_kmh}")
        if self.duration_s is not None and not self.duration_s > 0:
            raise ConfigError(f"--duration: must be > 0, got {self.duration_s}")

    def to_json(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    @classmethod
    def from_json(cls, data: dict[str, Any]) -> LandingSpec:
        return cls(**data)

    def tasks(self, index: int) -> list[Task]:
        return [Task(index, 0, landing_trial, (self.scenario, index, self.seed,
                                               self.speed_kmh, self.duration_s))]

    def record(self, index: int, results: list[dict[str, Any]]) -> dict[str, Any]:
        return results[0]

    def foreign(self, index: int, record: dict[str, Any]) -> str | None:
        if record.get("seed") != _trial_seed(self.seed, index):
            return f"has a seed that does not derive from the campaign seed {self.seed}"
        return None


def _trial_seed(seed: int, index: int) -> int:
    """Trial ``index``'s world seed, as :func:`landing_trial` draws it (after the car's
    start)."""
    rng = np.random.default_rng([seed, index])
    rng.uniform(0.0, 1.0)
    return int(rng.integers(0, 2**31))


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
    s = World(RunSpec(sc, seed=trial_seed, duration_s=duration_s)).run().summary()
    assert s.landing is not None  # the scenario was checked for a lander above
    landing = dataclasses.asdict(s.landing)
    keep = ("landed", "time_to_land_s", "touchdown", "landed_elsewhere", "edge_strikes",
            "touchdowns",
            "on_deck_at_end", "phases_s", "aborts", "max_touchdown_speed_mps")
    return {"index": index, "seed": trial_seed, "start_arc_m": moved.start_arc_m,
            "speed_kmh": moved.speed_mps / KMH, "wall_s": s.wall_s,
            **{k: landing[k] for k in keep}}


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
        "time_to_land_s": {f"p{q}": percentile(times, q) for q in (5, 50, 95, 100)},
        "touchdowns_off_the_deck": len(off_deck), "hard_touchdowns": len(hard),
        "edge_strikes": sum(t["edge_strikes"] for t in trials),
        "no_touchdown": n - len(touched),
        "not_landed_in_time": len(late),
        "touchdown_vertical_speed_mps": {"p50": percentile(vz, 50), "max": max(vz, default=None)},
        "touchdown_offset_m": {"p50": percentile(off, 50), "max": max(off, default=None)},
        "mean_phase_s_of_landed": {k: round(v, 2) for k, v in phases.items()},
        "aborts": aborts,
    }


def run_landing_campaign(out: str | Path, *, trials: int, seed: int = 0,
                         scenario: str = "moving_target_landing",
                         speed_kmh: float | None = None, duration_s: float | None = None,
                         execution: Execution = QUIET) -> dict[str, Any]:
    """Fly (or continue) ``trials`` landings as ``execution`` says (local processes or Ray;
    default: the machine's cores, no progress shown) and write trials.jsonl, report.json;
    return the report."""
    if isinstance(trials, bool) or not isinstance(trials, int) or trials < 1:
        raise ConfigError(f"--trials: must be ≥ 1, got {trials}")
    spec = LandingSpec(scenario, seed, speed_kmh, duration_s)
    execution = execution.on_this_machine()
    landing_trial(scenario, 0, seed, speed_kmh, 0.1)  # a bad scenario fails here, at once
    out = Path(out)
    results = run_trials(out, spec, LandingSpec.from_json, execution, trials=trials)
    report = {"scenario": scenario, "seed": seed, **landing_report(results)}
    (out / "report.json").write_text(json.dumps(report, indent=2) + "\n")
    return report
