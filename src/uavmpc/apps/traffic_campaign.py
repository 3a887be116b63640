"""The traffic campaign: seeded dense traffics, each flown with and without avoidance
(``uavmpc campaign traffic``).

A trial is one seeded :func:`~uavmpc.scenarios.traffic.traffic` scenario flown twice by
:class:`~uavmpc.drivers.world.World` with the same world seed (link randomness), once with
avoidance and once without, so that the two flights differ only by avoidance. The report
gives, per side, the collisions, the closest approach, the goals reached and the trip-time
percentiles, and the trip-time penalty of avoidance: for each UAV that arrived in both
flights, its trip with avoidance minus its trip without (pooled over the trials).

A campaign is a :class:`TrafficSpec` in a folder kept by the one campaign engine
(:mod:`uavmpc.apps.campaign_engine`): ``campaign.json`` (the spec), ``trials.jsonl`` (one line
per trial, both sides, appended as it ends: re-running the same command continues the
campaign), ``runs.jsonl``, ``report.json``. Each side of a trial is a job of its own on the
workers (a flight is single-threaded), so two workers already fly both sides of a trial at once.
"""

from __future__ import annotations

import json
import time
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from uavmpc.apps.campaign_engine import QUIET, Execution, Task, campaign_wall_s, run_trials
from uavmpc.config import ConfigError
from uavmpc.scenarios.run import RunSpec
from uavmpc.scenarios.stats import percentile
from uavmpc.scenarios.traffic import MAX_UAVS, traffic, traffic_outcome

SIDES = ("with_avoidance", "without_avoidance")


def _frozen(value: object) -> object:
    """A JSON value with its lists as tuples (an option read back from JSON equals the one
    given)."""
    if isinstance(value, list | tuple):
        return tuple(_frozen(v) for v in value)
    return value


@dataclass(frozen=True)
class TrafficSpec:
    """What every trial of a traffic campaign flies: ``uavs`` UAVs, the campaign seed, the
    flights' length (None: each scenario's own) and more keyword arguments of
    :func:`~uavmpc.scenarios.traffic.traffic` (``options``: (name, value) pairs, sorted)."""

    kind: ClassVar[str] = "traffic"

    uavs: int = 300
    seed: int = 0
    duration_s: float | None = None
    options: tuple[tuple[str, object], ...] = ()

    def __post_init__(self) -> None:
        u = self.uavs
        if isinstance(u, bool) or not isinstance(u, int) or not 1 <= u <= MAX_UAVS:
            raise ConfigError(f"--uavs: must be an integer in [1, {MAX_UAVS}], got {u!r}")
        if isinstance(self.seed, bool) or not isinstance(self.seed, int) or self.seed < 0:
            raise ConfigError(f"--seed: must be a non-negative integer, got {self.seed!r}")
        if self.duration_s is not None and not self.duration_s > 0:
            raise ConfigError(f"--duration: must be > 0, got {self.duration_s}")
        object.__setattr__(self, "options", tuple(sorted(
            (str(k), _frozen(v)) for k, v in dict(self.options).items())))

    @property
    def scenario_options(self) -> dict[str, Any]:
        return dict(self.options)

    def to_json(self) -> dict[str, Any]:
        return {"uavs": self.uavs, "seed": self.seed, "duration_s": self.duration_s,
                "options": self.scenario_options}

    @classmethod
    def from_json(cls, data: Mapping[str, Any]) -> TrafficSpec:
        return cls(data["uavs"], data["seed"], data["duration_s"],
                   tuple(dict(data["options"]).items()))

    def tasks(self, index: int) -> list[Task]:
        return [Task(index, part, traffic_flight, (index, self.seed, self.uavs,
                                                   self.duration_s, avoidance,
                                                   self.scenario_options))
                for part, avoidance in enumerate((True, False))]

    def record(self, index: int, results: list[dict[str, Any]]) -> dict[str, Any]:
        both = dict(zip(SIDES, results, strict=True))
        f = both["with_avoidance"]
        return {"index": index, "scenario_seed": f["scenario_seed"],
                "world_seed": f["world_seed"], **both}

    def foreign(self, index: int, record: dict[str, Any]) -> str | None:
        if (record.get("scenario_seed"), record.get("world_seed")) != trial_seeds(self.seed,
                                                                                  index):
            return f"has seeds that do not derive from the campaign seed {self.seed}"
        return None


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
    result = World(RunSpec(sc, avoidance=avoidance, seed=world_seed,
                                     duration_s=duration_s)).run()
    return {"index": index, "avoidance": avoidance, "scenario_seed": scenario_seed,
            "world_seed": world_seed, "duration_s": result.duration_s,
            "wall_s": result.wall_s, **traffic_outcome(result, sc)}


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
        "closest_approach_p50_m": percentile(closest, 50),
        "goals_reached": reached,
        "goals_reached_share": reached / uavs if uavs else None,
        "arrived": len(trips),
        "trip_s": {"p50": percentile(trips, 50), "p95": percentile(trips, 95),
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
            "p50": percentile(penalty, 50), "p95": percentile(penalty, 95),
            "max": max(penalty, default=None)},
    }


def run_traffic_campaign(out: str | Path, *, trials: int, uavs: int = 300, seed: int = 0,
                         duration_s: float | None = None,
                         scenario_options: dict[str, Any] | None = None,
                         execution: Execution = QUIET) -> dict[str, Any]:
    """Fly (or continue) ``trials`` traffics with and without avoidance as ``execution`` says
    (local processes or Ray; default: the machine's cores, no progress shown); write
    trials.jsonl (one line per trial, both sides) and report.json; return the report.

    ``duration_s``: simulated seconds per flight (default: each scenario's, long enough for
    every trip); ``scenario_options``: more keyword arguments of
    :func:`~uavmpc.scenarios.traffic.traffic`."""
    if isinstance(trials, bool) or not isinstance(trials, int) or trials < 1:
        raise ConfigError(f"--trials: must be an integer ≥ 1, got {trials!r}")
    spec = TrafficSpec(uavs, seed, duration_s, tuple((scenario_options or {}).items()))
    execution = execution.on_this_machine()
    for i in range(trials):  # a layout that cannot be drawn fails here, before any flight
        traffic(uavs, trial_seeds(seed, i)[0], duration_s=duration_s,
                **(scenario_options or {}))
    out = Path(out)
    wall0 = time.perf_counter()
    records = run_trials(out, spec, TrafficSpec.from_json, execution, trials=trials)
    report = {"scenario": "traffic", "seed": seed, "options": scenario_options or {},
              **traffic_report(records),
              "workers": execution.counts[0], "threads": execution.counts[1],
              "wall_s": campaign_wall_s(out, wall0)}
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
